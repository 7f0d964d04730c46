//! What each light kind does, in one place: its power, the start of a light path it emits,
//! a sample of it seen from a point (next-event estimation), where equiangular sampling
//! aims and what a ray leaving the scene sees of it. A new kind is a variant of
//! `scene::Light` and one arm in each method here.
//!
//! Lights at infinity (directional, environment) light the scene's bounding sphere
//! (`scene_center`, `scene_radius`): their light paths start on a disk of it facing the
//! direction they travel, whose area enters their power.
use glam::{Vec2, Vec3};
use std::f32::consts::PI;

use crate::core::Rgb;
use crate::geometry::EPS;
use crate::sampling::{
    cosine_hemisphere, orthonormal_basis, uniform_cone, uniform_disk, uniform_sphere,
};
use crate::scene::Light;

/// One emitted photon: where it starts, where it goes and its power (W).
pub struct Emission {
    pub origin: Vec3,
    pub dir: Vec3,
    pub power: Rgb,
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
    /// Total emitted power (W per channel); `scene_radius` bounds what a directional light lights.
    pub fn power(&self, scene_radius: f32) -> Rgb {
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
            Light::Directional { irradiance, .. } => irradiance * PI * scene_radius * scene_radius,
            Light::Sphere {
                radius, radiance, ..
            } => radiance * PI * 4.0 * PI * radius * radius,
            // pi R^2 of disk per unit solid angle, over the whole sphere of directions.
            Light::Environment(ref env) => env.integral() * PI * scene_radius * scene_radius,
        }
    }

    /// A light path's start: origin, direction and power (W; the light's whole power,
    /// for one path chosen with probability 1). A directional light emits over a disk of
    /// the scene's bounding sphere (`scene_center`, `scene_radius`) facing it.
    pub fn emit(&self, scene_center: Vec3, scene_radius: f32, u1: Vec2, u2: Vec2) -> Emission {
        let power = self.power(scene_radius);
        match *self {
            Light::Point { position, .. } => Emission {
                origin: position,
                dir: uniform_sphere(u1),
                power,
            },
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
            Light::Directional { direction, .. } => Emission {
                origin: disk_origin(direction, scene_center, scene_radius, u1),
                dir: direction,
                power,
            },
            // A direction drawn as next-event estimation draws it (by the map's luminance,
            // or uniformly), travelling the other way; the disk's pi R^2 times the radiance
            // over the direction's density.
            Light::Environment(ref env) => {
                let (towards, radiance, pdf) = env.sample(u2);
                let dir = -towards;
                Emission {
                    origin: disk_origin(dir, scene_center, scene_radius, u1),
                    dir,
                    power: radiance * (PI * scene_radius * scene_radius / pdf),
                }
            }
            Light::Sphere { center, radius, .. } => {
                let n = uniform_sphere(u1);
                Emission {
                    origin: center + n * (radius + EPS),
                    dir: cosine_hemisphere(n, u2),
                    power,
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

/// A uniform point of the disk of the scene's bounding sphere that faces direction of
/// travel `dir`, just outside the sphere.
fn disk_origin(dir: Vec3, scene_center: Vec3, scene_radius: f32, u: Vec2) -> Vec3 {
    let (t, b) = orthonormal_basis(dir);
    let d = uniform_disk(u) * scene_radius;
    scene_center - dir * scene_radius * 1.01 + t * d.x + b * d.y
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
