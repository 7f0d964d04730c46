//! Unbiased ray-marching transmittance along a camera segment (Kettunen et al. 2021, "An
//! unbiased ray-marching transmittance estimator"), as a step function of the distance.
//!
//! A jittered march stratified by the majorant estimates the optical depth tau(t) up to
//! every t at once. One march is the control tau_c; T = exp(-tau_c) sum_k (tau_c - tau)^k /
//! k!, each power a product of independent marches' differences, the series cut by Russian
//! roulette (each term weighted by one over the probability of reaching it), which keeps it
//! unbiased. Where the march follows the density well, the differences are small and the
//! estimate is nearly exact; ratio tracking's variance does not fall that way.
use smallvec::SmallVec;

use crate::core::Ray;
use crate::media::Heterogeneous;
use crate::sampling::Rng;
use crate::settings::MAX_TR_SAMPLES;
use crate::transport::freepath::{FreePath, RatioSteps, Walk, ROULETTE_BELOW};
use crate::transport::Counters;

/// Majorant optical depth per march cell is this over M (`--tr-samples`): each march looks
/// the density up once per cell. Measured on smoke-grid at 60 passes (docs/benchmarks.md,
/// "Unbiased ray marching"): at M = 4, cells of 0.25 cost more than they saved and cells of
/// 1.0 left more noise than 0.5.
const CELLS_PER_DEPTH_OVER_M: f32 = 2.0;

/// The control's cells are this many times longer: its error enters the estimate only at
/// second order (exp(-tau_c) (1 + tau_c - tau_1) is exp(-tau) (1 + tau - tau_1) to first
/// order). On smoke-grid, dense-smoke and cloud-sky, 2 kept the noise and took 3-6 % off
/// the pass; 4 added noise (docs/benchmarks.md, "Unbiased ray marching").
const CONTROL_CELLS: f32 = 2.0;

/// Terms of the series always evaluated (the first is 1, the second one difference).
const ALWAYS: usize = 2;
/// The probability of each further term, and the most terms (a bound the roulette keeps
/// far below).
const CONTINUE: f32 = 0.25;
/// (Reached with probability 0.25^22: no bias that any render could show.)
const MAX_TERMS: usize = 24;

/// (t, increment of the optical-depth estimate at t), one march's points.
type Points = SmallVec<[(f32, f32); 32]>;

/// One march of grid `g` over its walk, up to `limit`: cell j of the majorant optical depth
/// s(t) holds the point s = (j + u) step, weighted step sigma_t / majorant there, an
/// unbiased estimate of the integral of sigma_t over the cell's part before any t.
fn march(
    (step, limit): (f32, f32),
    g: &Heterogeneous,
    ray: &Ray,
    walk: &Walk,
    rng: &mut Rng,
    lookups: &mut u64,
    out: &mut Points,
) {
    let u = rng.f32();
    // Majorant depth to the next point, carried across the walk's segments.
    let mut ahead = u * step;
    for &(b, t0, t1) in walk {
        if b.majorant <= 0.0 {
            continue;
        }
        let mut t = t0;
        loop {
            let room = (t1 - t) * b.majorant;
            if ahead >= room {
                ahead -= room;
                break;
            }
            t += ahead / b.majorant;
            if t >= limit {
                return;
            }
            let ratio = if b.minorant >= b.majorant {
                1.0
            } else {
                *lookups += 1;
                g.sigma_t(ray.at(t)) / b.majorant
            };
            out.push((t, step * ratio));
            ahead = step;
        }
    }
}

/// Every grid's march, merged in order of t.
fn march_all(
    cells: (f32, f32),
    fp: &FreePath,
    ray: &Ray,
    walks: &[Walk],
    rng: &mut Rng,
    lookups: &mut u64,
) -> Points {
    let mut out = Points::new();
    for (g, walk) in fp.media.grids.iter().zip(walks) {
        march(cells, g, ray, walk, rng, lookups, &mut out);
    }
    if walks.len() > 1 {
        out.sort_by(|a, b| a.0.total_cmp(&b.0));
    }
    out
}

/// The estimate along the ray over the grids' `walks`, as (t, value after t) steps, with
/// `m` ([`CELLS_PER_DEPTH_OVER_M`]) setting the marches' cells.
pub fn march_steps(
    fp: &FreePath,
    ray: &Ray,
    walks: &[Walk],
    m: usize,
    rng: &mut Rng,
    c: &mut Counters,
) -> RatioSteps {
    let step = CELLS_PER_DEPTH_OVER_M / m.clamp(1, MAX_TR_SAMPLES) as f32;
    let mut lookups = 0;
    let control = march_all(
        (step * CONTROL_CELLS, f32::INFINITY),
        fp,
        ray,
        walks,
        rng,
        &mut lookups,
    );
    // (where, 1 / chance of going on): None where the control stays above the threshold.
    let cut = gone(&control).map(|(t, chance)| (t, (rng.f32() < chance).then(|| 1.0 / chance)));
    let limit = match cut {
        Some((t, None)) => t,
        _ => f32::INFINITY,
    };
    let mut terms: SmallVec<[Points; 4]> = SmallVec::new();
    // weights[k]: 1 / (k! P(reaching term k)).
    let mut weights: SmallVec<[f32; 8]> = SmallVec::from_slice(&[1.0]);
    for k in 1..MAX_TERMS {
        if k >= ALWAYS && rng.f32() >= CONTINUE {
            break;
        }
        terms.push(march_all((step, limit), fp, ray, walks, rng, &mut lookups));
        let last = weights[k - 1];
        weights.push(last / k as f32 * if k >= ALWAYS { 1.0 / CONTINUE } else { 1.0 });
    }
    c.density_lookups += lookups;
    let mut steps = sweep(&control, &terms, &weights, cut);
    roulette_steps(&mut steps, rng);
    steps
}

/// What a cut makes of the estimate at t: Err(where) past a cut that ended the segment,
/// one over the chance past one it survived, else 1.
fn cut_scale(cut: Option<(f32, Option<f32>)>, t: f32) -> Result<f32, f32> {
    match cut {
        Some((at, survived)) if t >= at => survived.ok_or(at),
        _ => Ok(1.0),
    }
}

/// The series sum_k weights[k] prod_{j <= k} (tau_c - tau_j), tau_c = tau[0].
fn series(tau: &[f32], weights: &[f32]) -> f32 {
    let (tc, mut prod, mut sum) = (tau[0], 1.0f32, 1.0f32);
    for k in 1..tau.len() {
        prod *= tc - tau[k];
        sum += prod * weights[k];
    }
    sum
}

/// The series at every point of the marches, in order of t: tau_c and each term's tau
/// summed up to there, a k-way merge of the already ordered marches (ties in march order,
/// as a stable sort of their union would give). Past a cut that ended the segment the
/// value is 0; past one it survived, scaled by one over its chance.
fn sweep(
    control: &Points,
    terms: &[Points],
    weights: &[f32],
    cut: Option<(f32, Option<f32>)>,
) -> RatioSteps {
    let lists: SmallVec<[&[(f32, f32)]; 8]> = std::iter::once(&control[..])
        .chain(terms.iter().map(|p| &p[..]))
        .collect();
    let mut heads: SmallVec<[usize; 8]> = SmallVec::from_elem(0, lists.len());
    let mut tau: SmallVec<[f32; 8]> = SmallVec::from_elem(0.0, lists.len());
    let mut control_tr = 1.0f32;
    let mut steps = RatioSteps::new();
    loop {
        let next = lists
            .iter()
            .zip(&heads)
            .filter_map(|(l, &h)| l.get(h).map(|p| p.0))
            .reduce(f32::min);
        let Some(t) = next else { break };
        let scale = match cut_scale(cut, t) {
            Ok(s) => s,
            Err(at) => {
                steps.push((at, 0.0));
                break;
            }
        };
        let (control_before, mut moved) = (heads[0], false);
        for (k, list) in lists.iter().enumerate() {
            while let Some(&(_, d)) = list.get(heads[k]).filter(|p| p.0 == t) {
                tau[k] += d;
                heads[k] += 1;
                moved = true;
            }
        }
        if heads[0] != control_before {
            control_tr = (-tau[0]).exp();
        }
        // Only a NaN distance (a NaN ray) matches nothing: end there rather than loop.
        if !moved {
            break;
        }
        steps.push((t, scale * control_tr * series(&tau, weights)));
    }
    steps
}

/// Where the control's transmittance first falls below ROULETTE_BELOW, and its value there
/// over ROULETTE_BELOW: the chance that the rest of the segment goes on (scaled by one over
/// it), drawn before the other marches, which stop there when it does not. In a dense
/// smoke most segments end so, and the marches past that point would weigh little.
fn gone(control: &Points) -> Option<(f32, f32)> {
    let mut tau = 0.0f32;
    control.iter().find_map(|&(t, d)| {
        tau += d;
        let tr = (-tau).exp();
        (tr < ROULETTE_BELOW).then_some((t, tr / ROULETTE_BELOW))
    })
}

/// Russian roulette on a step function, as [`crate::transport::freepath::roulette`] on a
/// product: where its magnitude first falls below ROULETTE_BELOW it goes on, scaled by
/// one over the chance of going on, or is 0 from there. Its expectation at every t is
/// kept, and camera estimates leave out what lies past a 0.
fn roulette_steps(steps: &mut RatioSteps, rng: &mut Rng) {
    let mut w = 1.0f32;
    for k in 0..steps.len() {
        let v = steps[k].1 * w;
        if v.abs() >= ROULETTE_BELOW {
            steps[k].1 = v;
            continue;
        }
        if v != 0.0 && rng.f32() * ROULETTE_BELOW < v.abs() {
            w *= ROULETTE_BELOW / v.abs();
            steps[k].1 = ROULETTE_BELOW.copysign(v);
        } else {
            steps[k].1 = 0.0;
            steps.truncate(k + 1);
            return;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::majorant::Mode;
    use crate::transport::transmittance::tests::{ramp_media_with, QuadTr};
    use crate::transport::transmittance::SegmentTr;
    use glam::Vec3;

    /// Mean and standard error of `n` estimates at each of `ts`, with the lookups per
    /// estimate.
    fn stats(fp: &FreePath, ray: &Ray, ts: &[f32], n: usize, seed: u64) -> (Vec<(f64, f64)>, f64) {
        let mut rng = Rng::new(seed, 3);
        let mut c = Counters::default();
        let mut sums = vec![(0.0f64, 0.0f64); ts.len()];
        for _ in 0..n {
            let walks = fp.walks(ray, 3.0, &mut c);
            let tr = SegmentTr::Ratio(march_steps(fp, ray, &walks, 4, &mut rng, &mut c));
            for (s, &t) in sums.iter_mut().zip(ts) {
                let v = tr.eval(t) as f64;
                s.0 += v;
                s.1 += v * v;
            }
        }
        let n = n as f64;
        let out = sums
            .iter()
            .map(|&(s, s2)| {
                let mean = s / n;
                (mean, ((s2 / n - mean * mean).max(0.0) / n).sqrt())
            })
            .collect();
        (out, c.density_lookups as f64 / n)
    }

    /// The march's estimate has the quadrature transmittance as its mean at every distance
    /// (5 standard errors of 20,000 estimates), with Woodcock's one majorant and with the
    /// octree's, in a thin ramp and in one 12 times denser, where the series' terms are
    /// larger and the roulette ends most estimates early.
    #[test]
    fn mean_is_the_transmittance() {
        let ray = Ray::new(
            Vec3::new(-0.5, 0.93, 1.02),
            Vec3::new(1.0, 0.05, 0.02).normalize(),
        );
        let ts = [0.55f32, 0.8, 1.2, 1.6, 2.4];
        for (scale, seed) in [(2.0f32, 1u64), (24.0, 2)] {
            let media = ramp_media_with(0.0, scale);
            let quad = QuadTr::new(&media, &ray, 3.0);
            for mode in [Mode::Woodcock, Mode::Adaptive] {
                let fp = FreePath {
                    media: &media,
                    mode,
                };
                let (got, _) = stats(&fp, &ray, &ts, 20_000, seed);
                for (&t, &(mean, se)) in ts.iter().zip(&got) {
                    let truth = quad.tr(t);
                    assert!(
                        (mean - truth).abs() < 5.0 * se + 1e-4,
                        "scale {scale}, {mode:?}, t={t}: {mean} +- {se} vs {truth}"
                    );
                }
            }
        }
    }

    /// The merge gives, bit for bit, the sweep over the stable-sorted union of the marches'
    /// points, with ties across marches (points on a shared grid of t) and every kind of cut.
    #[test]
    fn sweep_equals_the_sorted_union() {
        let naive = |lists: &[Points], weights: &[f32], cut: Option<(f32, Option<f32>)>| {
            let mut events: Vec<(f32, usize, f32)> = Vec::new();
            for (k, l) in lists.iter().enumerate() {
                events.extend(l.iter().map(|&(t, d)| (t, k, d)));
            }
            events.sort_by(|a, b| a.0.total_cmp(&b.0));
            let mut tau = vec![0.0f32; lists.len()];
            let mut steps = RatioSteps::new();
            let mut i = 0;
            while i < events.len() {
                let t = events[i].0;
                let scale = match cut_scale(cut, t) {
                    Ok(s) => s,
                    Err(at) => {
                        steps.push((at, 0.0));
                        break;
                    }
                };
                while i < events.len() && events[i].0 == t {
                    tau[events[i].1] += events[i].2;
                    i += 1;
                }
                steps.push((t, scale * (-tau[0]).exp() * series(&tau, weights)));
            }
            steps
        };
        let mut rng = Rng::new(11, 3);
        for case in 0..300 {
            let n = 2 + case % 4;
            let lists: Vec<Points> = (0..n)
                .map(|_| {
                    let mut t = 0.0f32;
                    (0..(rng.f32() * 40.0) as usize)
                        .map(|_| {
                            // Steps of 1/8 put many points of different marches on one t.
                            t += (1.0 + (rng.f32() * 4.0).floor()) / 8.0;
                            (t, rng.f32() * 0.7)
                        })
                        .collect()
                })
                .collect();
            let weights: Vec<f32> = (0..n).map(|k| 1.0 / (k + 1) as f32).collect();
            let at = rng.f32() * 6.0;
            let cut = match case % 3 {
                0 => None,
                1 => Some((at, None)),
                _ => Some((at, Some(3.0))),
            };
            let got = sweep(&lists[0], &lists[1..], &weights, cut);
            let want = naive(&lists, &weights, cut);
            let bits = |s: &RatioSteps| -> Vec<(u32, u32)> {
                s.iter().map(|p| (p.0.to_bits(), p.1.to_bits())).collect()
            };
            assert_eq!(bits(&got), bits(&want), "case {case}");
        }
    }

    /// At the far end of the thin ramp, the march's variance times its lookups is below
    /// ratio tracking's at 4 times the octree's majorants (the camera's default).
    #[test]
    fn beats_ratio_tracking_per_lookup() {
        let media = ramp_media_with(0.0, 2.0);
        let fp = FreePath {
            media: &media,
            mode: Mode::Adaptive,
        };
        let ray = Ray::new(
            Vec3::new(-0.5, 0.93, 1.02),
            Vec3::new(1.0, 0.05, 0.02).normalize(),
        );
        let n = 20_000;
        let (march, march_lookups) = stats(&fp, &ray, &[2.4], n, 5);
        let mut rng = Rng::new(6, 3);
        let mut c = Counters::default();
        let (mut s, mut s2) = (0.0f64, 0.0f64);
        for _ in 0..n {
            let v = SegmentTr::ratio(&fp, &ray, 3.0, 4, &mut rng, &mut c).eval(2.4) as f64;
            s += v;
            s2 += v * v;
        }
        let mean = s / n as f64;
        let ratio_var = s2 / n as f64 - mean * mean;
        let ratio_lookups = c.density_lookups as f64 / n as f64;
        let march_var = march[0].1 * march[0].1 * n as f64;
        assert!(
            march_var * march_lookups < 0.5 * ratio_var * ratio_lookups,
            "march {march_var} x {march_lookups}, ratio {ratio_var} x {ratio_lookups}"
        );
    }
}
