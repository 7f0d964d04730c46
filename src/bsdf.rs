//! Surface scattering shared by light and camera paths: Lambert, smooth dielectric
//! (exact unpolarised Fresnel, total internal reflection) and mirror.
use glam::{Vec2, Vec3};

use crate::core::Rgb;
use crate::sampling::cosine_hemisphere;
use crate::scene::Material;

/// Unpolarised Fresnel reflectance for cosine `cos_i` (> 0) on the incident side and
/// relative index `eta` = n_transmitted / n_incident. Returns 1 on total internal reflection.
pub fn fresnel_dielectric(cos_i: f32, eta: f32) -> f32 {
    let cos_i = cos_i.clamp(0.0, 1.0);
    let sin2_t = (1.0 - cos_i * cos_i) / (eta * eta);
    if sin2_t >= 1.0 {
        return 1.0;
    }
    let cos_t = (1.0 - sin2_t).sqrt();
    let rs = (cos_i - eta * cos_t) / (cos_i + eta * cos_t);
    let rp = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
    0.5 * (rs * rs + rp * rp)
}

pub fn reflect(d: Vec3, n: Vec3) -> Vec3 {
    d - 2.0 * d.dot(n) * n
}

/// Refraction of direction `d` through a surface with normal `n` facing the incident side.
pub fn refract(d: Vec3, n: Vec3, eta: f32) -> Option<Vec3> {
    let cos_i = -d.dot(n);
    let sin2_t = (1.0 - cos_i * cos_i) / (eta * eta);
    if sin2_t >= 1.0 {
        return None;
    }
    let cos_t = (1.0 - sin2_t).sqrt();
    Some((d / eta + n * (cos_i / eta - cos_t)).normalize())
}

/// Result of scattering a path off a surface.
pub struct Bounce {
    pub dir: Vec3,
    /// Multiplies the path weight (already divided by the sampling probability).
    pub weight: Rgb,
}

/// Samples a continuation for a path travelling along `d` that hit a surface with
/// geometric normal `ng` and shading normal `ns`. Lambert is cosine-sampled with weight
/// rho; the dielectric picks reflection with probability F, so its weight is 1.
pub fn sample(
    material: &Material,
    d: Vec3,
    ng: Vec3,
    ns: Vec3,
    u: f32,
    u2: Vec2,
) -> Option<Bounce> {
    let front = d.dot(ng) < 0.0;
    let n_geo = if front { ng } else { -ng };
    let mut n = if ns.dot(n_geo) < 0.0 { -ns } else { ns };
    if -d.dot(n) <= 0.0 {
        n = n_geo;
    }
    let valid = |dir: Vec3, same_side: bool| (dir.dot(n_geo) > 0.0) == same_side;
    match *material {
        Material::Lambert { reflectance } => {
            let dir = cosine_hemisphere(n_geo, u2);
            Some(Bounce {
                dir,
                weight: reflectance,
            })
        }
        Material::Mirror { reflectance } => {
            let dir = reflect(d, n);
            valid(dir, true).then_some(Bounce {
                dir,
                weight: reflectance,
            })
        }
        Material::Dielectric { ior } => {
            let eta = if front { ior } else { 1.0 / ior };
            let f = fresnel_dielectric(-d.dot(n), eta);
            let (dir, same_side) = if u < f {
                (reflect(d, n), true)
            } else {
                (refract(d, n, eta)?, false)
            };
            valid(dir, same_side).then_some(Bounce {
                dir,
                weight: Vec3::ONE,
            })
        }
    }
}

/// Both branches of a smooth dielectric with their Fresnel weights (reflection F,
/// refraction 1 - F; refraction absent under total internal reflection); None for other
/// materials. Branches leaving on the wrong side of the geometric surface are dropped.
pub fn split(material: &Material, d: Vec3, ng: Vec3, ns: Vec3) -> Option<[Option<(Vec3, f32)>; 2]> {
    let Material::Dielectric { ior } = *material else {
        return None;
    };
    let front = d.dot(ng) < 0.0;
    let n_geo = if front { ng } else { -ng };
    let mut n = if ns.dot(n_geo) < 0.0 { -ns } else { ns };
    if -d.dot(n) <= 0.0 {
        n = n_geo;
    }
    let eta = if front { ior } else { 1.0 / ior };
    let f = fresnel_dielectric(-d.dot(n), eta);
    let r = reflect(d, n);
    let reflected = (r.dot(n_geo) > 0.0).then_some((r, f));
    let refracted = refract(d, n, eta)
        .filter(|t| t.dot(n_geo) < 0.0 && f < 1.0)
        .map(|t| (t, 1.0 - f));
    Some([reflected, refracted])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fresnel_normal_incidence_and_tir() {
        // (n-1)^2/(n+1)^2 = 0.04 for n = 1.5.
        assert!((fresnel_dielectric(1.0, 1.5) - 0.04).abs() < 1e-6);
        assert!((fresnel_dielectric(1.0, 1.0 / 1.5) - 0.04).abs() < 1e-6);
        // Critical angle from inside glass: asin(1/1.5) = 41.81 deg.
        let crit = (1.0f32 / 1.5).asin();
        assert_eq!(fresnel_dielectric((crit + 0.01).cos(), 1.0 / 1.5), 1.0);
        assert!(fresnel_dielectric((crit - 0.01).cos(), 1.0 / 1.5) < 1.0);
        // Grazing incidence reflects everything.
        assert!(fresnel_dielectric(1e-4, 1.5) > 0.99);
    }

    #[test]
    fn fresnel_matches_brewster_angle() {
        // At Brewster's angle rp = 0, so F = rs^2 / 2 with the closed form below.
        let n = 1.5f32;
        let tb = n.atan();
        let tt = (tb.sin() / n).asin();
        let rs = ((tb - tt).sin() / (tb + tt).sin()).powi(2);
        assert!((fresnel_dielectric(tb.cos(), n) - 0.5 * rs).abs() < 1e-5);
    }

    #[test]
    fn refraction_obeys_snell() {
        let n = Vec3::Y;
        let theta = 0.6f32;
        let d = Vec3::new(theta.sin(), -theta.cos(), 0.0);
        let t = refract(d, n, 1.5).unwrap();
        let sin_t = t.x;
        assert!((theta.sin() - 1.5 * sin_t).abs() < 1e-5);
        assert!(t.y < 0.0);
    }
}
