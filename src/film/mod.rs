//! Progressive accumulation: the image is the mean of the pass images (each pass is an
//! independent estimate with its own radii, as in Knaus and Zwicker's formulation).
//!
//! Sums are fixed-point integers: every value added is rounded once to a multiple of
//! 2^-[`FRACTION_BITS`], and integer addition is associative. So the sums of passes
//! 1..=8 are the same bits whether one process adds them in order or shards add 1..=4
//! and 5..=8 and a merge adds the two sums ([`Film::merge`]): farm renders merge exactly.
//!
//! Beside the sums of all passes the film keeps those of the odd passes (those of
//! odd-numbered groups where passes share samples, `plan::Plan::group`): two interleaved
//! half-films, whose difference is the reference-free noise estimate of [`error`]. And
//! beside the image it keeps the nested sums, the beams' and the surface photons' apart:
//! the estimate at half the radius minus the one at the radius (`core::Nested`), whose
//! mean estimates the kernel's bias; the beams' also let [`error`] choose a radius per
//! pixel.
pub mod error;

use rayon::prelude::*;

use crate::core::{Nested, Rgb};

/// Fraction bits of the fixed-point sums: a resolution of 3.6e-15, and room for sums up
/// to 2^79 (6e23) in an i128.
pub const FRACTION_BITS: i32 = 48;
const SCALE: f64 = (1u64 << FRACTION_BITS) as f64;

/// Per-pixel fixed-point RGB sums of all passes and of the odd passes alone.
#[derive(Clone, Debug, PartialEq)]
pub struct Halves {
    pub all: Vec<[i128; 3]>,
    pub odd: Vec<[i128; 3]>,
}

impl Halves {
    fn new(pixels: usize) -> Self {
        Halves {
            all: vec![[0; 3]; pixels],
            odd: vec![[0; 3]; pixels],
        }
    }

    /// In parallel: a pass adds several images, and a serial sweep here was a tenth of a
    /// 2-core pass's wall time (more with more cores). Integer sums: the same bits.
    fn add(&mut self, odd: bool, img: &[Rgb]) {
        self.add_with(odd, img, |p| *p);
    }

    fn add_with<T: Sync>(&mut self, odd: bool, img: &[T], rgb: impl Fn(&T) -> Rgb + Sync) {
        self.all
            .par_iter_mut()
            .zip(self.odd.par_iter_mut())
            .zip(img.par_iter())
            .with_min_len(MIN_PIXELS_PER_TASK)
            .for_each(|((s, o), p)| {
                let p = rgb(p);
                let v = [fixed(p.x), fixed(p.y), fixed(p.z)];
                for c in 0..3 {
                    s[c] += v[c];
                    if odd {
                        o[c] += v[c];
                    }
                }
            });
    }

    fn merge(&mut self, other: &Halves) {
        for (mine, theirs) in [(&mut self.all, &other.all), (&mut self.odd, &other.odd)] {
            for (s, o) in mine.iter_mut().zip(theirs) {
                for c in 0..3 {
                    s[c] += o[c];
                }
            }
        }
    }

    /// The mean over the odd or the even passes, `n` of them.
    fn half(&self, odd: bool, n: u32) -> Vec<[f64; 3]> {
        let inv = 1.0 / n.max(1) as f64;
        self.all
            .iter()
            .zip(&self.odd)
            .map(|(s, o)| [0, 1, 2].map(|c| float(if odd { o[c] } else { s[c] - o[c] }) * inv))
            .collect()
    }

    fn matches(&self, pixels: usize) -> bool {
        self.all.len() == pixels && self.odd.len() == pixels
    }
}

/// How many passes a film holds: all, the odd ones, and those whose beam estimate added
/// the nested sums (counted when the CPU adds them, or when the GPU's are absorbed).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Counts {
    pub passes: u32,
    pub odd: u32,
    pub nested: u32,
}

#[derive(Clone, Debug, PartialEq)]
pub struct Film {
    pub width: u32,
    pub height: u32,
    image: Halves,
    /// Sums of the beams' nested half-radius difference (the adaptive bandwidth's D).
    nested: Halves,
    /// Sums of the surface photons' nested difference (in the bias estimate only).
    photons: Halves,
    counts: Counts,
    /// Alpha sums (a transparent film), else empty.
    alpha: Vec<i128>,
    /// Pixels that see a light directly (sorted): left out of the error estimate.
    lights: Vec<u32>,
}

/// Pixels per parallel task of the film's sweeps.
const MIN_PIXELS_PER_TASK: usize = 4096;

/// `x` as a fixed-point value, rounded half away from zero; non-finite values (never
/// produced by a correct pass) saturate or become 0, so they cannot poison a merge.
fn fixed(x: f32) -> i128 {
    let v = x as f64 * SCALE;
    // Below 2^14 (2^62 in fixed point), nearly every radiance, an i64 rounds exactly and
    // without the software i128 conversion and the libm call, a fifth of a film sweep.
    if v.abs() < I64_EXACT {
        let t = v as i64;
        let frac = v - t as f64;
        (t + i64::from(frac >= 0.5) - i64::from(frac <= -0.5)) as i128
    } else {
        v.round() as i128
    }
}

/// 2^62: below it, truncation to i64 and the fraction left are exact.
const I64_EXACT: f64 = (1u64 << 62) as f64;

fn float(s: i128) -> f64 {
    s as f64 / SCALE
}

impl Film {
    pub fn new(width: u32, height: u32) -> Self {
        let pixels = (width * height) as usize;
        Film {
            width,
            height,
            image: Halves::new(pixels),
            nested: Halves::new(pixels),
            photons: Halves::new(pixels),
            counts: Counts::default(),
            alpha: Vec::new(),
            lights: Vec::new(),
        }
    }

    /// The film with `pixels` (those that see a light directly) left out of its error
    /// estimate, as the references are judged: a small bright light can hold most of an
    /// image's sum, so a relative error over it would say little about the rest.
    pub fn with_lights(mut self, mut pixels: Vec<u32>) -> Self {
        pixels.sort_unstable();
        pixels.dedup();
        pixels.retain(|&p| (p as usize) < self.image.all.len());
        self.lights = pixels;
        self
    }

    /// The pixels left out of the error estimate.
    pub fn lights(&self) -> &[u32] {
        &self.lights
    }

    /// A film from stored sums (a part file): the image's and the nested ones over the
    /// passes `counts` gives; None when a pixel count does not match the size or the
    /// counts do not add up.
    pub fn from_sums(
        width: u32,
        height: u32,
        counts: Counts,
        image: Halves,
        nested: Halves,
        photons: Halves,
    ) -> Option<Self> {
        let n = (width as usize) * (height as usize);
        let ok = image.matches(n)
            && nested.matches(n)
            && photons.matches(n)
            && counts.odd <= counts.passes
            && counts.nested <= counts.passes;
        ok.then_some(Film {
            width,
            height,
            image,
            nested,
            photons,
            counts,
            alpha: Vec::new(),
            lights: Vec::new(),
        })
    }

    /// With stored alpha sums (one per pixel); None when the count does not match.
    pub fn with_alpha_sums(self, alpha: Vec<i128>) -> Option<Self> {
        (alpha.len() == self.image.all.len()).then_some(Film { alpha, ..self })
    }

    /// The fixed-point alpha sums (empty unless the film is transparent).
    pub fn alpha_sums(&self) -> &[i128] {
        &self.alpha
    }

    /// Adds a pass's alpha (transparent film; nothing when `alpha` is empty).
    pub fn add_alpha(&mut self, alpha: &[f32]) {
        if alpha.is_empty() {
            return;
        }
        if self.alpha.is_empty() {
            self.alpha = vec![0; self.image.all.len()];
        }
        for (s, &a) in self.alpha.iter_mut().zip(alpha) {
            *s += fixed(a);
        }
    }

    /// The mean alpha over passes, when the film is transparent.
    pub fn alpha(&self) -> Option<Vec<f32>> {
        let inv = 1.0 / self.counts.passes.max(1) as f64;
        (!self.alpha.is_empty()).then(|| {
            self.alpha
                .iter()
                .map(|&s| (float(s) * inv) as f32)
                .collect()
        })
    }

    /// The image's fixed-point sums, row-major RGB, of all passes and of the odd ones.
    pub fn sums(&self) -> &Halves {
        &self.image
    }

    /// The beams' nested half-radius difference's sums.
    pub fn nested_sums(&self) -> &Halves {
        &self.nested
    }

    /// The surface photons' nested difference's sums.
    pub fn photon_sums(&self) -> &Halves {
        &self.photons
    }

    pub fn counts(&self) -> Counts {
        self.counts
    }

    /// Adds `img` to the sums of the current pass, odd or not (one pass adds several
    /// estimates).
    pub fn add(&mut self, odd: bool, img: &[Rgb]) {
        self.image.add(odd, img);
    }

    /// Adds `img` as the first estimate of a pass, odd or not, and counts the pass.
    pub fn add_pass(&mut self, odd: bool, img: &[Rgb]) {
        self.add(odd, img);
        self.counts.passes += 1;
        self.counts.odd += u32::from(odd);
    }

    /// Adds the current pass's beams' nested half-radius difference (once per pass) and
    /// counts it.
    pub fn add_nested(&mut self, odd: bool, d: &[Rgb]) {
        self.nested.add(odd, d);
        self.counts.nested += 1;
    }

    /// Adds the current pass's beam estimate with its nested difference:
    /// [`Self::add`] of the `l`s and [`Self::add_nested`] of the `d`s.
    pub fn add_beams(&mut self, odd: bool, beams: &[Nested]) {
        self.image.add_with(odd, beams, |n| n.l);
        self.nested.add_with(odd, beams, |n| n.d);
        self.counts.nested += 1;
    }

    /// Adds the current pass's surface photons' nested difference (every pass has one,
    /// from its camera paths).
    pub fn add_photon_nested(&mut self, odd: bool, d: &[Rgb]) {
        self.photons.add(odd, d);
    }

    /// Adds another film's sums and passes (same size); the result does not depend on
    /// the order in which films are merged.
    pub fn merge(&mut self, other: &Film) {
        debug_assert_eq!((self.width, self.height), (other.width, other.height));
        self.image.merge(&other.image);
        self.nested.merge(&other.nested);
        self.photons.merge(&other.photons);
        if self.alpha.is_empty() {
            self.alpha = vec![0; other.alpha.len()];
        }
        for (s, o) in self.alpha.iter_mut().zip(&other.alpha) {
            *s += o;
        }
        self.counts.passes += other.counts.passes;
        self.counts.odd += other.counts.odd;
        self.counts.nested += other.counts.nested;
    }

    pub fn passes(&self) -> u32 {
        self.counts.passes
    }

    /// Odd passes.
    pub fn odd_passes(&self) -> u32 {
        self.counts.odd
    }

    /// The current estimate: mean over passes, row-major RGB.
    pub fn image(&self) -> Vec<[f32; 3]> {
        let inv = 1.0 / self.counts.passes.max(1) as f64;
        self.image
            .all
            .iter()
            .map(|s| s.map(|c| (float(c) * inv) as f32))
            .collect()
    }

    /// Adds per-pixel sums kept outside the film (the GPU's, over the same passes) into
    /// it, once, so the film can be shown or stored.
    pub fn absorb(&mut self, extra: &Held) {
        let [even, odd] = &extra.halves;
        let rgb = |p: &[f32]| Rgb::new(p[0], p[1], p[2]);
        for (sums, at) in [(&mut self.image, 0), (&mut self.nested, 4)] {
            let (e, o): (Vec<Rgb>, Vec<Rgb>) = even
                .iter()
                .zip(odd)
                .map(|(e, o)| (rgb(&e[at..at + 3]), rgb(&o[at..at + 3])))
                .unzip();
            sums.add(false, &e);
            sums.add(true, &o);
        }
        self.counts.nested += extra.passes;
    }
}

/// Per-pixel sums kept outside the film (the GPU's), of the even and of the odd passes:
/// the beam estimate's RGB and evaluation count, then the nested difference's RGB and a
/// pad; and how many passes they hold.
#[derive(Clone, Debug, Default)]
pub struct Held {
    pub halves: [Vec<[f32; 8]>; 2],
    pub passes: u32,
}

impl Film {
    /// How many passes the odd or the even half holds.
    fn half_passes(&self, odd: bool) -> u32 {
        if odd {
            self.counts.odd
        } else {
            self.counts.passes - self.counts.odd
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    /// The i64 rounding is `f64::round` to i128 (half away from zero, saturating, NaN to
    /// 0) on halves, the limits of the fast path, non-finite values and random bits.
    #[test]
    fn fixed_rounds_as_f64_round() {
        let reference = |x: f32| (x as f64 * SCALE).round() as i128;
        let ulp = 1.0 / SCALE as f32;
        let mut xs = vec![
            0.0,
            -0.0,
            f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::MAX,
        ];
        xs.extend([
            f32::MIN,
            f32::MIN_POSITIVE,
            16384.0,
            16383.999,
            1e-20,
            3.3e-15,
        ]);
        for k in [1.0f32, 3.0, 5.0, 1025.0] {
            xs.extend([0.5 * k * ulp, 0.5 * k * ulp * (1.0 + f32::EPSILON)]);
        }
        let mut bits = 0x2545_f491_u32;
        for _ in 0..2_000_000 {
            bits ^= bits << 13;
            bits ^= bits >> 17;
            bits ^= bits << 5;
            xs.push(f32::from_bits(bits));
        }
        for x in xs.iter().flat_map(|&x| [x, -x]) {
            assert_eq!(fixed(x), reference(x), "{x:e}");
        }
    }

    /// Sharded sums merge to the very bits of one film adding every pass in order.
    #[test]
    fn merged_shards_equal_one_film_bit_for_bit() {
        let pass = |i: u32| -> Vec<Rgb> {
            (0..7)
                .map(|p| {
                    let x = ((i * 7 + p) as f32 * 0.618_034).fract();
                    Vec3::new(x * 1e-6, x * 3.7, x.powi(9) * 1e4)
                })
                .collect()
        };
        let mut one = Film::new(7, 1);
        for i in 1..=12 {
            one.add_pass(i % 2 == 1, &pass(i));
        }
        let mut shards: Vec<Film> = [(1, 5), (5, 6), (6, 13)]
            .iter()
            .map(|&(a, b)| {
                let mut f = Film::new(7, 1);
                (a..b).for_each(|i| f.add_pass(i % 2 == 1, &pass(i)));
                f
            })
            .collect();
        let mut merged = shards.pop().unwrap();
        for s in shards.iter().rev() {
            merged.merge(s);
        }
        assert_eq!(merged, one);
        assert_eq!((one.passes(), one.odd_passes()), (12, 6));
        assert_eq!(merged.image(), one.image());
        // The mean is within the fixed point's resolution of the f64 mean.
        let exact: f64 = (1..=12).map(|i| pass(i)[3].y as f64).sum::<f64>() / 12.0;
        assert!((one.image()[3][1] as f64 - exact).abs() <= 1e-6 * exact);
    }
}
