//! How far the film is from converged, without a reference, and the per-pixel radius
//! that brings it closer.
//!
//! **Noise.** Hachisuka, Jarosz and Jensen (2010) estimate the noise of progressive
//! density estimation from the spread of its passes; the difference of the film's two
//! interleaved half-films is that spread summed per pixel, and it is how ppb's
//! conformance references are judged (two renders' rel_l1 / sqrt 2). With A the mean of
//! the n_a even passes, B that of the n_b odd ones (alternate passes, or alternate groups
//! of passes that share samples) and X the mean of all n = n_a + n_b: when the passes are
//! independent, (A - B) sqrt(n_a n_b) / n has the variance of X - E[X] (exactly for equal
//! variances, and nearly for the progressive passes' slowly growing ones, which
//! interleaving splits evenly). On 4x4 block means the same difference keeps the noise's
//! correlation across pixels (a beam's kernel covers several), which an estimate from
//! per-pixel variances would miss.
//!
//! **Bias.** A kernel estimate's expectation is the radiance blurred by the kernel:
//! L + c r^p + ..., with p = 2 where the radiance is smooth (the second derivatives of
//! Hachisuka et al.'s bias term) and p = 1 at a step (a medium's silhouette). Every beam
//! kernel evaluation also counts at r/2 ([`crate::core::Nested`]), so the film holds D,
//! the mean of (estimate at r/2 - estimate at r), with E[D] = -(1 - 2^-p) bias. The signed bias is estimated as -[`BIAS_PER_D`] D:
//! exact for p = 1.5, within 0.77-1.16 of the truth from p = 2 to p = 1. Its size per
//! pixel, sqrt(D^2 - var D) averaged over a window (D's own noise removed, the rest
//! clipped at zero), enters the expected error as sqrt(bias^2 + noise^2). The surface
//! photons' 2D kernels are nested too, in sums of their own with the same K: their bias
//! adds to the estimate, but not to lambda (docs/error-estimate.md says why).
//!
//! **Adaptive bandwidth** (Kaplanyan and Dachsbacher 2013 choose each point's radius by
//! the same balance): the adaptive image is X + lambda D per pixel, the estimate of a
//! kernel mixing radius r (weight 1 - lambda) and r/2 (weight lambda). lambda in [0, 1]
//! minimises the estimated squared error, bias^2 (1 - lambda / K)^2 + var X +
//! lambda^2 var D, from the same windowed moments: near 1 (the narrow kernel) where the
//! bias is large, 0 (the wide one) where the radiance is smooth.
//! It converges: both X and X + D are fixed-schedule estimates (radii r_i and r_i / 2,
//! eq. 3) that converge to the radiance, and any lambda in [0, 1], however it was
//! chosen, gives |X + lambda D - L| <= |X - L| + |D| <= 2 |X - L| + |X + D - L|.
use super::{Film, Halves};
use rayon::prelude::*;

/// Block size of the low-frequency error (4x4 block means, as the conformance tests judge).
pub const BLOCK: usize = 4;

/// Passes each half-film needs before its noise is estimated.
pub const MIN_HALF_PASSES: u32 = 2;

/// K: the bias of the image at radius r per unit of -D, 1 / (1 - 2^-1.5).
pub const BIAS_PER_D: f64 = 1.547_005_383_792_515;

/// How many of its own spreads the windowed bias must stand above zero before lambda
/// narrows the kernel (the size estimate subtracts one): at 1, pure noise narrowed it in
/// about 5 % of cloud-hg's pixels and raised its per-pixel error by 3 % at 300 passes; at
/// 3, by under 1 %, while fog-box's faces kept their gain (docs/error-estimate.md).
const NARROW_SPREADS: f64 = 3.0;

/// Half-widths of the windows the bias moments are averaged over: 5x5 pixels, 3x3 blocks.
const PIXEL_WINDOW: usize = 2;
const BLOCK_WINDOW: usize = 1;

/// Per-pixel RGB in f64, row-major.
type Pixels = Vec<[f64; 3]>;

/// A rel_l1 on both metrics.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct Rel {
    /// Per pixel and channel.
    pub pixel: f64,
    /// On the means of whole 4x4 blocks.
    pub block: f64,
}

/// The expected rel_l1 of the film's image from the converged radiance.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct ErrorEstimate {
    /// Noise and bias together, per pixel and channel ...
    pub pixel: f64,
    /// ... and on the means of whole 4x4 blocks.
    pub block: f64,
    /// The noise alone: the expected rel_l1 from the image's own mean.
    pub noise: Rel,
    /// The kernels' bias alone; None where some pass's estimate kept no nested sums.
    pub bias: Option<Rel>,
    /// Passes it was estimated from.
    pub passes: u32,
}

impl ErrorEstimate {
    /// The estimate on `metric`.
    pub fn on(&self, metric: Metric) -> f64 {
        match metric {
            Metric::Pixel => self.pixel,
            Metric::Block => self.block,
        }
    }
}

/// Which rel_l1 a target applies to.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Metric {
    #[default]
    Pixel,
    /// 4x4 block means: the blotches that show before noise.
    Block,
}

/// How the film's sums become the image.
#[derive(
    Clone,
    Copy,
    Debug,
    Default,
    PartialEq,
    Eq,
    clap::ValueEnum,
    serde::Serialize,
    serde::Deserialize,
)]
#[serde(rename_all = "lowercase")]
pub enum Bandwidth {
    /// Every pixel at the radius of eq. 3 (the paper's).
    #[default]
    Fixed,
    /// Each pixel's radius between r and r/2 by its estimated bias and noise.
    Adaptive,
}

/// Means and scaled half-film differences of one quantity (the image, or D).
struct Moments {
    mean: Pixels,
    dev: Pixels,
}

/// The film's moments as an image resolves them: the image's, the beams' D when every
/// pass added it and the photons' beside it, and each pixel's lambda.
struct Resolved {
    x: Moments,
    d: Option<Moments>,
    photons: Option<Moments>,
    lambda: Vec<f64>,
}

impl Film {
    /// The mean and scaled half-film difference of one set of the film's sums; None
    /// until each half holds [`MIN_HALF_PASSES`] passes.
    fn moments(&self, sums: &Halves) -> Option<Moments> {
        let (nb, na) = (self.half_passes(true), self.half_passes(false));
        if na.min(nb) < MIN_HALF_PASSES {
            return None;
        }
        let (odd, even) = (sums.half(true, nb), sums.half(false, na));
        let n = f64::from(na + nb);
        let scale = (f64::from(na) * f64::from(nb)).sqrt() / n;
        let (wa, wb) = (f64::from(na) / n, f64::from(nb) / n);
        let (dev, mean) = even
            .iter()
            .zip(&odd)
            .map(|(a, b)| {
                let d = [0, 1, 2].map(|c| (a[c] - b[c]) * scale);
                let x = [0, 1, 2].map(|c| a[c] * wa + b[c] * wb);
                (d, x)
            })
            .unzip();
        Some(Moments { mean, dev })
    }

    fn resolve(&self, bandwidth: Bandwidth) -> Option<Resolved> {
        let x = self.moments(&self.image)?;
        let complete = self.counts.nested == self.counts.passes;
        let d = complete.then(|| self.moments(&self.nested)).flatten();
        let photons = d.as_ref().and_then(|_| self.moments(&self.photons));
        let (w, h) = (self.width as usize, self.height as usize);
        let lambda = match (&d, bandwidth) {
            (Some(d), Bandwidth::Adaptive) => lambdas(d, w, h),
            _ => vec![0.0; w * h],
        };
        Some(Resolved {
            x,
            d,
            photons,
            lambda,
        })
    }

    /// The image as `bandwidth` resolves it (the fixed one where the nested sums are
    /// missing or too few passes were made).
    pub fn image_with(&self, bandwidth: Bandwidth) -> Vec<[f32; 3]> {
        let image = self.image();
        match self.narrowing_map(bandwidth) {
            Some(n) if bandwidth == Bandwidth::Adaptive => image
                .iter()
                .zip(&n)
                .map(|(x, s)| [0, 1, 2].map(|c| (f64::from(x[c]) + s[c]) as f32))
                .collect(),
            _ => image,
        }
    }

    /// What the adaptive kernel adds to the fixed image, lambda D per pixel (zero at the
    /// fixed bandwidth); None until the noise can be estimated or where the beams' nested
    /// sums are missing.
    pub fn narrowing_map(&self, bandwidth: Bandwidth) -> Option<Vec<[f64; 3]>> {
        let Resolved { d, lambda, .. } = self.resolve(bandwidth)?;
        let d = d?;
        let shift = d.mean.iter().zip(&lambda).map(|(d, l)| d.map(|c| l * c));
        Some(shift.collect())
    }

    /// The image `bandwidth` resolves, per pixel: its mean, its noise deviation, and its
    /// signed bias estimate with that estimate's own noise deviation (where the film has
    /// nested sums): -(K - lambda) D of the beams' and -K D of the photons'.
    fn parts(&self, bandwidth: Bandwidth) -> Option<Parts> {
        let Resolved {
            x,
            d,
            photons,
            lambda,
        } = self.resolve(bandwidth)?;
        let mix = |a: &Pixels, b: Option<&Pixels>| -> Pixels {
            a.iter()
                .enumerate()
                .map(|(i, v)| {
                    let m = b.map_or([0.0; 3], |b| b[i]);
                    [0, 1, 2].map(|c| v[c] + lambda[i] * m[c])
                })
                .collect()
        };
        let bias = |beams: &Pixels, photons: Option<&Pixels>| -> Pixels {
            beams
                .iter()
                .zip(&lambda)
                .enumerate()
                .map(|(i, (b, l))| {
                    let p = photons.map_or([0.0; 3], |p| p[i]);
                    [0, 1, 2].map(|c| -(BIAS_PER_D - l) * b[c] - BIAS_PER_D * p[c])
                })
                .collect()
        };
        let p = photons.as_ref();
        Some(Parts {
            mean: mix(&x.mean, d.as_ref().map(|d| &d.mean)),
            noise: mix(&x.dev, d.as_ref().map(|d| &d.dev)),
            bias: d.as_ref().map(|d| {
                let b = bias(&d.mean, p.map(|p| &p.mean));
                (b, bias(&d.dev, p.map(|p| &p.dev)))
            }),
        })
    }

    /// The expected rel_l1 of the image `bandwidth` resolves from the converged
    /// radiance, per pixel and on 4x4 block means, without the pixels that see a light
    /// directly ([`Film::with_lights`]); None until each half-film holds
    /// [`MIN_HALF_PASSES`] passes.
    pub fn error_estimate(&self, bandwidth: Bandwidth) -> Option<ErrorEstimate> {
        let Parts { mean, noise, bias } = self.parts(bandwidth)?;
        let (w, h) = (self.width as usize, self.height as usize);
        let (px, bl) = self.judged();
        let rel = |err: &Pixels, m: &Pixels, keep: &[bool]| {
            let total = l1(m, keep);
            if total > 0.0 {
                l1(err, keep) / total
            } else {
                0.0
            }
        };
        let block = |v: &Pixels| blocks(v, w, h);
        let (bw, bh) = (w / BLOCK, h / BLOCK);
        let (pixel_bias, block_bias) = match &bias {
            Some((b, db)) => (
                Some(bias_sizes(b, db, (w, h), PIXEL_WINDOW)),
                Some(bias_sizes(&block(b), &block(db), (bw, bh), BLOCK_WINDOW)),
            ),
            None => (None, None),
        };
        let (block_mean, block_noise) = (block(&mean), block(&noise));
        Some(ErrorEstimate {
            pixel: rel(&together(&noise, pixel_bias.as_ref()), &mean, &px),
            block: rel(
                &together(&block_noise, block_bias.as_ref()),
                &block_mean,
                &bl,
            ),
            noise: Rel {
                pixel: rel(&noise, &mean, &px),
                block: rel(&block_noise, &block_mean, &bl),
            },
            bias: pixel_bias.zip(block_bias).map(|(p, b)| Rel {
                pixel: rel(&p, &mean, &px),
                block: rel(&b, &block_mean, &bl),
            }),
            passes: self.counts.passes,
        })
    }

    /// Which pixels and which 4x4 blocks the estimate judges: all but the pixels that see
    /// a light directly and the blocks that touch them (as `equal_time.py` judges).
    fn judged(&self) -> (Vec<bool>, Vec<bool>) {
        let (w, h) = (self.width as usize, self.height as usize);
        let (bw, bh) = (w / BLOCK, h / BLOCK);
        let (mut px, mut bl) = (vec![true; w * h], vec![true; bw * bh]);
        for &p in self.lights() {
            let p = p as usize;
            px[p] = false;
            let (bx, by) = (p % w / BLOCK, p / w / BLOCK);
            if bx < bw && by < bh {
                bl[by * bw + bx] = false;
            }
        }
        (px, bl)
    }

    /// Each pixel's signed bias estimate, -K D of the beams' and the photons' nested sums
    /// (radiance units, RGB), of the image at the fixed bandwidth; None until the noise
    /// can be estimated or where the beams' nested sums are missing.
    pub fn bias_map(&self) -> Option<Vec<[f64; 3]>> {
        Some(self.parts(Bandwidth::Fixed)?.bias?.0)
    }

    /// Each pixel's lambda in the image `bandwidth` resolves: the weight of the r/2 kernel
    /// (0 everywhere at the fixed bandwidth); None until the noise can be estimated or
    /// where the nested sums are missing.
    pub fn lambda_map(&self, bandwidth: Bandwidth) -> Option<Vec<f32>> {
        let r = self.resolve(bandwidth)?;
        r.d.as_ref()?;
        Some(r.lambda.iter().map(|&l| l as f32).collect())
    }

    /// Each pixel's expected absolute error per channel (radiance units) in the image
    /// `bandwidth` resolves: its noise (the half-films' scaled difference, its absolute
    /// value averaged over the 3x3 pixels around, one pixel's difference being a single
    /// draw) and its bias size together; None as for [`Film::error_estimate`].
    pub fn error_map(&self, bandwidth: Bandwidth) -> Option<Vec<[f32; 3]>> {
        let Parts { noise, bias, .. } = self.parts(bandwidth)?;
        let (w, h) = (self.width as usize, self.height as usize);
        let abs: Pixels = noise.iter().map(|d| d.map(f64::abs)).collect();
        let sizes = bias.map(|(b, db)| bias_sizes(&b, &db, (w, h), PIXEL_WINDOW));
        let map = together(&window_mean(&abs, w, h, 1), sizes.as_ref());
        Some(map.iter().map(|v| v.map(|c| c as f32)).collect())
    }
}

/// The parts of a resolved image's error (`Film::parts`).
struct Parts {
    mean: Pixels,
    noise: Pixels,
    bias: Option<(Pixels, Pixels)>,
}

/// Noise and bias sizes per pixel and channel as one expected error, sqrt(n^2 + b^2)
/// (exact for either alone; for Gaussian noise E|b + N| is at most 9 % below it).
fn together(noise: &Pixels, bias: Option<&Pixels>) -> Pixels {
    match bias {
        Some(b) => noise
            .iter()
            .zip(b)
            .map(|(n, b)| [0, 1, 2].map(|c| n[c].hypot(b[c])))
            .collect(),
        None => noise.clone(),
    }
}

/// Sum of |v| over the kept pixels.
fn l1(v: &[[f64; 3]], keep: &[bool]) -> f64 {
    v.iter()
        .zip(keep)
        .filter(|(_, &k)| k)
        .flat_map(|(p, _)| p)
        .map(|x| x.abs())
        .sum()
}

/// The mean of each pixel's (2 k + 1)^2 window, clipped at the image's edges; rows in
/// parallel (the estimate sweeps the film several times, after every render and as
/// often as `watch` and `--target-error` ask).
fn window_mean(v: &[[f64; 3]], w: usize, h: usize, k: usize) -> Pixels {
    let mut out = vec![[0f64; 3]; w * h];
    out.par_chunks_mut(w.max(1))
        .enumerate()
        .for_each(|(y, row)| {
            let ys = y.saturating_sub(k)..(y + k + 1).min(h);
            for (x, o) in row.iter_mut().enumerate() {
                let xs = x.saturating_sub(k)..(x + k + 1).min(w);
                let count = (ys.len() * xs.len()) as f64;
                let mut sum = [0f64; 3];
                for v2 in ys.clone() {
                    for u in xs.clone() {
                        let p = v[v2 * w + u];
                        (0..3).for_each(|c| sum[c] += p[c]);
                    }
                }
                *o = sum.map(|s| s / count);
            }
        });
    out
}

/// The spread of a window mean of b^2 - db^2 under pure noise, per unit of db^2, at each
/// pixel: 2 / sqrt(m) for Gaussian noise over m independent pixels. A kernel's noise is
/// shared by the pixels it covers (a smooth photon map's over many), so m is the window's
/// effective count, wm'(db^2) / wm'(wm(db)^2) (wm: the window mean, wm' one 3 times as
/// wide: db's own window means show how much of its noise the window averages away),
/// within 1 and the window's pixels.
fn window_spread(db: &Pixels, w: usize, h: usize, k: usize) -> Vec<f64> {
    let sq = |v: &Pixels| -> Pixels {
        v.iter()
            .map(|p| [p.iter().map(|c| c * c).sum(), 0.0, 0.0])
            .collect()
    };
    let wide = 3 * k + 1;
    let all = window_mean(&sq(db), w, h, wide);
    let kept = window_mean(&sq(&window_mean(db, w, h, k)), w, h, wide);
    let count = ((2 * k + 1) * (2 * k + 1)) as f64;
    all.iter()
        .zip(&kept)
        .map(|(a, s)| {
            let m = if s[0] > 0.0 {
                (a[0] / s[0]).clamp(1.0, count)
            } else {
                count
            };
            2.0 / m.sqrt()
        })
        .collect()
}

/// How large a signed bias estimate `b` (with its noise deviation `db`) is per pixel:
/// sqrt of the window mean of b^2 - db^2 (the estimate's own noise removed), less that
/// mean's own spread ([`window_spread`], so that pure noise rarely reads as bias),
/// clipped at zero.
fn bias_sizes(b: &Pixels, db: &Pixels, (w, h): (usize, usize), k: usize) -> Pixels {
    let sq = |v: &Pixels| -> Pixels { v.iter().map(|p| p.map(|c| c * c)).collect() };
    let (b2, db2) = (window_mean(&sq(b), w, h, k), window_mean(&sq(db), w, h, k));
    let spread = window_spread(db, w, h, k);
    b2.iter()
        .zip(&db2)
        .zip(&spread)
        .map(|((s, n), sp)| [0, 1, 2].map(|c| (s[c] - n[c] - sp * n[c]).max(0.0).sqrt()))
        .collect()
}

/// Each pixel's lambda: the minimiser over [0, 1] of the estimated squared error of
/// X + lambda D (see the module's comment), from the window means of the moments summed
/// over the channels (one radius per pixel). cov(X, D) is taken as zero: with I and O the
/// kernel's inner and outer halves' sums, X's beam part is (I + O) / 2r and D is
/// (I - O) / 2r, whose covariance vanishes where the beams' density is locally even; its
/// windowed estimate would only add noise to lambda.
fn lambdas(d: &Moments, w: usize, h: usize) -> Vec<f64> {
    let per_pixel = |f: &dyn Fn(usize, usize) -> f64| -> Pixels {
        (0..w * h)
            .map(|i| [f(i, 0) + f(i, 1) + f(i, 2), 0.0, 0.0])
            .collect()
    };
    let e2 = per_pixel(&|i, c| d.mean[i][c].powi(2) - d.dev[i][c].powi(2));
    let vd = per_pixel(&|i, c| d.dev[i][c].powi(2));
    let k = PIXEL_WINDOW;
    let spread = window_spread(&d.dev, w, h, k);
    let (e2, vd) = (window_mean(&e2, w, h, k), window_mean(&vd, w, h, k));
    (0..w * h)
        .map(|i| {
            let v = vd[i][0];
            let e = (e2[i][0] - NARROW_SPREADS * spread[i] * v).max(0.0);
            if e + v <= 0.0 {
                return 0.0;
            }
            (BIAS_PER_D * e / (e + v)).min(1.0)
        })
        .collect()
}

/// Means over whole [`BLOCK`] x [`BLOCK`] blocks (a partial block at an edge is left out,
/// as `compare::block_mean` does).
fn blocks(v: &[[f64; 3]], w: usize, h: usize) -> Vec<[f64; 3]> {
    let (bw, bh) = (w / BLOCK, h / BLOCK);
    let mut out = vec![[0f64; 3]; bw * bh];
    let k = 1.0 / (BLOCK * BLOCK) as f64;
    for y in 0..bh * BLOCK {
        for x in 0..bw * BLOCK {
            let o = &mut out[(y / BLOCK) * bw + x / BLOCK];
            for c in 0..3 {
                o[c] += v[y * w + x][c] * k;
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::Rng;
    use glam::Vec3;
    use std::f64::consts::PI;

    fn gauss(rng: &mut Rng) -> f32 {
        let (u, v) = (1.0 - rng.f32(), rng.f32());
        (-2.0 * u.ln()).sqrt() * (2.0 * std::f32::consts::PI * v).cos()
    }

    /// `passes` passes of a 64x64 film whose pixels are `mean` plus noise shared by each
    /// 4x4 block (sd `block_sd`) plus noise of their own (sd `pixel_sd`).
    fn film(passes: u32, mean: f32, block_sd: f32, pixel_sd: f32) -> Film {
        film_with_light(passes, mean, block_sd, pixel_sd, 0)
    }

    /// [`film`] with its first `light` pixels (row 0) a bright, noisy light: the same
    /// draws scaled 1000 times, the noise 10,000 times.
    fn film_with_light(passes: u32, mean: f32, block_sd: f32, pixel_sd: f32, light: usize) -> Film {
        const N: usize = 64;
        let mut film = Film::new(N as u32, N as u32);
        let mut rng = Rng::new(7, 1);
        for i in 1..=passes {
            let shared: Vec<f32> = (0..(N / 4) * (N / 4)).map(|_| gauss(&mut rng)).collect();
            let img: Vec<Vec3> = (0..N * N)
                .map(|p| {
                    let b = shared[(p / N / 4) * (N / 4) + (p % N) / 4];
                    let (m, s) = if p < light { (1e3, 1e4) } else { (1.0, 1.0) };
                    Vec3::from_array(
                        [0; 3].map(|_| m * mean + s * (block_sd * b + pixel_sd * gauss(&mut rng))),
                    )
                })
                .collect();
            film.add_pass(i % 2 == 1, &img);
        }
        film
    }

    /// Gaussian noise of sd s on the mean of n passes has E|X - EX| = s sqrt(2 / pi n).
    fn expected(sd: f64, passes: u32, mean: f64) -> f64 {
        sd * (2.0 / (PI * f64::from(passes))).sqrt() / mean
    }

    /// The estimate's relative sd: one |N(0, 1)| term has sd sqrt(1 - 2/pi) over a mean of
    /// sqrt(2/pi); `terms` independent ones average it down.
    fn tolerance(terms: usize) -> f64 {
        4.0 * ((PI / 2.0 - 1.0) / terms as f64).sqrt()
    }

    /// The pixels that see a light are left out of the estimate, with the blocks they
    /// touch: a bright, noisy light there changes nothing.
    #[test]
    fn leaves_the_lights_pixels_out() {
        let light: Vec<u32> = (0..8).collect();
        let plain = film(25, 2.0, 0.1, 0.5).with_lights(light.clone());
        let lit = film_with_light(25, 2.0, 0.1, 0.5, light.len());
        let e = |f: &Film| f.error_estimate(Bandwidth::Fixed).unwrap();
        let (a, b) = (e(&plain), e(&lit.clone().with_lights(light)));
        assert_eq!((a.pixel, a.block), (b.pixel, b.block));
        let c = e(&lit);
        assert!(
            c.pixel > 2.0 * a.pixel && c.block > 2.0 * a.block,
            "{c:?} vs {a:?}"
        );
    }

    #[test]
    fn matches_independent_noise_per_pixel_and_on_blocks() {
        // An odd pass count: halves of 12 and 13 passes.
        let (n, mean, sd) = (25, 2.0, 0.5);
        let e = film(n, mean, 0.0, sd)
            .error_estimate(Bandwidth::Fixed)
            .unwrap();
        let want = expected(f64::from(sd), n, f64::from(mean));
        let tol = tolerance(64 * 64 * 3);
        assert!((e.pixel / want - 1.0).abs() < tol, "{} vs {want}", e.pixel);
        let want = expected(f64::from(sd) / 4.0, n, f64::from(mean));
        let tol = tolerance(16 * 16 * 3);
        assert!((e.block / want - 1.0).abs() < tol, "{} vs {want}", e.block);
        assert_eq!(e.passes, n);
    }

    /// Noise shared by a block's pixels (a beam's kernel spanning them) stays in the block
    /// estimate, where a per-pixel variance would divide it by 4.
    #[test]
    fn keeps_noise_correlated_across_a_block() {
        let (n, mean, bsd, psd) = (16, 1.0f32, 0.3f32, 0.4f32);
        let e = film(n, mean, bsd, psd)
            .error_estimate(Bandwidth::Fixed)
            .unwrap();
        let (b, p) = (f64::from(bsd), f64::from(psd));
        let pixel = expected((b * b + p * p).sqrt(), n, f64::from(mean));
        let block = expected((b * b + p * p / 16.0).sqrt(), n, f64::from(mean));
        // The shared draws are per block: 768 of them set both sums' spread.
        let tol = tolerance(16 * 16 * 3);
        assert!(
            (e.pixel / pixel - 1.0).abs() < tol,
            "{} vs {pixel}",
            e.pixel
        );
        assert!(
            (e.block / block - 1.0).abs() < tol,
            "{} vs {block}",
            e.block
        );
    }

    /// `passes` passes of a 64x64 film of mean `mean` whose nested sums say its bias is
    /// `bias`: each pixel's beam estimate is the sum of an inner and an outer half
    /// (independent, sd `sd` each), X = mean + bias + (a + b) and D = -bias / K + (a - b),
    /// the nested kernel's structure (`lambdas`).
    fn nested_film(passes: u32, mean: f32, bias: f32, sd: f32) -> Film {
        const N: usize = 64;
        let mut film = Film::new(N as u32, N as u32);
        let mut rng = Rng::new(9, 2);
        let k = BIAS_PER_D as f32;
        for i in 1..=passes {
            let (x, d): (Vec<Vec3>, Vec<Vec3>) = (0..N * N)
                .map(|_| {
                    let (a, b) = (sd * gauss(&mut rng), sd * gauss(&mut rng));
                    (
                        Vec3::splat(mean + bias + a + b),
                        Vec3::splat(-bias / k + a - b),
                    )
                })
                .unzip();
            film.add_pass(i % 2 == 1, &x);
            film.add_nested(i % 2 == 1, &d);
        }
        film
    }

    /// A bias well above the noise is measured at its size (the window's noise
    /// correction, 0.4 K^2 var D against bias^2 = 0.09, moves it by under 0.2 %; the
    /// window means of 4096 pixels leave well under 1 %), and the adaptive image takes
    /// the narrow kernel everywhere: its bias is the r/2 estimate's, (1 - 1/K) of it.
    #[test]
    fn nested_sums_measure_a_bias_and_narrow_the_kernel() {
        let (mean, bias, sd) = (2.0f32, 0.3f32, 0.1f32);
        let f = nested_film(64, mean, bias, sd);
        let e = f.error_estimate(Bandwidth::Fixed).unwrap();
        let want = f64::from(bias / (mean + bias));
        let got = e.bias.unwrap().pixel;
        assert!((got / want - 1.0).abs() < 0.01, "{got} vs {want}");
        let adaptive = f.image_with(Bandwidth::Adaptive);
        let avg = adaptive.iter().map(|p| f64::from(p[0])).sum::<f64>() / 4096.0;
        let narrow = f64::from(mean) + f64::from(bias) * (1.0 - 1.0 / BIAS_PER_D);
        // The mean of 4096 pixels of sd sqrt(2 sd^2 / 64) each: 4 standard errors.
        let tol = 4.0 * (2.0 * f64::from(sd * sd) / 64.0 / 4096.0).sqrt();
        assert!((avg - narrow).abs() < tol, "{avg} vs {narrow}");
        let a = f.error_estimate(Bandwidth::Adaptive).unwrap();
        assert!(a.bias.unwrap().pixel < 0.5 * got, "{a:?}");
    }

    /// Without a bias the nested sums read as little bias and keep the wide kernel nearly
    /// everywhere: windowed over 25 pixels and less one spread of its own, pure noise
    /// leaves at most about 0.18 K sqrt(var D) (Jensen's bound on E sqrt(max(0, Z - 1)
    /// 0.4)), a third of the noise E|dev| = 0.8 sqrt(var X); lambda, at three spreads, is
    /// far less often above zero than the size estimate (whose mean would be about
    /// K 0.083 0.4 = 0.05 at one).
    #[test]
    fn nested_sums_without_bias_keep_the_wide_kernel() {
        let f = nested_film(64, 2.0, 0.0, 0.1);
        let e = f.error_estimate(Bandwidth::Fixed).unwrap();
        let bias = e.bias.unwrap().pixel;
        assert!(bias < 0.35 * e.noise.pixel, "{e:?}");
        let d = f.moments(&f.nested).unwrap();
        let lambda = lambdas(&d, 64, 64);
        let mean = lambda.iter().sum::<f64>() / lambda.len() as f64;
        assert!(mean < 0.08, "mean lambda {mean}");
        // The total is noise and bias together, at least the noise.
        assert!(e.pixel >= e.noise.pixel && e.pixel < e.noise.pixel + bias);
    }

    #[test]
    fn waits_for_two_passes_in_each_half_and_maps_every_pixel() {
        assert!(film(3, 1.0, 0.0, 0.1)
            .error_estimate(Bandwidth::Fixed)
            .is_none());
        let f = film(4, 1.0, 0.0, 0.1);
        assert!(f.error_estimate(Bandwidth::Fixed).is_some());
        let map = f.error_map(Bandwidth::Fixed).unwrap();
        assert_eq!(map.len(), 64 * 64);
        let mean = map.iter().flatten().map(|&v| f64::from(v)).sum::<f64>() / (3.0 * 4096.0);
        let want = expected(0.1, 4, 1.0);
        assert!(
            (mean / want - 1.0).abs() < tolerance(4096 * 3),
            "{mean} vs {want}"
        );
        // A noiseless film has no error.
        assert_eq!(
            film(4, 1.0, 0.0, 0.0)
                .error_estimate(Bandwidth::Fixed)
                .unwrap()
                .pixel,
            0.0
        );
    }
}
