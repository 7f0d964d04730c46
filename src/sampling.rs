//! Random streams and warps.
//!
//! Every light path and every pixel of every pass gets its own stream, keyed by
//! (seed, pass, stream kind, index), so images do not depend on the thread count.
//! The generator is PCG32 (O'Neill 2014) written here: a dozen lines whose output we
//! pin in tests, where a crate's stream could change under a version bump.
use glam::{Vec2, Vec3};
use std::f32::consts::PI;

#[derive(Clone, Debug)]
pub struct Rng {
    state: u64,
    inc: u64,
}

/// Which part of a pass a stream serves; keeps the streams of one pass independent.
#[derive(Clone, Copy, Debug)]
#[repr(u64)]
pub enum Stream {
    Light = 1,
    Camera = 2,
    /// Pixel jitter kept for a stratified-transmittance block (keyed by block, not pass).
    CameraJitter = 3,
    /// The free paths drawn for a stratified block.
    TrBlock = 4,
    /// The order in which a stratified cycle's passes use each stratum.
    TrCycle = 5,
}

/// SplitMix64 finaliser: turns structured keys into well-spread seeds.
pub fn mix64(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// PCG-RXS-M-XS 32 as a hash (Jarzynski and Olano 2020, "Hash Functions for GPU
/// Rendering"): a bijection of u32 that spreads structured keys. `shaders/freepath.wgsl`
/// has the same function, so both devices draw the same numbers from the same keys.
pub const fn pcg_hash(x: u32) -> u32 {
    let s = x.wrapping_mul(747_796_405).wrapping_add(2_891_336_453);
    let w = ((s >> ((s >> 28) + 4)) ^ s).wrapping_mul(277_803_737);
    (w >> 22) ^ w
}

/// The weights of [`hash_unit`]'s words: odd pseudo-random constants, the i-th
/// pcg_hash(i + 1) | 1 (`shaders/beam_estimate.wgsl` writes the first ten as literals).
pub const HASH_WEIGHTS: [u32; 16] = {
    let mut k = [0; 16];
    let mut i = 0;
    while i < 16 {
        k[i] = pcg_hash(i as u32 + 1) | 1;
        i += 1;
    }
    k
};

/// A uniform number in [0, 1) from `words`: their sum weighted by [`HASH_WEIGHTS`], then
/// two rounds of [`pcg_hash`]. The
/// products are independent of each other, so the hash costs about two rounds' latency:
/// a chain of one round per word made the tube's beam estimate 16 % slower on cloud-hg,
/// and constants not folded at compile time 6 %.
#[inline(always)]
pub fn hash_unit<const N: usize>(words: [u32; N]) -> f32 {
    const { assert!(N <= HASH_WEIGHTS.len(), "hash_unit takes up to 16 words") };
    let mut h = 0u32;
    for (&w, &k) in words.iter().zip(&HASH_WEIGHTS) {
        h = h.wrapping_add(w.wrapping_mul(k));
    }
    (pcg_hash(pcg_hash(h)) >> 8) as f32 * (1.0 / (1u32 << 24) as f32)
}

impl Rng {
    pub fn new(seed: u64, seq: u64) -> Self {
        let mut r = Rng {
            state: 0,
            inc: (seq << 1) | 1,
        };
        r.next_u32();
        r.state = r.state.wrapping_add(seed);
        r.next_u32();
        r
    }

    /// The stream for one (seed, pass, kind, index).
    pub fn for_path(seed: u64, pass: u32, kind: Stream, index: u64) -> Self {
        let key = mix64(seed ^ mix64(((pass as u64) << 8) | kind as u64));
        Rng::new(mix64(key ^ index), mix64(index.wrapping_add(key)))
    }

    pub fn next_u32(&mut self) -> u32 {
        let old = self.state;
        self.state = old
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(self.inc);
        let xorshifted = (((old >> 18) ^ old) >> 27) as u32;
        let rot = (old >> 59) as u32;
        xorshifted.rotate_right(rot)
    }

    /// Uniform in [0, 1).
    pub fn f32(&mut self) -> f32 {
        (self.next_u32() >> 8) as f32 * (1.0 / (1u32 << 24) as f32)
    }

    pub fn vec2(&mut self) -> Vec2 {
        Vec2::new(self.f32(), self.f32())
    }
}

/// Two unit vectors completing `n` to a right-handed frame (Duff et al. 2017).
pub fn orthonormal_basis(n: Vec3) -> (Vec3, Vec3) {
    let sign = 1.0f32.copysign(n.z);
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    (
        Vec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x),
        Vec3::new(b, sign + n.y * n.y * a, -n.y),
    )
}

pub fn uniform_sphere(u: Vec2) -> Vec3 {
    let z = 1.0 - 2.0 * u.x;
    let r = (1.0 - z * z).max(0.0).sqrt();
    let phi = 2.0 * PI * u.y;
    Vec3::new(r * phi.cos(), r * phi.sin(), z)
}

/// Cosine-weighted direction around `n` (pdf cos/pi).
pub fn cosine_hemisphere(n: Vec3, u: Vec2) -> Vec3 {
    let r = u.x.sqrt();
    let phi = 2.0 * PI * u.y;
    let z = (1.0 - u.x).max(0.0).sqrt();
    let (t, b) = orthonormal_basis(n);
    (t * (r * phi.cos()) + b * (r * phi.sin()) + n * z).normalize()
}

/// Uniform direction in the cone of half-angle acos(cos_max) around `axis`.
pub fn uniform_cone(axis: Vec3, cos_max: f32, u: Vec2) -> Vec3 {
    let z = 1.0 - u.x * (1.0 - cos_max);
    let r = (1.0 - z * z).max(0.0).sqrt();
    let phi = 2.0 * PI * u.y;
    let (t, b) = orthonormal_basis(axis);
    (t * (r * phi.cos()) + b * (r * phi.sin()) + axis * z).normalize()
}

/// Uniform point on the unit disk (concentric map).
pub fn uniform_disk(u: Vec2) -> Vec2 {
    let o = 2.0 * u - Vec2::ONE;
    if o.x == 0.0 && o.y == 0.0 {
        return Vec2::ZERO;
    }
    let (r, theta) = if o.x.abs() > o.y.abs() {
        (o.x, PI / 4.0 * (o.y / o.x))
    } else {
        (o.y, PI / 2.0 - PI / 4.0 * (o.x / o.y))
    };
    Vec2::new(r * theta.cos(), r * theta.sin())
}

/// A discrete distribution proportional to non-negative weights: inverted by binary search
/// over its cumulative sums (kept in f64 so a million small weights still add up).
#[derive(Clone, Debug, PartialEq)]
pub struct Discrete {
    /// cdf[i] = sum of the weights before i, over the total; cdf[n] = 1.
    cdf: Vec<f64>,
    total: f64,
}

impl Discrete {
    /// None when no weight is positive (negative and non-finite weights count as 0).
    pub fn new(weights: impl IntoIterator<Item = f64>) -> Option<Self> {
        let mut cdf = vec![0.0];
        let mut acc = 0.0f64;
        for w in weights {
            acc += if w.is_finite() { w.max(0.0) } else { 0.0 };
            cdf.push(acc);
        }
        if acc <= 0.0 {
            return None;
        }
        cdf.iter_mut().for_each(|c| *c /= acc);
        Some(Discrete { cdf, total: acc })
    }

    pub fn len(&self) -> usize {
        self.cdf.len() - 1
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Sum of the weights.
    pub fn total(&self) -> f64 {
        self.total
    }

    pub fn prob(&self, i: usize) -> f32 {
        (self.cdf[i + 1] - self.cdf[i]) as f32
    }

    /// The index `u` in [0, 1) falls in, its probability, and `u` rescaled to [0, 1)
    /// within the index's share (so one uniform also places the sample inside it).
    pub fn sample(&self, u: f32) -> (usize, f32, f32) {
        let u = u as f64;
        let i = (self.cdf.partition_point(|&c| c <= u) - 1).min(self.len() - 1);
        // The last i with cdf[i] <= u has cdf[i + 1] > u: a zero weight is never drawn.
        let (lo, hi) = (self.cdf[i], self.cdf[i + 1]);
        let rest = ((u - lo) / (hi - lo)).clamp(0.0, 1.0 - f64::EPSILON);
        (i, (hi - lo) as f32, rest as f32)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn streams_are_distinct_and_reproducible() {
        let a: Vec<u32> = (0..4)
            .map(|_| Rng::for_path(1, 0, Stream::Light, 5).next_u32())
            .collect();
        assert!(a.iter().all(|&x| x == a[0]));
        let mut r0 = Rng::for_path(1, 0, Stream::Light, 5);
        let mut r1 = Rng::for_path(1, 0, Stream::Light, 6);
        let mut r2 = Rng::for_path(1, 1, Stream::Light, 5);
        let mut r3 = Rng::for_path(1, 0, Stream::Camera, 5);
        let x = r0.next_u32();
        assert_ne!(x, r1.next_u32());
        assert_ne!(x, r2.next_u32());
        assert_ne!(x, r3.next_u32());
    }

    #[test]
    fn uniform_mean_and_variance() {
        // Mean of U(0,1) is 1/2 with variance 1/12; 5 sigma bound on n samples.
        let mut r = Rng::new(7, 3);
        let n = 200_000;
        let s: f64 = (0..n).map(|_| r.f32() as f64).sum();
        let bound = 5.0 * (1.0f64 / 12.0 / n as f64).sqrt();
        assert!((s / n as f64 - 0.5).abs() < bound);
    }

    #[test]
    fn basis_is_orthonormal() {
        let mut r = Rng::new(1, 1);
        for _ in 0..1000 {
            let n = uniform_sphere(r.vec2());
            let (t, b) = orthonormal_basis(n);
            assert!((t.length() - 1.0).abs() < 1e-4 && (b.length() - 1.0).abs() < 1e-4);
            assert!(t.dot(n).abs() < 1e-4 && b.dot(n).abs() < 1e-4 && t.dot(b).abs() < 1e-4);
        }
    }
}
