//! Camera-segment transmittance through the density grids, one estimate per segment per
//! pass (the homogeneous media's share is exact and multiplied in by the caller). Three
//! estimators, all unbiased for exp(-integral of the grids' sigma_t) at every distance t:
//! - random: the progressive deep shadow map, Tr(t) = fraction of M free paths longer
//!   than t;
//! - stratified (the paper's sec. 4.3): the free paths of a block of N passes are drawn at
//!   once per pixel, sorted into M strata of N/M, and every pass uses one not yet used path
//!   of each stratum, in an order drawn per cycle of N/M passes so that what a pass uses
//!   follows from its index alone (primary segments; later segments use random);
//! - ratio: ratio tracking (Novak et al. 2014) along the octree's local majorants, a
//!   continuous estimate Tr(t) = product over tentative collisions before t of
//!   (1 - sigma_t(x) / (M majorant)): one tracking at M times the majorant, as many
//!   lookups as M trackings. One estimate weights every beam crossing of its segment in a
//!   pass, so its noise is shared by all of them. Its variance, T^2 (exp(X / M) - 1) with
//!   X the integral of sigma_t^2 / majorant, is below that of M trackings averaged,
//!   T^2 (exp(X) - 1) / M (what this estimator was before: at 40 passes cloud-hg's noise
//!   per pixel fell 6 % and smoke-grid's tracking time a quarter; docs/benchmarks.md,
//!   "Denser ratio tracking"). M = 4 stayed best at equal time against 2 and 8.
use smallvec::SmallVec;

use crate::core::Ray;
use crate::media::Chords;
use crate::sampling::Rng;
use crate::settings::MAX_TR_SAMPLES;
use crate::transport::freepath::{FreePath, RatioSteps, Walk};
use crate::transport::Counters;

/// One pass's estimate of the grids' transmittance along one camera segment.
#[derive(Clone, Debug)]
pub enum SegmentTr {
    /// No grid on the segment.
    Clear,
    /// M free-path lengths (infinite: the path got through).
    FreePaths {
        lengths: [f32; MAX_TR_SAMPLES],
        m: u8,
    },
    /// Tr after each tentative collision, sorted by t.
    Ratio(RatioSteps),
}

impl SegmentTr {
    /// Draws `m` grid free paths along `ray` up to `tmax`.
    pub fn random(
        fp: &FreePath,
        ray: &Ray,
        tmax: f32,
        m: usize,
        rng: &mut Rng,
        c: &mut Counters,
    ) -> SegmentTr {
        let m = m.clamp(1, MAX_TR_SAMPLES);
        let mut lengths = [f32::INFINITY; MAX_TR_SAMPLES];
        let walks = fp.walks(ray, tmax, c);
        for l in lengths.iter_mut().take(m) {
            c.free_paths += 1;
            let t = fp.sample_grids_over(ray, tmax, Some(&walks), rng, c);
            *l = t.unwrap_or(f32::INFINITY);
        }
        SegmentTr::FreePaths {
            lengths,
            m: m as u8,
        }
    }

    /// One ratio tracking along `ray` up to `tmax` at `m` times the local majorants, as
    /// a step function.
    pub fn ratio(
        fp: &FreePath,
        ray: &Ray,
        tmax: f32,
        m: usize,
        rng: &mut Rng,
        c: &mut Counters,
    ) -> SegmentTr {
        let walks = fp.walks(ray, tmax, c);
        SegmentTr::ratio_over(fp, ray, &walks, m, rng, c)
    }

    /// [`Self::ratio`] over the grids' walks along `ray` ([`FreePath::walks`]), made
    /// before for this and other uses of the segment. Each grid's factors come in order
    /// of t; with several grids they are merged before the product is taken.
    pub fn ratio_over(
        fp: &FreePath,
        ray: &Ray,
        walks: &[Walk],
        m: usize,
        rng: &mut Rng,
        c: &mut Counters,
    ) -> SegmentTr {
        let rate = m.clamp(1, MAX_TR_SAMPLES) as f32;
        let mut steps = RatioSteps::new();
        fp.ratio_steps(ray, walks, rate, rng, c, &mut steps);
        if walks.len() > 1 {
            steps.sort_by(|a, b| a.0.total_cmp(&b.0));
        }
        let mut tr = 1.0f32;
        for s in steps.iter_mut() {
            tr *= s.1;
            s.1 = tr;
        }
        SegmentTr::Ratio(steps)
    }

    /// Estimated grid transmittance from the segment start to `t`. A step applies after
    /// its t, as in [`Self::steps`] (what the GPU reads): a free path that ends exactly at
    /// t still reaches t, a ratio step exactly at t is not yet taken.
    pub fn eval(&self, t: f32) -> f32 {
        match self {
            SegmentTr::Clear => 1.0,
            SegmentTr::FreePaths { lengths, m } => {
                let m = *m as usize;
                lengths[..m].iter().filter(|&&l| l >= t).count() as f32 / m as f32
            }
            SegmentTr::Ratio(steps) => {
                let i = steps.partition_point(|s| s.0 < t);
                if i == 0 {
                    1.0
                } else {
                    steps[i - 1].1
                }
            }
        }
    }

    /// Where the estimate falls to 0 for good: it is 0 at every t past this (infinite
    /// when it never is). Beam crossings and light samples past it weigh nothing, so
    /// the estimates leave them out.
    pub fn zero_from(&self) -> f32 {
        match self {
            SegmentTr::Clear => f32::INFINITY,
            SegmentTr::FreePaths { lengths, m } => {
                lengths[..*m as usize].iter().copied().fold(0.0, f32::max)
            }
            SegmentTr::Ratio(steps) => steps
                .iter()
                .find(|s| s.1 == 0.0)
                .map_or(f32::INFINITY, |s| s.0),
        }
    }

    /// The part of a segment [0, t_surf) where the estimate can be above 0: it ends just
    /// past [`Self::zero_from`] (a ratio step applies after its t, so the estimate at
    /// that t itself is not yet 0).
    pub fn seen_until(&self, t_surf: f32) -> f32 {
        t_surf.min(self.zero_from().next_up())
    }

    /// The estimate as a step function: (t_k, value for t > t_k), t_k ascending, appended
    /// to `out` (before the first step the value is 1). What the GPU estimate reads.
    pub fn steps(&self, out: &mut Vec<[f32; 2]>) {
        match self {
            SegmentTr::Clear => {}
            SegmentTr::FreePaths { lengths, m } => {
                let m = *m as usize;
                let mut finite: SmallVec<[f32; MAX_TR_SAMPLES]> = lengths[..m]
                    .iter()
                    .copied()
                    .filter(|l| l.is_finite())
                    .collect();
                finite.sort_by(f32::total_cmp);
                for (k, &l) in finite.iter().enumerate() {
                    out.push([l, (m - k - 1) as f32 / m as f32]);
                }
            }
            SegmentTr::Ratio(steps) => out.extend(steps.iter().map(|&(t, v)| [t, v])),
        }
    }
}

/// Per-pixel free paths of the current stratified block.
pub struct StratStore {
    /// Free paths per pixel per block (N).
    pub n: usize,
    /// Strata (M).
    pub m: usize,
    /// Block whose paths are stored, if any.
    pub block: Option<u32>,
    /// Cycle (key of its random stream) whose order the strata are shuffled in.
    pub cycle: Option<u32>,
    paths: Vec<f32>,
}

/// One pixel's share of the store and where this pass stands in its block.
///
/// Each of the M strata holds q = N/M sorted paths; every q passes (a cycle) use each of
/// them once, in an order drawn from the cycle's own random stream. What a pass picks
/// therefore depends on its index alone, not on which passes ran before it.
pub struct StratPixel<'a> {
    pub paths: &'a mut [f32],
    /// Draw this block's paths before use.
    pub regenerate: bool,
    /// Shuffle the strata into this cycle's order before use.
    pub reshuffle: bool,
    /// Random stream of the block (draws the paths).
    pub block_rng: Rng,
    /// Random stream of the cycle (the order in which its passes use each stratum).
    pub cycle_rng: Rng,
    /// This pass's position in its cycle, 0..q.
    pub slot: usize,
}

impl StratStore {
    pub fn new(pixels: usize, n: usize, m: usize) -> Self {
        StratStore {
            n,
            m,
            block: None,
            cycle: None,
            paths: vec![f32::INFINITY; pixels * n],
        }
    }

    /// Rows of per-pixel paths for parallel camera passes.
    pub fn rows_mut(&mut self, width: usize) -> Vec<&mut [f32]> {
        self.paths.chunks_mut(width * self.n).collect()
    }

    /// Passes per cycle (q = N/M).
    pub fn cycle(&self) -> usize {
        self.n / self.m
    }
}

impl StratPixel<'_> {
    /// This pass's M lengths: in each stratum, the path at this pass's slot of the cycle's
    /// random order. At a cycle's first pass each stratum is put back in sorted order and
    /// shuffled (Fisher-Yates) from the cycle's stream, so the order follows from the
    /// cycle alone; the other passes of the cycle only read it.
    pub fn pick(
        &mut self,
        fp: &FreePath,
        ray: &Ray,
        tmax: f32,
        m: usize,
        c: &mut Counters,
    ) -> SegmentTr {
        if self.regenerate {
            let walks = fp.walks(ray, tmax, c);
            for p in self.paths.iter_mut() {
                c.free_paths += 1;
                *p = fp
                    .sample_grids_over(ray, tmax, Some(&walks), &mut self.block_rng, c)
                    .unwrap_or(f32::INFINITY);
            }
            self.paths.sort_by(f32::total_cmp);
        }
        let q = self.paths.len() / m;
        if self.regenerate || self.reshuffle {
            for stratum in self.paths.chunks_mut(q).take(m) {
                stratum.sort_by(f32::total_cmp);
                for i in (1..q).rev() {
                    let j = ((self.cycle_rng.f32() * (i + 1) as f32) as usize).min(i);
                    stratum.swap(i, j);
                }
            }
        }
        let mut lengths = [f32::INFINITY; MAX_TR_SAMPLES];
        for (s, l) in lengths.iter_mut().take(m).enumerate() {
            *l = self.paths[s * q + self.slot.min(q - 1)];
        }
        SegmentTr::FreePaths {
            lengths,
            m: m as u8,
        }
    }
}

/// The camera-transmittance factor of eq. 2: transmittance from the origin of a camera
/// segment to t, the homogeneous media's exact exp(-tau) (from their `chords` along the
/// segment's ray) times this pass's estimate `grids` of the density grids' share
/// (`SegmentTr::eval`).
#[inline]
pub fn camera_tr(chords: &Chords, grids: &SegmentTr, t: f32) -> f32 {
    (-chords.optical_depth(t)).exp() * grids.eval(t)
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::majorant::Mode;
    use crate::media::grid::GridBuilder;
    use crate::media::{GridMedium, Heterogeneous, Media, Phase};
    use crate::transport::freepath::FreePath;
    use glam::{DAffine3, IVec3, Vec3};
    use std::sync::Arc;

    /// A grid whose density ramps along x, so transmittance is not exponential in t.
    pub(crate) fn ramp_media() -> Media {
        ramp_media_with(0.0, 2.0)
    }

    /// 20^3 voxels of (offset + i / 19) x (1 to 2 by (j + k) mod 3), 0.1 m apart.
    pub(crate) fn ramp_media_with(offset: f32, density_scale: f32) -> Media {
        let mut b = GridBuilder::new(
            "density",
            0.0,
            DAffine3::from_scale(glam::DVec3::splat(0.1)),
        );
        for i in 0..20 {
            for j in 0..20 {
                for k in 0..20 {
                    let v = (offset + i as f32 / 19.0) * (1.0 + 0.5 * ((j + k) % 3) as f32);
                    b.set(IVec3::new(i, j, k), v, true);
                }
            }
        }
        let g = GridMedium::new(
            Arc::new(b.finish()),
            DAffine3::IDENTITY,
            density_scale,
            Vec3::ONE,
            Phase::ISOTROPIC,
            "ramp".into(),
            [0; 32],
        );
        Media::with_grids(vec![], vec![Heterogeneous::build(g, 5)])
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
        let fp = FreePath {
            media: &media,
            mode: Mode::Woodcock,
        };
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
                .map(|_| SegmentTr::random(&fp, &ray, 3.0, 4, &mut rng, &mut c).eval(t) as f64)
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
        let fp = FreePath {
            media: &media,
            mode: Mode::Woodcock,
        };
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
    use super::tests::{ramp_media, ramp_media_with, QuadTr};
    use super::*;
    use crate::majorant::Mode;
    use crate::transport::freepath::tests::ks_against;
    use crate::transport::freepath::FreePath;
    use glam::Vec3;

    /// Adaptive free paths follow the quadrature transmittance (KS, 0.1 % level), and
    /// match Woodcock's in a two-sample KS test (critical value 1.95 sqrt(2/n) at 0.1 %),
    /// with fewer density lookups.
    #[test]
    fn adaptive_matches_woodcock_and_quadrature() {
        let media = ramp_media();
        let adaptive = FreePath {
            media: &media,
            mode: Mode::Adaptive,
        };
        let woodcock = FreePath {
            media: &media,
            mode: Mode::Woodcock,
        };
        let ray = Ray::new(
            Vec3::new(-0.5, 0.93, 1.02),
            Vec3::new(1.0, 0.05, 0.02).normalize(),
        );
        let (n, tmax) = (20_000, 3.0);
        let draw = |fp: &FreePath, seed: u64, c: &mut Counters| {
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

    /// Where leaves have positive minorants, collisions decided without a lookup leave the
    /// free paths following the quadrature transmittance (KS at 0.1 %).
    #[test]
    fn minorant_accepts_keep_free_paths_exact() {
        let media = ramp_media_with(1.0, 20.0);
        let adaptive = FreePath {
            media: &media,
            mode: Mode::Adaptive,
        };
        let ray = Ray::new(
            Vec3::new(0.15, 0.93, 1.02),
            Vec3::new(1.0, 0.05, 0.02).normalize(),
        );
        let (n, tmax) = (20_000, 0.4);
        let mut c = Counters::default();
        let mut rng = Rng::new(5, 3);
        let mut a: Vec<f32> = (0..n)
            .map(|_| {
                adaptive
                    .sample(&ray, tmax, &mut rng, &mut c)
                    .unwrap_or(f32::INFINITY)
            })
            .collect();
        let quad = QuadTr::new(&media, &ray, tmax);
        let (d, _) = ks_against(&mut a, |t| quad.tr(t), tmax);
        assert!(d < 1.95 / (n as f64).sqrt(), "KS vs quadrature {d}");
        assert!(
            c.minorant_accepts > c.free_paths / 4,
            "{} lookup-free collisions in {} free paths",
            c.minorant_accepts,
            c.free_paths
        );
    }
}

#[cfg(test)]
mod estimator_tests {
    use super::tests::{ramp_media, QuadTr};
    use super::*;
    use crate::majorant::Mode;
    use crate::transport::freepath::FreePath;
    use glam::Vec3;

    fn setup() -> (crate::media::Media, Ray) {
        let media = ramp_media();
        let ray = Ray::new(
            Vec3::new(-0.5, 0.93, 1.02),
            Vec3::new(1.0, 0.05, 0.02).normalize(),
        );
        (media, ray)
    }

    /// Ratio tracking averages to the quadrature transmittance at several distances
    /// (bound: 5 standard errors of the sample mean).
    #[test]
    fn ratio_tracking_is_unbiased() {
        let (media, ray) = setup();
        let fp = FreePath {
            media: &media,
            mode: Mode::Adaptive,
        };
        let quad = QuadTr::new(&media, &ray, 3.0);
        let mut rng = Rng::new(21, 1);
        let mut c = Counters::default();
        let n = 20_000;
        let est: Vec<SegmentTr> = (0..n)
            .map(|_| SegmentTr::ratio(&fp, &ray, 3.0, 1, &mut rng, &mut c))
            .collect();
        for t in [0.7f32, 1.5, 2.3, 2.9] {
            let v: Vec<f64> = est.iter().map(|e| e.eval(t) as f64).collect();
            let mean = v.iter().sum::<f64>() / n as f64;
            let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
            let truth = quad.tr(t);
            assert!(
                (mean - truth).abs() < 5.0 * (var / n as f64).sqrt() + 1e-4,
                "t={t}: {mean} vs {truth}"
            );
        }
    }

    /// Where the transmittance falls below 0.001, ratio tracking with its roulette
    /// ([`crate::transport::freepath::roulette`]) still averages to the quadrature, for the
    /// camera's step estimate and for shadow rays (5 standard errors of the sample mean),
    /// and the roulette ends most trackings before the far end (without it, a product is
    /// 0 only where a lookup meets its leaf's majorant exactly).
    #[test]
    fn ratio_tracking_with_roulette_is_unbiased_where_light_is_nearly_gone() {
        let media = super::tests::ramp_media_with(0.0, 5.0);
        let ray = setup().1;
        let fp = FreePath {
            media: &media,
            mode: Mode::Adaptive,
        };
        let tmax = 3.0;
        let quad = QuadTr::new(&media, &ray, tmax);
        assert!(quad.tr(tmax) < 0.001, "{}", quad.tr(tmax));
        let mut rng = Rng::new(41, 1);
        let mut c = Counters::default();
        let n = 40_000;
        let est: Vec<SegmentTr> = (0..n)
            .map(|_| SegmentTr::ratio(&fp, &ray, tmax, 1, &mut rng, &mut c))
            .collect();
        let mean_se = |v: &[f64]| {
            let mean = v.iter().sum::<f64>() / n as f64;
            let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
            (mean, (var / n as f64).sqrt())
        };
        for t in [1.2f32, 1.8, 2.4, 3.0] {
            let truth = quad.tr(t);
            let (mean, se) = mean_se(&est.iter().map(|e| e.eval(t) as f64).collect::<Vec<_>>());
            assert!(
                (mean - truth).abs() < 5.0 * se + 1e-5,
                "steps t={t}: {mean} vs {truth}"
            );
            let shadow: Vec<f64> = (0..n)
                .map(|_| fp.transmittance(&ray, t, &mut rng, &mut c) as f64)
                .collect();
            let (mean, se) = mean_se(&shadow);
            assert!(
                (mean - truth).abs() < 5.0 * se + 1e-5,
                "shadow t={t}: {mean} vs {truth}"
            );
        }
        let ended = est.iter().filter(|e| e.zero_from() < tmax).count();
        assert!(
            ended > n / 2,
            "{ended} of {n} trackings ended by the roulette"
        );
    }

    /// Past `zero_from` every estimate is 0 and at it not yet (ratio steps apply after
    /// their t, free paths reach their own end), so `seen_until` drops only crossings
    /// that weigh nothing.
    #[test]
    fn estimates_are_zero_exactly_past_zero_from() {
        let media = super::tests::ramp_media_with(0.0, 4.0);
        let ray = setup().1;
        let fp = FreePath {
            media: &media,
            mode: Mode::Adaptive,
        };
        let mut rng = Rng::new(43, 1);
        let mut c = Counters::default();
        let (mut ended, tmax) = (0, 3.0);
        for k in 0..4000 {
            let e = if k % 2 == 0 {
                SegmentTr::ratio(&fp, &ray, tmax, 4, &mut rng, &mut c)
            } else {
                SegmentTr::random(&fp, &ray, tmax, 4, &mut rng, &mut c)
            };
            let z = e.zero_from();
            let mut steps = Vec::new();
            e.steps(&mut steps);
            if z.is_finite() {
                ended += 1;
                assert!(e.eval(z) > 0.0 && e.eval(z.next_up()) == 0.0, "{e:?}");
                assert_eq!(e.seen_until(f32::INFINITY), z.next_up());
                assert!(steps.iter().all(|s| s[0] <= z || s[1] == 0.0), "{e:?}");
            } else {
                assert!(steps.iter().all(|s| s[1] > 0.0), "{e:?}");
                assert_eq!(e.seen_until(tmax), tmax);
            }
        }
        assert!(ended > 1000, "{ended}");
    }

    /// One ratio tracking at M = 4 times the majorant is unbiased at several distances (5
    /// standard errors of the sample mean), and its variance is at most a quarter of one
    /// tracking's at the majorant, which is what 4 trackings averaged would give:
    /// T^2 (exp(X / 4) - 1) <= T^2 (exp(X) - 1) / 4, X the integral of sigma_t^2 /
    /// majorant. So 4 var_4 - var_1 stays below 5 standard errors (each variance's from its
    /// sample fourth moment), and past mid-segment, where X has grown, it is below -5 of
    /// them.
    #[test]
    fn denser_ratio_tracking_beats_the_mean_of_as_many() {
        let (media, ray) = setup();
        let fp = FreePath {
            media: &media,
            mode: Mode::Adaptive,
        };
        let quad = QuadTr::new(&media, &ray, 3.0);
        let mut c = Counters::default();
        let n = 20_000;
        let draw = |m: usize, seed: u64, c: &mut Counters| {
            let mut rng = Rng::new(seed, 2);
            (0..n)
                .map(|_| SegmentTr::ratio(&fp, &ray, 3.0, m, &mut rng, c))
                .collect::<Vec<_>>()
        };
        let (one, four) = (draw(1, 31, &mut c), draw(4, 32, &mut c));
        // Sample mean, variance and the standard error of that variance.
        let moments = |v: &[f64]| {
            let k = v.len() as f64;
            let mean = v.iter().sum::<f64>() / k;
            let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (k - 1.0);
            let m4 = v.iter().map(|x| (x - mean).powi(4)).sum::<f64>() / k;
            (mean, var, ((m4 - var * var) / k).max(0.0).sqrt())
        };
        for t in [0.7f32, 1.5, 2.3] {
            let at = |e: &[SegmentTr]| e.iter().map(|s| s.eval(t) as f64).collect::<Vec<_>>();
            let (m1, v1, s1) = moments(&at(&one));
            let (m4, v4, s4) = moments(&at(&four));
            let truth = quad.tr(t);
            for (m, v) in [(m1, v1), (m4, v4)] {
                let bound = 5.0 * (v / n as f64).sqrt() + 1e-4;
                assert!((m - truth).abs() < bound, "t={t}: {m} vs {truth}");
            }
            let gap = 4.0 * v4 - v1;
            let se = (16.0 * s4 * s4 + s1 * s1).sqrt();
            let below = if t > 1.0 { -5.0 * se } else { 5.0 * se };
            assert!(
                v1 > 1e-4 && gap < below,
                "t={t}: var_1 {v1}, var_4 {v4} (se {s1}, {s4})"
            );
        }
    }

    /// Per pass estimates of one pixel over blocks of N = 64 passes: stratified is
    /// unbiased and its per-pass squared error is below random's. Blocks are independent,
    /// so each estimator's mean squared error gets a standard error over blocks; the
    /// assertion keeps 5 of them on each side.
    #[test]
    fn stratified_is_unbiased_with_lower_variance() {
        let (media, ray) = setup();
        let fp = FreePath {
            media: &media,
            mode: Mode::Adaptive,
        };
        let quad = QuadTr::new(&media, &ray, 3.0);
        let t = 1.6f32;
        let truth = quad.tr(t);
        let (n, m, blocks) = (64usize, 4usize, 300u32);
        let mut c = Counters::default();
        let mut paths = vec![0.0f32; n];
        let (mut strat_mse, mut rand_mse, mut strat_sum) = (Vec::new(), Vec::new(), 0.0f64);
        for b in 0..blocks {
            let mut rng = Rng::new(b as u64, 7);
            let (mut se_s, mut se_r) = (0.0f64, 0.0f64);
            for k in 0..n {
                let q = n / m;
                let mut px = StratPixel {
                    paths: &mut paths,
                    regenerate: k == 0,
                    reshuffle: k % q == 0,
                    block_rng: Rng::new(1000 + b as u64, 3),
                    cycle_rng: Rng::new(2000 + (b as u64) * 64 + (k / q) as u64, 5),
                    slot: k % q,
                };
                let s = px.pick(&fp, &ray, 3.0, m, &mut c).eval(t) as f64;
                let r = SegmentTr::random(&fp, &ray, 3.0, m, &mut rng, &mut c).eval(t) as f64;
                strat_sum += s;
                se_s += (s - truth).powi(2) / n as f64;
                se_r += (r - truth).powi(2) / n as f64;
            }
            strat_mse.push(se_s);
            rand_mse.push(se_r);
        }
        let stats = |v: &[f64]| {
            let mean = v.iter().sum::<f64>() / v.len() as f64;
            let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (v.len() - 1) as f64;
            (mean, (var / v.len() as f64).sqrt())
        };
        let (ms, ss) = stats(&strat_mse);
        let (mr, sr) = stats(&rand_mse);
        assert!(
            ms + 5.0 * ss < mr - 5.0 * sr,
            "stratified {ms} +- {ss}, random {mr} +- {sr}"
        );
        // Unbiased: the mean over all passes; per-block means are independent.
        let mean = strat_sum / (n as f64 * blocks as f64);
        let bound = 5.0 * (ms / (n as f64 * blocks as f64)).sqrt()
            + 5.0 * (truth * (1.0 - truth) / (n as f64 * blocks as f64)).sqrt();
        assert!(
            (mean - truth).abs() < bound,
            "{mean} vs {truth} (bound {bound})"
        );
        eprintln!("per-pass MSE: stratified {ms:.5}, random {mr:.5}");
    }
}
