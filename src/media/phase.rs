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

/// 1 / (4 pi), as the Henyey-Greenstein formula rounds it at g = 0.
const ISOTROPIC_VALUE: f32 = 1.0 / (4.0 * PI * 1.0 * 1.0);

impl Phase {
    pub const ISOTROPIC: Phase = Phase { g: 0.0 };

    /// Phase function value (1/sr). Isotropic media skip the square root and division:
    /// they were a fifth of fog-box's pass (a dependent chain at every beam-pixel pair),
    /// and the formula gives this constant's bits at g = 0.
    pub fn eval(&self, cos_theta: f32) -> f32 {
        let g = self.g;
        if g == 0.0 {
            return ISOTROPIC_VALUE;
        }
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::Rng;

    /// The isotropic shortcut has the bits of the general formula at g = 0.
    #[test]
    fn isotropic_value_is_the_formula_at_g_zero() {
        let formula = |g: f32, cos: f32| {
            let denom = 1.0 + g * g - 2.0 * g * cos;
            (1.0 - g * g) / (4.0 * PI * denom * denom.max(1e-12).sqrt())
        };
        for g in [0.0f32, -0.0] {
            for i in 0..=200 {
                let cos = i as f32 / 100.0 - 1.0;
                assert_eq!(Phase { g }.eval(cos).to_bits(), formula(g, cos).to_bits());
            }
        }
        assert_eq!(Phase { g: 0.5 }.eval(0.3), formula(0.5, 0.3));
    }

    /// The density integrates to 1 over the sphere (midpoint rule in cos theta).
    #[test]
    fn normalized() {
        for g in [-0.7, 0.0, 0.3, 0.9] {
            let p = Phase { g };
            let n = 200_000;
            let integral: f64 = (0..n)
                .map(|i| {
                    let c = -1.0 + (i as f64 + 0.5) * 2.0 / n as f64;
                    2.0 * std::f64::consts::PI * p.eval(c as f32) as f64 * 2.0 / n as f64
                })
                .sum();
            assert!((integral - 1.0).abs() < 1e-3, "g={g}: {integral}");
        }
    }

    /// Sampled cosines against eval integrated over 40 bins: Pearson chi-square below the
    /// 99.9 % quantile of chi^2(39) = 72.05.
    #[test]
    fn sampling_matches_eval() {
        for g in [-0.5, 0.0, 0.7] {
            let p = Phase { g };
            let bins = 40;
            let n = 200_000;
            let mut counts = vec![0u32; bins];
            let mut rng = Rng::new(5, 9);
            for _ in 0..n {
                let c = p.sample_cos(rng.f32());
                let b = (((c + 1.0) * 0.5 * bins as f32) as usize).min(bins - 1);
                counts[b] += 1;
            }
            let chi2: f64 = (0..bins)
                .map(|b| {
                    let sub = 200;
                    let width = 2.0 / bins as f64;
                    let prob: f64 = (0..sub)
                        .map(|k| {
                            let c = -1.0 + width * (b as f64 + (k as f64 + 0.5) / sub as f64);
                            2.0 * std::f64::consts::PI * p.eval(c as f32) as f64 * width
                                / sub as f64
                        })
                        .sum();
                    let e = prob * n as f64;
                    (counts[b] as f64 - e).powi(2) / e
                })
                .sum();
            assert!(chi2 < 72.05, "g={g}: chi2 {chi2}");
        }
    }

    /// g > 0 scatters forward: sampled directions keep going along the photon's travel.
    #[test]
    fn positive_g_is_forward() {
        let p = Phase { g: 0.7 };
        let mut rng = Rng::new(1, 2);
        let d = Vec3::new(0.0, -1.0, 0.0);
        let mean: f32 = (0..20_000)
            .map(|_| p.sample(d, rng.f32(), rng.f32()).dot(d))
            .sum::<f32>()
            / 20_000.0;
        // The mean cosine of HG is g; sd of one cosine <= 1, 5 sigma = 0.035.
        assert!((mean - 0.7).abs() < 0.035, "{mean}");
    }
}
