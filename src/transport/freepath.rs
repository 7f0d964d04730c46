//! Free-path sampling behind one interface: a sampler returns the distance to the next
//! real collision along a ray (or none before `tmax`) and the transmittance of an interval.
//! Homogeneous media are sampled exactly, piece by piece (the paper's eq. 4).
use crate::geometry::Ray;
use crate::media::Media;
use crate::sampling::Rng;
use crate::transport::Counters;

pub trait FreePath: Sync {
    /// Distance to the next collision in (0, tmax), or None if the ray gets through.
    fn sample(&self, ray: &Ray, tmax: f32, rng: &mut Rng, c: &mut Counters) -> Option<f32>;
    /// Transmittance between t0 and t1 along the ray.
    fn transmittance(&self, ray: &Ray, t0: f32, t1: f32) -> f32;
}

/// Exact sampling of piecewise-constant extinction: draw an optical depth -ln(1-u) and walk
/// the constant pieces until it is used up.
pub struct Analytic<'a> {
    pub media: &'a Media,
}

impl FreePath for Analytic<'_> {
    fn sample(&self, ray: &Ray, tmax: f32, rng: &mut Rng, c: &mut Counters) -> Option<f32> {
        c.free_paths += 1;
        let segs = self.media.segments(ray, tmax);
        let mut tau = -(1.0 - rng.f32()).ln();
        for s in &segs {
            let depth = s.sigma_t * (s.t1 - s.t0);
            if tau < depth {
                return Some(s.t0 + tau / s.sigma_t);
            }
            tau -= depth;
        }
        None
    }

    fn transmittance(&self, ray: &Ray, t0: f32, t1: f32) -> f32 {
        (-self.media.optical_depth(ray, t0, t1)).exp()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::media::{MediumDesc, Phase};
    use glam::Vec3;

    /// Free-path CDF against the analytic transmittance across two overlapping boxes:
    /// Kolmogorov-Smirnov statistic below the 0.1% critical value 1.95/sqrt(n).
    #[test]
    fn free_paths_follow_transmittance() {
        let media = Media::new(vec![
            MediumDesc {
                bounds: [Vec3::splat(-1.0), Vec3::splat(1.0)],
                sigma_t: 0.7,
                albedo: Vec3::ONE,
                phase: Phase::ISOTROPIC,
            },
            MediumDesc {
                bounds: [Vec3::new(0.0, -1.0, -1.0), Vec3::new(2.0, 1.0, 1.0)],
                sigma_t: 1.3,
                albedo: Vec3::ONE,
                phase: Phase::ISOTROPIC,
            },
        ]);
        let fp = Analytic { media: &media };
        let ray = Ray::new(Vec3::new(-2.0, 0.1, 0.2), Vec3::X);
        let tmax = 5.0;
        let n = 20_000;
        let mut rng = Rng::new(42, 1);
        let mut c = Counters::default();
        let mut samples: Vec<f32> = (0..n)
            .map(|_| {
                fp.sample(&ray, tmax, &mut rng, &mut c)
                    .unwrap_or(f32::INFINITY)
            })
            .collect();
        samples.sort_by(f32::total_cmp);
        let mut d_max = 0.0f64;
        for (i, &t) in samples.iter().enumerate() {
            let cdf = if t.is_finite() {
                1.0 - fp.transmittance(&ray, 0.0, t) as f64
            } else {
                1.0 - fp.transmittance(&ray, 0.0, tmax) as f64
            };
            let emp_hi = (i + 1) as f64 / n as f64;
            let emp_lo = i as f64 / n as f64;
            if t.is_finite() {
                d_max = d_max.max((emp_hi - cdf).abs()).max((emp_lo - cdf).abs());
            }
        }
        assert!(d_max < 1.95 / (n as f64).sqrt(), "KS D = {d_max}");
        // Escape probability equals the total transmittance (binomial 5 sigma).
        let escaped = samples.iter().filter(|t| !t.is_finite()).count() as f64 / n as f64;
        let tr = fp.transmittance(&ray, 0.0, tmax) as f64;
        assert!((escaped - tr).abs() < 5.0 * (tr * (1.0 - tr) / n as f64).sqrt());
    }
}
