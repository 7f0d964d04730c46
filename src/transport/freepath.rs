//! Free-path sampling, one walk for every user. Homogeneous media are sampled exactly,
//! piece by piece (the paper's eq. 4). Each density grid hands out its majorant segments
//! along the ray ([`Heterogeneous::majorants`]: one at the global majorant for Woodcock,
//! the octree's leaves for adaptive sampling); [`FreePath::track`] draws tentative
//! collisions over them and asks the caller at each one, so delta tracking and ratio
//! tracking (and any later user) share it. Extinctions add, so a collision is the nearest
//! of the parts' free paths.
use smallvec::SmallVec;

use crate::core::Ray;
use crate::majorant::{LeafBounds, Mode};
use crate::media::{Heterogeneous, Media};
use crate::sampling::Rng;
use crate::transport::Counters;

/// Ratio-tracking steps: (t_k, factor or, once cumulated, Tr just after t_k).
pub type RatioSteps = SmallVec<[(f32, f32); 8]>;

/// One grid's majorant segments along one ray, (bounds, t0, t1) front to back: walked
/// once and tracked over as often as needed. A camera segment's ratio tracking and its
/// light samples' majorant distances cross the same octree leaves, and the walk (a chain
/// of dependent steps) cost as much as their lookups.
pub type Walk = SmallVec<[(LeafBounds, f32, f32); 16]>;

/// The free-path sampler of a pass: the media and which majorants the grids use.
#[derive(Clone, Copy)]
pub struct FreePath<'a> {
    pub media: &'a Media,
    pub mode: Mode,
}

/// Exact free path through the homogeneous media: draw an optical depth -ln(1-u) and walk
/// the constant pieces until it is used up.
pub fn sample_homogeneous(media: &Media, ray: &Ray, tmax: f32, rng: &mut Rng) -> Option<f32> {
    if media.media.is_empty() {
        return None;
    }
    let mut tau = -(1.0 - rng.f32()).ln();
    for s in media.pieces(ray, tmax).iter() {
        let depth = s.sigma_t * (s.t1 - s.t0);
        if tau < depth {
            return Some(s.t0 + tau / s.sigma_t);
        }
        tau -= depth;
    }
    None
}

/// Below this, a ratio-tracking product goes through Russian roulette: in a dense cloud
/// the camera's and the shadow rays' trackings went on to the far side with products
/// that weight nothing (cloud-hg: a third of the beam crossings the splat evaluated had
/// a camera transmittance under 0.001, and 0.01 % of the radiance). Small enough that
/// what the roulette adds to the noise is that of light already nearly gone.
pub const ROULETTE_BELOW: f32 = 0.02;

/// Russian roulette on a ratio-tracking product `tr`: below [`ROULETTE_BELOW`] it
/// becomes ROULETTE_BELOW with probability tr / ROULETTE_BELOW, else 0, so its
/// expectation is kept and a tracking ends once its product is 0. The result is never
/// above `tr`'s product before the factor that brought it down, so the estimate stays
/// non-increasing along the ray.
pub fn roulette(tr: f32, rng: &mut Rng) -> f32 {
    if tr >= ROULETTE_BELOW || tr <= 0.0 {
        return tr;
    }
    if rng.f32() * ROULETTE_BELOW < tr {
        ROULETTE_BELOW
    } else {
        0.0
    }
}

/// `b` with its majorant `rate` times as high (the rate of a denser tracking).
#[inline]
fn at_rate(b: LeafBounds, rate: f32) -> LeafBounds {
    LeafBounds {
        majorant: b.majorant * rate,
        ..b
    }
}

/// What a tracking visit decides at a tentative collision (false: stop).
type Visit<'a> = &'a mut dyn FnMut(f32, LeafBounds, &mut Rng) -> bool;

/// How many times its majorant a shadow ray's ratio tracking runs at: each factor is
/// 1 - sigma_t / (K majorant), K times the lookups of one tracking at the majorant, and a
/// variance T^2 (exp(X / K) - 1) against one tracking's T^2 (exp(X) - 1) (X = integral of
/// sigma_t^2 / majorant; Poisson tentative collisions), below that of K trackings
/// averaged. On smoke-grid, whose light samples are a third of its per-pixel noise, K = 2
/// gave about 8 % less error at equal time than K = 1, and K = 3 no less than 2
/// (docs/benchmarks.md, "Denser ratio tracking").
pub const SHADOW_RATE: f32 = 2.0;

/// Tentative collisions of rate `b.majorant` on [t0, t1]; `visit(t, b, rng)` returns
/// false to stop. Returns false if stopped.
fn track_constant(
    t0: f32,
    t1: f32,
    b: LeafBounds,
    tau: &mut f32,
    rng: &mut Rng,
    visit: Visit,
) -> bool {
    let mut t = t0;
    loop {
        let room = (t1 - t) * b.majorant;
        if *tau >= room {
            *tau -= room;
            return true;
        }
        t += *tau / b.majorant;
        if !visit(t, b, rng) {
            return false;
        }
        *tau = -(1.0 - rng.f32()).ln();
    }
}

impl FreePath<'_> {
    /// Distance to the next collision in (0, tmax), or None if the ray gets through:
    /// the nearer of the homogeneous media's exact free path and the grids'.
    pub fn sample(&self, ray: &Ray, tmax: f32, rng: &mut Rng, c: &mut Counters) -> Option<f32> {
        c.free_paths += 1;
        let t_hom = sample_homogeneous(self.media, ray, tmax, rng);
        self.sample_grids(ray, t_hom.unwrap_or(tmax), rng, c)
            .or(t_hom)
    }

    /// Grid `g`'s majorant segments along the ray over [0, tmax], for [`Self::track_walk`].
    pub fn walk(&self, g: &Heterogeneous, ray: &Ray, tmax: f32, c: &mut Counters) -> Walk {
        let mut out = Walk::new();
        let steps = g.majorants(ray, tmax, self.mode, |b, t0, t1| {
            out.push((b, t0, t1));
            true
        });
        if self.mode == Mode::Adaptive {
            c.octree_steps += steps;
        }
        out
    }

    /// [`Self::track`] up to `limit` over segments walked before (to `limit` or further):
    /// the same random numbers, in the same order, give the same tentative collisions.
    fn track_walk(&self, walk: &Walk, limit: f32, rate: f32, rng: &mut Rng, visit: Visit) {
        let mut tau = -(1.0 - rng.f32()).ln();
        for &(b, t0, t1) in walk {
            if t0 >= limit {
                return;
            }
            let t1 = t1.min(limit);
            if b.majorant > 0.0 && !track_constant(t0, t1, at_rate(b, rate), &mut tau, rng, visit) {
                return;
            }
        }
    }

    /// Tentative collisions of grid `g` along the ray over its majorant segments, a
    /// Poisson process of rate `rate` times majorant(t) (the visit sees that rate as the
    /// bounds' majorant); the optical depth left to the next one is carried across
    /// segments (one logarithm per tentative collision, none per segment).
    #[allow(clippy::too_many_arguments)]
    pub fn track(
        &self,
        g: &Heterogeneous,
        ray: &Ray,
        tmax: f32,
        rate: f32,
        rng: &mut Rng,
        c: &mut Counters,
        visit: Visit,
    ) {
        let mut tau = -(1.0 - rng.f32()).ln();
        let steps = g.majorants(ray, tmax, self.mode, |b, t0, t1| {
            b.majorant <= 0.0 || track_constant(t0, t1, at_rate(b, rate), &mut tau, rng, visit)
        });
        if self.mode == Mode::Adaptive {
            c.octree_steps += steps;
        }
    }

    /// A free path through the grids alone (camera transmittance estimates use these;
    /// the homogeneous part of the transmittance is analytic). A tentative collision whose
    /// uniform falls below the segment's minorant is real without a density lookup
    /// (sigma_t >= minorant there): the same decision, one lookup fewer. Grids are tracked
    /// independently and the nearest collision wins.
    pub fn sample_grids(
        &self,
        ray: &Ray,
        tmax: f32,
        rng: &mut Rng,
        c: &mut Counters,
    ) -> Option<f32> {
        self.sample_grids_over(ray, tmax, None, rng, c)
    }

    /// [`Self::sample_grids`], over the grids' `walks` along the ray to `tmax` where the
    /// caller made them ([`Self::walks`]; the M free paths of a camera segment cross the
    /// same leaves), else along the octrees.
    pub fn sample_grids_over(
        &self,
        ray: &Ray,
        tmax: f32,
        walks: Option<&[Walk]>,
        rng: &mut Rng,
        c: &mut Counters,
    ) -> Option<f32> {
        let mut best: Option<f32> = None;
        for (i, g) in self.media.grids.iter().enumerate() {
            let limit = best.unwrap_or(tmax);
            let (mut lookups, mut accepts) = (0, 0);
            let mut visit = |t: f32, b: LeafBounds, rng: &mut Rng| {
                let u = rng.f32() * b.majorant;
                let real = if u < b.minorant {
                    accepts += 1;
                    true
                } else {
                    lookups += 1;
                    u < g.sigma_t(ray.at(t))
                };
                if real {
                    best = Some(t);
                }
                !real
            };
            match walks.and_then(|w| w.get(i)) {
                Some(walk) => self.track_walk(walk, limit, 1.0, rng, &mut visit),
                None => self.track(g, ray, limit, 1.0, rng, c, &mut visit),
            }
            c.density_lookups += lookups;
            c.minorant_accepts += accepts;
        }
        best
    }

    /// Every grid's [`Walk`] along the ray over [0, tmax], in the order of `media.grids`.
    pub fn walks(&self, ray: &Ray, tmax: f32, c: &mut Counters) -> SmallVec<[Walk; 1]> {
        let grids = self.media.grids.iter();
        grids.map(|g| self.walk(g, ray, tmax, c)).collect()
    }

    /// Ratio tracking through the grids over their `walks` ([`Self::walks`] of the ray)
    /// at `rate` times their majorants: pushes (t, 1 - sigma_t(x) / (rate majorant)) for
    /// every tentative collision, each grid's in order of t but the grids one after the
    /// other, each grid's product put through [`roulette`] (a factor that [`roulette`]
    /// changed is pushed as the one that gives its product).
    pub fn ratio_steps(
        &self,
        ray: &Ray,
        walks: &[Walk],
        rate: f32,
        rng: &mut Rng,
        c: &mut Counters,
        out: &mut RatioSteps,
    ) {
        for (g, walk) in self.media.grids.iter().zip(walks) {
            let mut lookups = 0;
            let mut tr = 1.0f32;
            self.track_walk(walk, f32::INFINITY, rate, rng, &mut |t, b, rng| {
                lookups += 1;
                let f = (1.0 - g.sigma_t(ray.at(t)) / b.majorant).max(0.0);
                let next = roulette(tr * f, rng);
                // The factor that takes this tracking's product from tr to next (tr is at
                // least ROULETTE_BELOW or 1, so it is at most 1).
                out.push((t, if next == tr * f { f } else { next / tr }));
                tr = next;
                tr > 0.0
            });
            c.density_lookups += lookups;
        }
    }

    /// Ratio tracking through the grids up to `tmax` at [`SHADOW_RATE`] times their
    /// majorants: the product over tentative collisions of (1 - sigma_t(x) / (K
    /// majorant)), an unbiased estimate of the grids' transmittance (shadow rays; stops at
    /// the first zero factor). Each grid's product goes through [`roulette`], as in
    /// [`Self::ratio_steps`].
    pub fn ratio_transmittance(
        &self,
        ray: &Ray,
        tmax: f32,
        rng: &mut Rng,
        c: &mut Counters,
    ) -> f32 {
        let mut tr = 1.0f32;
        for g in &self.media.grids {
            let (mut lookups, mut gtr) = (0, 1.0f32);
            self.track(g, ray, tmax, SHADOW_RATE, rng, c, &mut |t, b, rng| {
                lookups += 1;
                gtr = roulette(
                    gtr * (1.0 - g.sigma_t(ray.at(t)) / b.majorant).max(0.0),
                    rng,
                );
                gtr > 0.0
            });
            c.density_lookups += lookups;
            tr *= gtr;
            if tr <= 0.0 {
                break;
            }
        }
        tr
    }

    /// Transmittance along `ray` to `tmax` (infinite: out of the scene), unbiased: the
    /// homogeneous media's exp(-tau) times a ratio-tracking estimate through the grids.
    pub fn transmittance(&self, ray: &Ray, tmax: f32, rng: &mut Rng, c: &mut Counters) -> f32 {
        let tr = (-self.media.optical_depth(ray, tmax)).exp();
        if tr <= 0.0 || !self.media.crosses_grids(ray, tmax) {
            return tr;
        }
        tr * self.ratio_transmittance(ray, tmax, rng, c)
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::media::{MediumDesc, Phase};
    use glam::Vec3;

    /// The roulette keeps a product's mean (5 standard errors of sqrt(tr (c - tr) / n),
    /// its variance in closed form) and gives c or 0 below c = ROULETTE_BELOW; at or
    /// above c it changes nothing.
    #[test]
    fn roulette_keeps_the_mean() {
        let c = ROULETTE_BELOW;
        let mut rng = Rng::new(17, 2);
        let n = 200_000;
        for tr in [0.001f32, 0.007, 0.019] {
            let mut sum = 0.0f64;
            for _ in 0..n {
                let v = roulette(tr, &mut rng);
                assert!(v == 0.0 || v == c, "{v}");
                sum += v as f64;
            }
            let se = (tr as f64 * (c - tr) as f64 / n as f64).sqrt();
            let mean = sum / n as f64;
            assert!((mean - tr as f64).abs() < 5.0 * se, "{tr}: {mean}");
        }
        for tr in [0.0f32, c, 0.5, 1.0] {
            assert_eq!(roulette(tr, &mut rng), tr);
        }
    }

    /// KS statistic of free paths against a CDF 1 - Tr(t); Tr(tmax) is the escape mass.
    pub(crate) fn ks_against(
        samples: &mut [f32],
        tr: impl Fn(f32) -> f64,
        tmax: f32,
    ) -> (f64, f64) {
        let n = samples.len();
        samples.sort_by(f32::total_cmp);
        let mut d_max = 0.0f64;
        for (i, &t) in samples.iter().enumerate() {
            if !t.is_finite() {
                break;
            }
            let cdf = 1.0 - tr(t);
            let hi = (i + 1) as f64 / n as f64;
            let lo = i as f64 / n as f64;
            d_max = d_max.max((hi - cdf).abs()).max((lo - cdf).abs());
        }
        let escaped = samples.iter().filter(|t| !t.is_finite()).count() as f64 / n as f64;
        (d_max, escaped - tr(tmax))
    }

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
        let fp = FreePath {
            media: &media,
            mode: Mode::Woodcock,
        };
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
        let tr = |t: f32| (-media.optical_depth(&ray, t) as f64).exp();
        let (d, escape_err) = ks_against(&mut samples, tr, tmax);
        assert!(d < 1.95 / (n as f64).sqrt(), "KS D = {d}");
        let p = tr(tmax);
        assert!(escape_err.abs() < 5.0 * (p * (1.0 - p) / n as f64).sqrt());
        assert_eq!(c.density_lookups, 0);
    }
}

#[cfg(test)]
mod walk_tests {
    use super::*;
    use crate::transport::transmittance::tests::ramp_media;
    use glam::Vec3;

    /// Tracking over a walk made once gives the tentative collisions (positions, bounds and
    /// the random numbers drawn) that tracking along the live octree walk gives, for
    /// several trackings of one walk; a walk that lost, reordered or repeated a segment
    /// would shift every later collision.
    #[test]
    fn tracking_a_stored_walk_equals_tracking_the_live_walk() {
        let media = ramp_media();
        let fp = FreePath {
            media: &media,
            mode: Mode::Adaptive,
        };
        let g = &media.grids[0];
        let mut dirs = Rng::new(5, 2);
        let (mut collisions, mut segments) = (0, 0);
        for ray_index in 0..400 {
            let target = Vec3::new(dirs.f32(), dirs.f32(), dirs.f32()) * 2.0;
            let o = Vec3::new(-0.5, 0.3 + dirs.f32(), 1.0 + dirs.f32());
            let ray = Ray::new(o, (target - o).normalize());
            let tmax = 1.0 + 3.0 * dirs.f32();
            let mut c = Counters::default();
            let walk = fp.walk(g, &ray, tmax, &mut c);
            segments += walk.len();
            for k in 0..4u64 {
                // Trackings at the majorant and denser ones.
                let rate = [1.0, 2.0, 3.0, 1.0][k as usize];
                let record = |live: bool| {
                    let mut rng = Rng::new(ray_index, k);
                    let mut seen = Vec::new();
                    let mut visit = |t: f32, b: LeafBounds, rng: &mut Rng| {
                        seen.push((t.to_bits(), b.majorant.to_bits(), rng.f32().to_bits()));
                        true
                    };
                    if live {
                        fp.track(
                            g,
                            &ray,
                            tmax,
                            rate,
                            &mut rng,
                            &mut Counters::default(),
                            &mut visit,
                        );
                    } else {
                        fp.track_walk(&walk, f32::INFINITY, rate, &mut rng, &mut visit);
                    }
                    seen
                };
                let live = record(true);
                assert_eq!(record(false), live, "ray {ray_index}, tracking {k}");
                collisions += live.len();
            }
        }
        assert!(
            segments > 1500 && collisions > 4000,
            "{segments} segments, {collisions} collisions"
        );
    }

    /// Free paths over stored walks equal free paths along the live octree walks, draw for
    /// draw, with two overlapping grids: the second grid's walk is cut at the first grid's
    /// collision as the live walk to that distance would be.
    #[test]
    fn free_paths_over_stored_walks_equal_live_ones() {
        use crate::transport::transmittance::tests::ramp_media_with;
        let (a, b) = (ramp_media_with(0.0, 2.0), ramp_media_with(0.5, 1.0));
        let media = Media::with_grids(vec![], vec![a.grids[0].clone(), b.grids[0].clone()]);
        let mut dirs = Rng::new(7, 3);
        let mut found = 0;
        for mode in [Mode::Adaptive, Mode::Woodcock] {
            let fp = FreePath {
                media: &media,
                mode,
            };
            for ray_index in 0..300 {
                let target = Vec3::new(dirs.f32(), dirs.f32(), dirs.f32()) * 2.0;
                let o = Vec3::new(-0.5, 0.3 + dirs.f32(), 1.0 + dirs.f32());
                let ray = Ray::new(o, (target - o).normalize());
                let tmax = 1.0 + 3.0 * dirs.f32();
                let walks = fp.walks(&ray, tmax, &mut Counters::default());
                let mut live = Rng::new(ray_index, 1);
                let mut stored = Rng::new(ray_index, 1);
                for _ in 0..8 {
                    let c = &mut Counters::default();
                    let want = fp.sample_grids(&ray, tmax, &mut live, c);
                    let got = fp.sample_grids_over(&ray, tmax, Some(&walks), &mut stored, c);
                    assert_eq!(
                        got.map(f32::to_bits),
                        want.map(f32::to_bits),
                        "{mode:?} ray {ray_index}"
                    );
                    found += want.is_some() as u32;
                }
                assert_eq!(
                    live.f32().to_bits(),
                    stored.f32().to_bits(),
                    "streams apart"
                );
            }
        }
        assert!(found > 2000, "only {found} collisions");
    }
}
