//! How far the film is from converged, without a reference: the noise of the mean of the
//! passes, from the film's two interleaved half-films. Hachisuka, Jarosz and Jensen (2010)
//! estimate the noise of progressive density estimation from the spread of its passes; the
//! difference of the half-films is that spread summed per pixel, and it is how ppb's
//! conformance references are judged (two renders' rel_l1 / sqrt 2).
//!
//! With A the mean of the n_a even passes, B that of the n_b odd ones (alternate passes, or
//! alternate groups of passes that share samples) and X the mean of all n = n_a + n_b:
//! when the passes are independent, (A - B) sqrt(n_a n_b) / n
//! has the variance of X - E[X] (exactly for equal variances, and nearly for the
//! progressive passes' slowly growing ones, which interleaving splits evenly). Its absolute
//! value summed over pixels and channels, over the sum of |X|, is the expected rel_l1 of X
//! from its own mean. On 4x4 block means the same difference keeps the noise's correlation
//! across pixels (a beam's kernel covers several), which an estimate from per-pixel
//! variances would miss.
//!
//! Not in it: the bias of the kernel's blur, which shrinks with the radii and is smaller
//! than the noise at the budgets measured in docs/error-estimate.md.
use super::Film;

/// Block size of the low-frequency error (4x4 block means, as the conformance tests judge).
pub const BLOCK: usize = 4;

/// Passes each half-film needs before its noise is estimated.
pub const MIN_HALF_PASSES: u32 = 2;

/// Per-pixel RGB in f64, row-major.
type Pixels = Vec<[f64; 3]>;

/// The expected rel_l1 of the film's image from its converged mean.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct ErrorEstimate {
    /// Per pixel and channel.
    pub pixel: f64,
    /// On the means of whole 4x4 blocks.
    pub block: f64,
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

impl Film {
    /// The half-films' scaled difference per pixel (RGB) and the mean image; None until
    /// each half holds [`MIN_HALF_PASSES`] passes.
    fn deviation(&self) -> Option<(Pixels, Pixels)> {
        let (nb, odd) = self.half(true);
        let (na, even) = self.half(false);
        if na.min(nb) < MIN_HALF_PASSES {
            return None;
        }
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
        Some((dev, mean))
    }

    /// The expected rel_l1 of the image from its converged mean, per pixel and on 4x4 block
    /// means; None until each half-film holds [`MIN_HALF_PASSES`] passes.
    pub fn error_estimate(&self) -> Option<ErrorEstimate> {
        let (dev, mean) = self.deviation()?;
        let l1 = |v: &[[f64; 3]]| v.iter().flatten().map(|x| x.abs()).sum::<f64>();
        let (w, h) = (self.width as usize, self.height as usize);
        let ratio = |d: f64, x: f64| if x > 0.0 { d / x } else { 0.0 };
        Some(ErrorEstimate {
            pixel: ratio(l1(&dev), l1(&mean)),
            block: ratio(l1(&blocks(&dev, w, h)), l1(&blocks(&mean, w, h))),
            passes: self.passes,
        })
    }

    /// Each pixel's expected absolute error per channel (radiance units): the half-films'
    /// scaled difference, its absolute value averaged over the 3x3 pixels around (one
    /// pixel's difference alone is a single draw); None as for [`Film::error_estimate`].
    pub fn error_map(&self) -> Option<Vec<[f32; 3]>> {
        let (dev, _) = self.deviation()?;
        let (w, h) = (self.width as usize, self.height as usize);
        let mut map = vec![[0f32; 3]; w * h];
        for y in 0..h {
            for x in 0..w {
                let (ys, xs) = (
                    y.saturating_sub(1)..(y + 2).min(h),
                    x.saturating_sub(1)..(x + 2).min(w),
                );
                let count = (ys.len() * xs.len()) as f64;
                let mut sum = [0f64; 3];
                for v in ys {
                    for u in xs.clone() {
                        let d = dev[v * w + u];
                        (0..3).for_each(|c| sum[c] += d[c].abs());
                    }
                }
                map[y * w + x] = sum.map(|s| (s / count) as f32);
            }
        }
        Some(map)
    }
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
        const N: usize = 64;
        let mut film = Film::new(N as u32, N as u32);
        let mut rng = Rng::new(7, 1);
        for i in 1..=passes {
            let shared: Vec<f32> = (0..(N / 4) * (N / 4)).map(|_| gauss(&mut rng)).collect();
            let img: Vec<Vec3> = (0..N * N)
                .map(|p| {
                    let b = shared[(p / N / 4) * (N / 4) + (p % N) / 4];
                    Vec3::from_array(
                        [0; 3].map(|_| mean + block_sd * b + pixel_sd * gauss(&mut rng)),
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

    #[test]
    fn matches_independent_noise_per_pixel_and_on_blocks() {
        // An odd pass count: halves of 12 and 13 passes.
        let (n, mean, sd) = (25, 2.0, 0.5);
        let e = film(n, mean, 0.0, sd).error_estimate().unwrap();
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
        let e = film(n, mean, bsd, psd).error_estimate().unwrap();
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

    #[test]
    fn waits_for_two_passes_in_each_half_and_maps_every_pixel() {
        assert!(film(3, 1.0, 0.0, 0.1).error_estimate().is_none());
        let f = film(4, 1.0, 0.0, 0.1);
        assert!(f.error_estimate().is_some());
        let map = f.error_map().unwrap();
        assert_eq!(map.len(), 64 * 64);
        let mean = map.iter().flatten().map(|&v| f64::from(v)).sum::<f64>() / (3.0 * 4096.0);
        let want = expected(0.1, 4, 1.0);
        assert!(
            (mean / want - 1.0).abs() < tolerance(4096 * 3),
            "{mean} vs {want}"
        );
        // A noiseless film has no error.
        assert_eq!(film(4, 1.0, 0.0, 0.0).error_estimate().unwrap().pixel, 0.0);
    }
}
