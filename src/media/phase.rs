//! Henyey-Greenstein phase function. `cos_theta` is the cosine between the incoming
//! propagation direction and the outgoing propagation direction (1 = light keeps going),
//! so g > 0 is forward scattering, as in SPEC.md and Mitsuba's `hg`.
use glam::Vec3;
use std::f32::consts::PI;

use crate::sampling::orthonormal_basis;

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Phase {
    /// Mean cosine in (-1, 1); 0 is isotropic.
    pub g: f32,
}

impl Phase {
    pub const ISOTROPIC: Phase = Phase { g: 0.0 };

    /// Phase function value (1/sr).
    pub fn eval(&self, cos_theta: f32) -> f32 {
        let g = self.g;
        let denom = 1.0 + g * g - 2.0 * g * cos_theta;
        (1.0 - g * g) / (4.0 * PI * denom * denom.max(1e-12).sqrt())
    }

    /// Cosine of the scattering angle distributed as `eval` (exact inversion).
    pub fn sample_cos(&self, u: f32) -> f32 {
        let g = self.g;
        if g.abs() < 1e-3 {
            return 1.0 - 2.0 * u;
        }
        let s = (1.0 - g * g) / (1.0 - g + 2.0 * g * u);
        ((1.0 + g * g - s * s) / (2.0 * g)).clamp(-1.0, 1.0)
    }

    /// New propagation direction after scattering a photon travelling along `dir`.
    pub fn sample(&self, dir: Vec3, u1: f32, u2: f32) -> Vec3 {
        let cos = self.sample_cos(u1);
        let sin = (1.0 - cos * cos).max(0.0).sqrt();
        let phi = 2.0 * PI * u2;
        let (t, b) = orthonormal_basis(dir);
        (t * (sin * phi.cos()) + b * (sin * phi.sin()) + dir * cos).normalize()
    }
}
