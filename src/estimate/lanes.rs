//! Eq. 2's crossing and edge rule ([`crossing`], [`counts`]) for one beam piece against a
//! run of camera rays from one origin, many rays at once: the regular part of the splat,
//! where most candidate pairs are rejected. Only the pairs that count go on to the
//! scalar [`counted_term`](super::eq2::counted_term), with its lookups.
//!
//! The lanes do the scalar [`crossing`]'s operations in its order, so every instruction
//! set finds the same pairs with the same bits (`core::simd`).
use glam::Vec3;

use super::eq2::{counts, crossing, BeamPiece, Crossing};
use crate::core::simd::Isa;

/// Camera rays as structure of arrays: unit directions and the segment ends t1 of the
/// segments [0, t1) (primary segments, indexed by pixel), followed by [`PAD`] rays that
/// count nothing, so the last wide step of a run reads within the arrays.
#[derive(Clone, Debug, Default)]
pub struct Rays {
    pub x: Vec<f32>,
    pub y: Vec<f32>,
    pub z: Vec<f32>,
    pub t1: Vec<f32>,
}

impl Rays {
    pub fn new(segments: impl Iterator<Item = (Vec3, f32)>) -> Rays {
        let mut r = Rays::default();
        for (d, t1) in segments {
            r.x.push(d.x);
            r.y.push(d.y);
            r.z.push(d.z);
            r.t1.push(t1);
        }
        for _ in 0..PAD {
            r.x.push(0.0);
            r.y.push(0.0);
            r.z.push(0.0);
            r.t1.push(-1.0);
        }
        r
    }

    fn dir(&self, i: usize) -> Vec3 {
        Vec3::new(self.x[i], self.y[i], self.z[i])
    }
}

/// The widest step's lane count.
const PAD: usize = 16;

/// One beam piece seen from the rays' common origin: what every crossing shares.
pub struct Fixed<'a> {
    o: Vec3,
    piece: &'a BeamPiece,
    r: f32,
    y: Vec3,
    psi: Vec3,
    w0: Vec3,
    e: f32,
}

impl<'a> Fixed<'a> {
    pub fn new(o: Vec3, piece: &'a BeamPiece, r: f32) -> Fixed<'a> {
        let (y, psi) = (Vec3::from(piece.origin), Vec3::from(piece.dir));
        let w0 = o - y;
        let e = psi.dot(w0);
        Fixed {
            o,
            piece,
            r,
            y,
            psi,
            w0,
            e,
        }
    }

    /// Calls `visit(i, crossing)` for every ray i in `range` whose pair with the piece
    /// counts, in increasing i, the rays taken `isa`'s lane count at a time (the last
    /// step masked: a row's run is often shorter than a step).
    pub fn for_each_counted(
        &self,
        isa: Isa,
        rays: &Rays,
        range: std::ops::Range<usize>,
        mut visit: impl FnMut(usize, &Crossing),
    ) {
        let mut i = range.start;
        let left = |i: usize| (range.end - i) as u32;
        let keep = |i: usize| {
            if left(i) >= 32 {
                u32::MAX
            } else {
                (1u32 << left(i)) - 1
            }
        };
        #[cfg(target_arch = "x86_64")]
        match isa {
            Isa::Avx512 | Isa::Avx2 => {
                while i < range.end {
                    // SAFETY: the set is only chosen where the CPU runs it (Isa::supported;
                    // AVX-512 only with AVX2 too).
                    if isa == Isa::Avx512 && left(i) > 8 {
                        let (mask, lanes) = unsafe { avx512(self, rays, i) };
                        lanes.visit(mask & keep(i), i, &mut visit);
                        i += 16;
                    } else {
                        let (mask, lanes) = unsafe { avx2(self, rays, i) };
                        lanes.visit(mask & keep(i), i, &mut visit);
                        i += 8;
                    }
                }
            }
            Isa::Scalar => {}
        }
        #[cfg(not(target_arch = "x86_64"))]
        let _ = (isa, keep);
        for i in i..range.end {
            if let Some(c) = self.scalar(rays, i) {
                visit(i, &c);
            }
        }
    }

    /// The one-pair reference: [`crossing`] and [`counts`] themselves.
    fn scalar(&self, rays: &Rays, i: usize) -> Option<Crossing> {
        let c = crossing(self.o, rays.dir(i), self.y, self.psi)?;
        counts(&c, (0.0, rays.t1[i]), self.piece, self.r).then_some(c)
    }

    /// [`Self::scalar`] for the N rays from `at`: the crossings and a bit per ray that
    /// counts. The same operations in the same order as [`crossing`] and [`counts`].
    #[inline(always)]
    fn lanes<const N: usize>(&self, rays: &Rays, at: usize) -> (u32, Lanes<N>) {
        let lane = |v: &[f32]| -> [f32; N] { v[at..at + N].try_into().expect("N lanes") };
        let (x, y, z, t1) = (lane(&rays.x), lane(&rays.y), lane(&rays.z), lane(&rays.t1));
        let (psi, w0, e) = (self.psi, self.w0, self.e);
        let (r2, s0, s1) = (self.r * self.r, self.piece.s0, self.piece.s1);
        let mut out = Lanes::<N>::default();
        let mut mask = 0u32;
        for k in 0..N {
            let b = (x[k] * psi.x) + (y[k] * psi.y) + (z[k] * psi.z);
            let sin2 = 1.0 - b * b;
            let d = (x[k] * w0.x) + (y[k] * w0.y) + (z[k] * w0.z);
            let t = (b * e - d) / sin2;
            let s = (e - b * d) / sin2;
            let vx = (w0.x + x[k] * t) - psi.x * s;
            let vy = (w0.y + y[k] * t) - psi.y * s;
            let vz = (w0.z + z[k] * t) - psi.z * s;
            let dist2 = (vx * vx) + (vy * vy) + (vz * vz);
            let ok =
                (sin2 >= 1e-10) & (dist2 < r2) & (0.0 <= t) & (t < t1[k]) & (s0 <= s) & (s < s1);
            mask |= (ok as u32) << k;
            (out.t[k], out.s[k], out.dist2[k], out.sin2[k]) = (t, s, dist2, sin2);
        }
        (mask, out)
    }
}

/// The crossings of N rays, lane by lane.
struct Lanes<const N: usize> {
    t: [f32; N],
    s: [f32; N],
    dist2: [f32; N],
    sin2: [f32; N],
}

impl<const N: usize> Default for Lanes<N> {
    fn default() -> Self {
        Lanes {
            t: [0.0; N],
            s: [0.0; N],
            dist2: [0.0; N],
            sin2: [0.0; N],
        }
    }
}

impl<const N: usize> Lanes<N> {
    fn visit(&self, mut mask: u32, at: usize, visit: &mut impl FnMut(usize, &Crossing)) {
        while mask != 0 {
            let k = mask.trailing_zeros() as usize;
            mask &= mask - 1;
            let c = Crossing {
                t: self.t[k],
                s: self.s[k],
                dist2: self.dist2[k],
                sin2: self.sin2[k],
            };
            visit(at + k, &c);
        }
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn avx2(f: &Fixed, rays: &Rays, at: usize) -> (u32, Lanes<8>) {
    f.lanes::<8>(rays, at)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
fn avx512(f: &Fixed, rays: &Rays, at: usize) -> (u32, Lanes<16>) {
    f.lanes::<16>(rays, at)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::Rng;

    /// Rays and a piece built so that a fair share of pairs count and many sit near an
    /// edge: crossings near the segment ends, the piece's ends and the radius; one case in
    /// four nearly parallel.
    fn case(rng: &mut Rng, n: usize) -> (Vec3, Rays, BeamPiece, f32) {
        let mut v = || Vec3::new(rng.f32(), rng.f32(), rng.f32()) * 2.0 - 1.0;
        let o = v();
        let dir = v().normalize_or(Vec3::X);
        let r = 0.05 + 0.2 * v().z.abs();
        // The beam passes within about r of the central ray, near its segment's end.
        let psi = if n.is_multiple_of(4) {
            dir
        } else {
            v().normalize_or(Vec3::Z)
        };
        let hit = o + dir * (1.0 + v().x) + v() * r;
        let s_at = 1.0 + v().y;
        let rays = Rays::new((0..n).map(|_| {
            let d = (dir + v() * 0.1).normalize_or(Vec3::Y);
            (d, 1.0 + v().x)
        }));
        let piece = BeamPiece {
            origin: (hit - psi * s_at).into(),
            s0: 0.2 + v().x,
            dir: psi.into(),
            s1: 1.0 + v().y,
            power: [1.0; 3],
            beam: 0,
        };
        (o, rays, piece, r)
    }

    /// Every instruction set this CPU runs finds the scalar reference's pairs, with the
    /// same crossings bit for bit, over ranges that start and end off the lane grid.
    #[test]
    fn every_isa_finds_the_scalar_pairs_bit_for_bit() {
        let mut rng = Rng::new(11, 0);
        let (mut counted, mut pairs) = (0, 0);
        for round in 0..400 {
            let n = 37 + round % 23;
            let (o, rays, piece, r) = case(&mut rng, n);
            let fixed = Fixed::new(o, &piece, r);
            let range = (round % 5)..n - (round % 3);
            let run = |isa| {
                let mut got = Vec::new();
                fixed.for_each_counted(isa, &rays, range.clone(), |i, c| {
                    got.push((
                        i,
                        c.t.to_bits(),
                        c.s.to_bits(),
                        c.dist2.to_bits(),
                        c.sin2.to_bits(),
                    ))
                });
                got
            };
            let reference = run(Isa::Scalar);
            counted += reference.len();
            pairs += range.len();
            for isa in Isa::ALL.into_iter().filter(|i| i.supported()) {
                assert_eq!(run(isa), reference, "round {round}, {isa:?}");
            }
        }
        // The cases exercise the rule: many pairs count, more do not.
        eprintln!("{counted} of {pairs} pairs counted");
        assert!(
            counted > 2000 && 2 * counted < pairs,
            "{counted} of {pairs} counted"
        );
    }
}
