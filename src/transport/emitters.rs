//! What each light kind does, in one place: its power, the start of a light path it emits,
//! a sample of it seen from a point (next-event estimation), where equiangular sampling
//! aims and what a ray leaving the scene sees of it. A new kind is a variant of
//! `scene::Light` and one arm in each method here.
//!
//! Lights at infinity (directional, environment) light the scene's bounding box: their
//! light paths start on the smallest rectangle facing the direction they travel that
//! covers the box's shadow ([`SceneBox::window`]), whose area enters their power. A path
//! that starts outside it meets nothing; the bounding sphere's disk wasted 40 % of
//! cloud-hg's paths on such misses.
use glam::{Vec2, Vec3};
use std::f32::consts::PI;

use crate::core::Rgb;
use crate::geometry::EPS;
use crate::sampling::{cosine_hemisphere, orthonormal_basis, uniform_cone, uniform_sphere};
use crate::scene::Light;

/// One emitted photon: where it starts, where it goes and its power (W).
pub struct Emission {
    pub origin: Vec3,
    pub dir: Vec3,
    pub power: Rgb,
}

/// Everything lights at infinity must light: surfaces and media, as a box.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SceneBox {
    pub lo: Vec3,
    pub hi: Vec3,
}

/// A rectangle perpendicular to a direction of travel, just upstream of the scene's box
/// and covering its shadow: the points `corner + u.x edges[0] + u.y edges[1]`, u in
/// [0, 1)^2.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Window {
    pub corner: Vec3,
    pub edges: [Vec3; 2],
    pub area: f32,
}

impl SceneBox {
    /// The half-diagonal, grown a little: a sphere around the box's centre.
    pub fn radius(&self) -> f32 {
        0.5 * (self.hi - self.lo).length() * 1.01 + 1e-3
    }

    /// The box's extent along unit axis `a`: its centre's projection -/+ its half sizes'.
    fn extent(&self, a: Vec3) -> (f32, f32) {
        let (c, h) = (0.5 * (self.lo + self.hi), 0.5 * (self.hi - self.lo));
        let r = h.dot(a.abs());
        (c.dot(a) - r, c.dot(a) + r)
    }

    /// The smallest rectangle across unit `dir` that covers the box's projection (grown
    /// by a margin, so rounding never drops a grazing path). The projection is a convex
    /// polygon whose edges are the projected box axes, and a smallest rectangle around
    /// a convex polygon has a side along one of its edges (rotating calipers), so the
    /// three projected axes are the only orientations to try.
    pub fn window(&self, dir: Vec3) -> Window {
        let margin = 1e-4 * (self.hi - self.lo).max_element() + 1e-4;
        let candidates = [Vec3::X, Vec3::Y, Vec3::Z].map(|axis| axis - dir * axis.dot(dir));
        let window = |s: Vec3| {
            let t = dir.cross(s);
            let ((s0, s1), (t0, t1)) = (self.extent(s), self.extent(t));
            let (ds, dt) = (s1 - s0 + 2.0 * margin, t1 - t0 + 2.0 * margin);
            let back = self.extent(dir).0 - margin;
            Window {
                corner: s * (s0 - margin) + t * (t0 - margin) + dir * back,
                edges: [s * ds, t * dt],
                area: ds * dt,
            }
        };
        let fallback = orthonormal_basis(dir).0;
        candidates
            .into_iter()
            .filter(|s| s.length_squared() > 1e-6)
            .map(|s| window(s.normalize()))
            .chain(std::iter::once(window(fallback)))
            .min_by(|a, b| a.area.total_cmp(&b.area))
            .expect("the fallback orientation is always tried")
    }
}

impl Window {
    fn at(&self, u: Vec2) -> Vec3 {
        self.corner + self.edges[0] * u.x + self.edges[1] * u.y
    }
}

/// A light seen from a point: the unit direction towards the sampled point of the light,
/// its distance (infinite for a directional light), and the radiance arriving along it
/// divided by the sample's solid-angle density (for delta lights: intensity / d^2, or
/// irradiance), before any transmittance.
#[derive(Clone, Copy, Debug)]
pub struct LightSample {
    pub dir: Vec3,
    pub dist: f32,
    pub value: Rgb,
}

impl Light {
    /// Total emitted power (W per channel) into `scene`. An environment's is that of its
    /// light through the disk of the box's bounding sphere, the same for every direction:
    /// it only weighs the choice between lights, since each path carries the area of its
    /// own direction's window.
    pub fn power(&self, scene: &SceneBox) -> Rgb {
        let disk = PI * scene.radius() * scene.radius();
        match *self {
            Light::Point { intensity, .. } => intensity * 4.0 * PI,
            Light::Spot {
                intensity,
                inner_deg,
                outer_deg,
                ..
            } => {
                // Linear falloff in cos: the cone's mean is the midpoint of the two cosines.
                let ci = inner_deg.to_radians().cos();
                let co = outer_deg.to_radians().cos();
                intensity * 2.0 * PI * (1.0 - 0.5 * (ci + co))
            }
            Light::Directional {
                irradiance,
                direction,
            } => irradiance * scene.window(direction).area,
            Light::Sphere {
                radius, radiance, ..
            } => radiance * PI * 4.0 * PI * radius * radius,
            // pi R^2 of disk per unit solid angle, over the whole sphere of directions.
            Light::Environment(ref env) => env.integral() * disk,
        }
    }

    /// A light path's start: origin, direction and power (W; the light's whole power,
    /// for one path chosen with probability 1). Lights at infinity emit over the window of
    /// `scene` across their direction; a directional light's `window` is passed in, made
    /// once.
    pub fn emit(&self, scene: &SceneBox, window: Option<&Window>, u1: Vec2, u2: Vec2) -> Emission {
        match *self {
            Light::Point { position, .. } => Emission {
                origin: position,
                dir: uniform_sphere(u1),
                power: self.power(scene),
            },
            Light::Sphere { center, radius, .. } => {
                let n = uniform_sphere(u1);
                Emission {
                    origin: center + n * (radius + EPS),
                    dir: cosine_hemisphere(n, u2),
                    power: self.power(scene),
                }
            }
            Light::Spot {
                position,
                direction,
                intensity,
                inner_deg,
                outer_deg,
            } => {
                let cos_outer = outer_deg.to_radians().cos();
                let dir = uniform_cone(direction, cos_outer, u1);
                let falloff = spot_falloff(direction, inner_deg, outer_deg, dir);
                let solid_angle = 2.0 * std::f32::consts::PI * (1.0 - cos_outer);
                Emission {
                    origin: position,
                    dir,
                    power: intensity * falloff * solid_angle,
                }
            }
            Light::Directional {
                direction,
                irradiance,
            } => {
                let w = window.copied().unwrap_or_else(|| scene.window(direction));
                Emission {
                    origin: w.at(u1),
                    dir: direction,
                    power: irradiance * w.area,
                }
            }
            // A direction drawn as next-event estimation draws it (by the map's luminance,
            // or uniformly), travelling the other way; its window's area times the
            // radiance over the direction's density.
            Light::Environment(ref env) => {
                let (towards, radiance, pdf) = env.sample(u2);
                let dir = -towards;
                let w = scene.window(dir);
                Emission {
                    origin: w.at(u1),
                    dir,
                    power: radiance * (w.area / pdf),
                }
            }
        }
    }

    /// Samples the light as seen from `x` (None where it sends nothing to `x`): next-event
    /// estimation's shadow-ray direction.
    pub fn sample(&self, x: Vec3, u: Vec2) -> Option<LightSample> {
        match *self {
            Light::Point {
                position,
                intensity,
            } => towards(position, x, intensity),
            Light::Spot {
                position,
                direction,
                intensity,
                inner_deg,
                outer_deg,
            } => {
                let s = towards(position, x, intensity)?;
                let falloff = spot_falloff(direction, inner_deg, outer_deg, -s.dir);
                (falloff > 0.0).then(|| LightSample {
                    value: s.value * falloff,
                    ..s
                })
            }
            Light::Directional {
                direction,
                irradiance,
            } => Some(LightSample {
                dir: -direction,
                dist: f32::INFINITY,
                value: irradiance,
            }),
            Light::Sphere {
                center,
                radius,
                radiance,
            } => sphere(center, radius, radiance, x, u),
            Light::Environment(ref env) => {
                let (dir, radiance, pdf) = env.sample(u);
                (pdf > 0.0).then(|| LightSample {
                    dir,
                    dist: f32::INFINITY,
                    value: radiance / pdf,
                })
            }
        }
    }

    /// Whether a ray leaving the scene sees the light (the environment).
    pub fn is_background(&self) -> bool {
        matches!(self, Light::Environment { .. })
    }

    /// Radiance a ray leaving the scene along `dir` sees of the light: the environment's,
    /// 0 for the others.
    pub fn background(&self, dir: Vec3) -> Rgb {
        match self {
            Light::Environment(env) => env.eval(dir),
            _ => Rgb::ZERO,
        }
    }

    /// The solid-angle density with which [`Self::sample`] draws `dir` for the lights a
    /// direction drawn by a BSDF or phase function can also find (the environment); 0
    /// for the others, whose light sample is then the only strategy.
    pub fn pdf(&self, dir: Vec3) -> f32 {
        match self {
            Light::Environment(env) => env.pdf(dir),
            _ => 0.0,
        }
    }

    /// Where equiangular sampling should aim for the light (None for a directional light).
    pub fn anchor(&self) -> Option<Vec3> {
        match *self {
            Light::Point { position, .. } | Light::Spot { position, .. } => Some(position),
            Light::Sphere { center, .. } => Some(center),
            Light::Directional { .. } | Light::Environment { .. } => None,
        }
    }
}

/// Spot falloff along emission direction `w`: full inside `inner_deg`, linear in cos to
/// zero at `outer_deg` (what the light tracer emits).
pub fn spot_falloff(axis: Vec3, inner_deg: f32, outer_deg: f32, w: Vec3) -> f32 {
    let cos_outer = outer_deg.to_radians().cos();
    let cos_inner = inner_deg.to_radians().cos();
    ((w.dot(axis) - cos_outer) / (cos_inner - cos_outer).max(1e-6)).clamp(0.0, 1.0)
}

fn towards(position: Vec3, x: Vec3, intensity: Rgb) -> Option<LightSample> {
    let v = position - x;
    let d2 = v.length_squared();
    (d2 > 0.0).then(|| {
        let dist = d2.sqrt();
        LightSample {
            dir: v / dist,
            dist,
            value: intensity / d2,
        }
    })
}

/// Uniform direction in the cone the sphere subtends from `x`, to the near side.
fn sphere(center: Vec3, radius: f32, radiance: Rgb, x: Vec3, u: Vec2) -> Option<LightSample> {
    let v = center - x;
    let d2 = v.length_squared();
    let r2 = radius * radius;
    if d2 <= r2 {
        return None;
    }
    let d = d2.sqrt();
    let axis = v / d;
    let cos_max = (1.0 - r2 / d2).max(0.0).sqrt();
    let dir = uniform_cone(axis, cos_max, u);
    // Distance to the sphere along dir (the nearer root; clamped at the tangent).
    let b = dir.dot(v);
    let dist = b - (b * b - (d2 - r2)).max(0.0).sqrt();
    let solid_angle = 2.0 * PI * (1.0 - cos_max);
    Some(LightSample {
        dir,
        dist,
        value: radiance * solid_angle,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::core::{ray_box, Ray};
    use crate::sampling::Rng;

    fn boxes() -> [SceneBox; 3] {
        let b = |lo: [f32; 3], hi: [f32; 3]| SceneBox {
            lo: Vec3::from(lo),
            hi: Vec3::from(hi),
        };
        [
            b([0.0; 3], [1.0; 3]),
            // A floor under a cloud, as in the conformance scenes.
            b([-3.0, 0.0, -3.0], [3.0, 1.9, 3.0]),
            b([-10.0, 2.0, 0.5], [-9.9, 2.01, 40.0]),
        ]
    }

    /// Unit directions: random ones, the axes and directions a hair off them.
    fn directions() -> Vec<Vec3> {
        let mut rng = Rng::new(11, 0);
        let mut dirs: Vec<Vec3> = (0..400).map(|_| uniform_sphere(rng.vec2())).collect();
        for axis in [Vec3::X, Vec3::Y, Vec3::Z] {
            for s in [1.0, -1.0] {
                dirs.push(axis * s);
                dirs.push((axis * s + Vec3::splat(1e-4)).normalize());
            }
        }
        dirs
    }

    /// Every point of the box lies downstream of its window and projects inside it.
    #[test]
    fn window_covers_the_box_shadow() {
        let mut rng = Rng::new(12, 0);
        for scene in boxes() {
            for dir in directions() {
                let w = scene.window(dir);
                let corners = (0..8).map(|i| {
                    Vec3::select(
                        glam::BVec3::new(i & 1 != 0, i & 2 != 0, i & 4 != 0),
                        scene.hi,
                        scene.lo,
                    )
                });
                let inside = (0..50).map(|_| {
                    let u = Vec3::new(rng.f32(), rng.f32(), rng.f32());
                    scene.lo + (scene.hi - scene.lo) * u
                });
                for p in corners.chain(inside) {
                    let v = p - w.corner;
                    let a = v.dot(w.edges[0]) / w.edges[0].length_squared();
                    let b = v.dot(w.edges[1]) / w.edges[1].length_squared();
                    assert!(v.dot(dir) > 0.0, "{dir}: {p} upstream of the window");
                    assert!(
                        (0.0..=1.0).contains(&a) && (0.0..=1.0).contains(&b),
                        "{dir}: {p} projects to ({a}, {b})"
                    );
                }
            }
        }
    }

    /// No orientation of the rectangle gives a smaller one: the three candidates hold the
    /// smallest (rotating calipers), so 90 other rotations never beat it.
    #[test]
    fn window_is_the_smallest_rectangle() {
        for scene in boxes() {
            for dir in directions() {
                let w = scene.window(dir);
                let (t, _) = orthonormal_basis(dir);
                let margin = 1e-4 * (scene.hi - scene.lo).max_element() + 1e-4;
                for k in 0..90 {
                    let angle = k as f32 * std::f32::consts::PI / 180.0;
                    let s = t * angle.cos() + dir.cross(t) * angle.sin();
                    let (s0, s1) = scene.extent(s);
                    let (t0, t1) = scene.extent(dir.cross(s));
                    let area = (s1 - s0 + 2.0 * margin) * (t1 - t0 + 2.0 * margin);
                    assert!(w.area <= area * (1.0 + 1e-4), "{dir}: {} > {area}", w.area);
                }
            }
        }
    }

    /// A directional light's paths from its window bring the box the power it intercepts,
    /// E times the box's projected area across the light (|d.x| ly lz + |d.y| lx lz +
    /// |d.z| lx ly), within 4.5 standard errors of the hit count's binomial spread.
    #[test]
    fn window_emission_brings_the_box_its_power() {
        let irradiance = Vec3::new(2.0, 3.0, 4.0);
        let mut rng = Rng::new(13, 0);
        let n = 40_000;
        for scene in boxes() {
            for dir in directions().into_iter().step_by(40) {
                let light = Light::Directional {
                    direction: dir,
                    irradiance,
                };
                let mut hits = 0u32;
                let mut power = Vec3::ZERO;
                for _ in 0..n {
                    let e = light.emit(&scene, None, rng.vec2(), rng.vec2());
                    let r = Ray::new(e.origin, e.dir);
                    if ray_box(&r, &[scene.lo, scene.hi], 0.0, f32::INFINITY).is_some() {
                        hits += 1;
                        power += e.power;
                    }
                }
                let l = scene.hi - scene.lo;
                let d = dir.abs();
                let projected = d.x * l.y * l.z + d.y * l.x * l.z + d.z * l.x * l.y;
                let area = scene.window(dir).area;
                let p = hits as f32 / n as f32;
                let se = area * (p * (1.0 - p) / n as f32).sqrt();
                let got = power / n as f32 / irradiance;
                for c in 0..3 {
                    assert!(
                        (got[c] - projected).abs() <= 4.5 * se + 1e-4 * projected,
                        "{dir}: {} against {projected} (se {se})",
                        got[c]
                    );
                }
            }
        }
    }
}
