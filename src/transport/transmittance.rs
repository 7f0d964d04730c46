//! Camera-segment transmittance through the density grids, estimated per pass from M free
//! paths (the paper's progressive deep shadow map): Tr(t) = the fraction of the M free
//! paths longer than t. Unbiased for exp(-integral of the grids' sigma_t) at every t; the
//! homogeneous media's share is exact and multiplied in by the caller.
use crate::geometry::Ray;
use crate::sampling::Rng;
use crate::transport::freepath::FreePath;
use crate::transport::Counters;

/// Most free paths per camera segment (`--tr-samples`).
pub const MAX_TR_SAMPLES: usize = 16;
/// Default free paths per camera segment per pass (M in the paper).
pub const DEFAULT_TR_SAMPLES: usize = 4;

/// M free-path lengths along one camera segment (infinite: the path got through).
#[derive(Clone, Copy, Debug)]
pub struct GridTr {
    lengths: [f32; MAX_TR_SAMPLES],
    m: u8,
}

impl GridTr {
    /// Transmittance 1 everywhere (no grid on the segment).
    pub const CLEAR: GridTr = GridTr {
        lengths: [f32::INFINITY; MAX_TR_SAMPLES],
        m: 1,
    };

    /// Draws `m` grid free paths along `ray` up to `tmax`.
    pub fn sample(
        fp: &dyn FreePath,
        ray: &Ray,
        tmax: f32,
        m: usize,
        rng: &mut Rng,
        c: &mut Counters,
    ) -> GridTr {
        let m = m.clamp(1, MAX_TR_SAMPLES);
        let mut lengths = [f32::INFINITY; MAX_TR_SAMPLES];
        for l in lengths.iter_mut().take(m) {
            c.free_paths += 1;
            *l = fp.sample_grids(ray, tmax, rng, c).unwrap_or(f32::INFINITY);
        }
        GridTr {
            lengths,
            m: m as u8,
        }
    }

    /// Estimated grid transmittance from the segment start to `t`.
    pub fn eval(&self, t: f32) -> f32 {
        let m = self.m as usize;
        let alive = self.lengths[..m].iter().filter(|&&l| l > t).count();
        alive as f32 / m as f32
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::media::grid::GridBuilder;
    use crate::media::{GridMedium, Media, Phase};
    use crate::transport::freepath::Woodcock;
    use glam::{DAffine3, IVec3, Vec3};
    use std::sync::Arc;

    /// A grid whose density ramps along x, so transmittance is not exponential in t.
    pub(crate) fn ramp_media() -> Media {
        let mut b = GridBuilder::new(
            "density",
            0.0,
            DAffine3::from_scale(glam::DVec3::splat(0.1)),
        );
        for i in 0..20 {
            for j in 0..20 {
                for k in 0..20 {
                    let v = (i as f32 / 19.0) * (1.0 + 0.5 * ((j + k) % 3) as f32);
                    b.set(IVec3::new(i, j, k), v, true);
                }
            }
        }
        let g = GridMedium::new(
            Arc::new(b.finish()),
            DAffine3::IDENTITY,
            2.0,
            Vec3::ONE,
            Phase::ISOTROPIC,
            "ramp".into(),
            [0; 32],
        );
        Media::with_grids(vec![], vec![g])
    }

    /// Quadrature of the grid's transmittance along `ray` on [0, tmax]: cumulative optical
    /// depth on 30 000 midpoint steps, interpolated linearly.
    pub(crate) struct QuadTr {
        tau: Vec<f64>,
        h: f64,
    }

    impl QuadTr {
        pub(crate) fn new(media: &Media, ray: &Ray, tmax: f32) -> Self {
            let n = 30_000;
            let h = tmax as f64 / n as f64;
            let mut tau = vec![0.0f64; n + 1];
            for i in 0..n {
                let s = media.grid_sigma_t(ray.at(((i as f64 + 0.5) * h) as f32)) as f64;
                tau[i + 1] = tau[i] + s * h;
            }
            QuadTr { tau, h }
        }

        pub(crate) fn tr(&self, t: f32) -> f64 {
            let x = (t as f64 / self.h).clamp(0.0, (self.tau.len() - 1) as f64);
            let i = (x as usize).min(self.tau.len() - 2);
            let f = x - i as f64;
            (-(self.tau[i] * (1.0 - f) + self.tau[i + 1] * f)).exp()
        }
    }

    #[test]
    fn deep_shadow_mean_matches_quadrature() {
        let media = ramp_media();
        let fp = Woodcock { media: &media };
        let ray = Ray::new(
            Vec3::new(-0.5, 0.93, 1.02),
            Vec3::new(1.0, 0.05, 0.02).normalize(),
        );
        let mut rng = Rng::new(9, 9);
        let mut c = Counters::default();
        let n = 20_000;
        let quad = QuadTr::new(&media, &ray, 3.0);
        for t in [0.8f32, 1.6, 2.4] {
            let truth = quad.tr(t);
            let mean: f64 = (0..n)
                .map(|_| GridTr::sample(&fp, &ray, 3.0, 4, &mut rng, &mut c).eval(t) as f64)
                .sum::<f64>()
                / n as f64;
            // Each estimate is a mean of 4 Bernoulli(Tr): sd sqrt(Tr(1-Tr)/4).
            let se = (truth * (1.0 - truth) / 4.0 / n as f64).sqrt();
            assert!(
                (mean - truth).abs() < 5.0 * se + 1e-4,
                "t={t}: {mean} vs {truth}"
            );
        }
        assert!(c.density_lookups > 0);
    }

    #[test]
    fn woodcock_free_paths_match_quadrature() {
        let media = ramp_media();
        let fp = Woodcock { media: &media };
        let ray = Ray::new(
            Vec3::new(-0.5, 0.93, 1.02),
            Vec3::new(1.0, 0.05, 0.02).normalize(),
        );
        let mut rng = Rng::new(4, 4);
        let mut c = Counters::default();
        let n = 20_000;
        let tmax = 3.0;
        let mut s: Vec<f32> = (0..n)
            .map(|_| {
                fp.sample(&ray, tmax, &mut rng, &mut c)
                    .unwrap_or(f32::INFINITY)
            })
            .collect();
        let quad = QuadTr::new(&media, &ray, tmax);
        let (d, esc) = crate::transport::freepath::tests::ks_against(&mut s, |t| quad.tr(t), tmax);
        assert!(d < 1.95 / (n as f64).sqrt(), "KS D = {d}");
        let p = quad.tr(tmax);
        assert!(esc.abs() < 5.0 * (p * (1.0 - p) / n as f64).sqrt() + 1e-3);
    }
}

#[cfg(test)]
mod adaptive_tests {
    use super::tests::{ramp_media, QuadTr};
    use super::*;
    use crate::majorant::Octree;
    use crate::transport::freepath::tests::ks_against;
    use crate::transport::freepath::{Adaptive, Woodcock};
    use glam::Vec3;

    /// Adaptive free paths follow the quadrature transmittance (KS, 0.1 % level), and
    /// match Woodcock's in a two-sample KS test (critical value 1.95 sqrt(2/n) at 0.1 %),
    /// with fewer density lookups.
    #[test]
    fn adaptive_matches_woodcock_and_quadrature() {
        let media = ramp_media();
        let trees: Vec<Octree> = media.grids.iter().map(|g| Octree::build(g, 5)).collect();
        let adaptive = Adaptive {
            media: &media,
            octrees: &trees,
        };
        let woodcock = Woodcock { media: &media };
        let ray = Ray::new(
            Vec3::new(-0.5, 0.93, 1.02),
            Vec3::new(1.0, 0.05, 0.02).normalize(),
        );
        let (n, tmax) = (20_000, 3.0);
        let draw = |fp: &dyn FreePath, seed: u64, c: &mut Counters| {
            let mut rng = Rng::new(seed, 3);
            (0..n)
                .map(|_| fp.sample(&ray, tmax, &mut rng, c).unwrap_or(f32::INFINITY))
                .collect::<Vec<f32>>()
        };
        let (mut ca, mut cw) = (Counters::default(), Counters::default());
        let mut a = draw(&adaptive, 1, &mut ca);
        let mut w = draw(&woodcock, 2, &mut cw);
        let quad = QuadTr::new(&media, &ray, tmax);
        let (d, esc) = ks_against(&mut a, |t| quad.tr(t), tmax);
        assert!(d < 1.95 / (n as f64).sqrt(), "KS vs quadrature {d}");
        let p = quad.tr(tmax);
        assert!(esc.abs() < 5.0 * (p * (1.0 - p) / n as f64).sqrt() + 1e-3);
        // Two-sample KS: largest gap of the empirical CDFs at every finite sample.
        w.sort_by(f32::total_cmp);
        let cdf = |s: &[f32], x: f32| s.partition_point(|&v| v <= x) as f64 / n as f64;
        let d2 = a
            .iter()
            .chain(w.iter())
            .filter(|x| x.is_finite())
            .map(|&x| (cdf(&a, x) - cdf(&w, x)).abs())
            .fold(0.0f64, f64::max);
        assert!(d2 < 1.95 * (2.0 / n as f64).sqrt(), "two-sample KS {d2}");
        assert!(ca.density_lookups < cw.density_lookups);
    }
}
