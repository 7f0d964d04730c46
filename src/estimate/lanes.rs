//! Each kernel's rule for which pairs count ([`pair`]: eq. 2's crossing and edge rule, or
//! the tube's chord) for many pairs at once: one
//! beam piece against a run of camera rays from one origin (the splat's rows), or one
//! camera segment against the pieces a BVH query returns (the gather). Most candidate
//! pairs are rejected here; only those that count go on to the scalar
//! [`pair_term`](super::eq2::pair_term), with its lookups.
//!
//! Each lane runs the scalar functions themselves, inlined, so every instruction set finds
//! the same pairs with the same bits (`core::simd`).
use glam::Vec3;
use rayon::prelude::*;

use super::eq2::{pair, BeamKernel, BeamPiece, Crossing};
use crate::core::simd::Isa;
use crate::core::Ray;

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

/// The widest step's lane count.
const PAD: usize = 16;

impl Rays {
    /// The arrays filled in parallel (a serial copy was a few per cent of a pass).
    pub fn new(segments: impl IndexedParallelIterator<Item = (Vec3, f32)>) -> Rays {
        let n = segments.len() + PAD;
        let mut r = Rays {
            x: vec![0.0; n],
            y: vec![0.0; n],
            z: vec![0.0; n],
            t1: vec![-1.0; n],
        };
        r.x.par_iter_mut()
            .zip(&mut r.y)
            .zip(&mut r.z)
            .zip(&mut r.t1)
            .zip(segments)
            .with_min_len(4096)
            .for_each(|((((x, y), z), t1), (d, t))| (*x, *y, *z, *t1) = (d.x, d.y, d.z, t));
        r
    }
}

/// N pairs as structure of arrays: rays o + t w over [t0, t1), pieces y + s psi over
/// [s0, s1).
#[derive(Clone, Copy)]
struct Pairs<const N: usize> {
    o: [[f32; N]; 3],
    w: [[f32; N]; 3],
    y: [[f32; N]; 3],
    psi: [[f32; N]; 3],
    t: [[f32; N]; 2],
    s: [[f32; N]; 2],
    /// The pieces' kernel scales: a pair counts within r times its piece's.
    scale: [f32; N],
}

impl<const N: usize> Pairs<N> {
    fn zero() -> Self {
        let z = [0.0; N];
        Pairs {
            o: [z; 3],
            w: [z; 3],
            y: [z; 3],
            psi: [z; 3],
            t: [z; 2],
            s: [z; 2],
            scale: z,
        }
    }

    /// Lane k: ray `o`, `w` over `span`.
    #[inline(always)]
    fn set_ray(&mut self, k: usize, o: Vec3, w: Vec3, span: (f32, f32)) {
        for i in 0..3 {
            (self.o[i][k], self.w[i][k]) = (o[i], w[i]);
        }
        (self.t[0][k], self.t[1][k]) = span;
    }

    /// Lane k: piece `p`.
    #[inline(always)]
    fn set_piece(&mut self, k: usize, p: &BeamPiece) {
        for i in 0..3 {
            (self.y[i][k], self.psi[i][k]) = (p.origin[i], p.dir[i]);
        }
        (self.s[0][k], self.s[1][k]) = (p.s0, p.s1);
        self.scale[k] = p.scale;
    }

    /// Lane k's pair by the kernel's rule ([`pair`]): whether it counts, and its crossing.
    #[inline(always)]
    fn test<const TUBE: bool>(&self, k: usize, r: f32) -> (bool, Crossing) {
        let at = |v: &[[f32; N]; 3]| [v[0][k], v[1][k], v[2][k]];
        let lines = (at(&self.o), at(&self.w), at(&self.y), at(&self.psi));
        let (span, ends) = ((self.t[0][k], self.t[1][k]), (self.s[0][k], self.s[1][k]));
        let kernel = if TUBE {
            BeamKernel::Tube
        } else {
            BeamKernel::Line
        };
        pair(kernel, lines, span, ends, r * self.scale[k])
    }
}

/// The crossings of N pairs, lane by lane, and a bit per pair that counts.
struct Lanes<const N: usize> {
    mask: u32,
    t: [f32; N],
    s: [f32; N],
    dist2: [f32; N],
    sin2: [f32; N],
    lo: [f32; N],
    hi: [f32; N],
}

impl<const N: usize> Lanes<N> {
    /// Tests the pairs that `fill` writes by `kernel`'s rule.
    #[inline(always)]
    fn test(fill: impl FnOnce(&mut Pairs<N>), r: f32, kernel: BeamKernel) -> Lanes<N> {
        match kernel {
            BeamKernel::Line => Self::test_by::<false>(fill, r),
            BeamKernel::Tube => Self::test_by::<true>(fill, r),
        }
    }

    /// [`Self::test`] by the tube's rule or eq. 2's, as a constant: each kernel's lane loop
    /// is compiled on its own (a kernel chosen inside the loop kept LLVM from vectorising
    /// it).
    #[inline(always)]
    fn test_by<const TUBE: bool>(fill: impl FnOnce(&mut Pairs<N>), r: f32) -> Lanes<N> {
        let mut pairs = Pairs::zero();
        fill(&mut pairs);
        let z = [0.0; N];
        let mut out = Lanes {
            mask: 0,
            t: z,
            s: z,
            dist2: z,
            sin2: z,
            lo: z,
            hi: z,
        };
        // The mask is built in a second loop: folded into this one, it kept LLVM from
        // vectorising the lanes.
        let mut ok = [false; N];
        #[allow(clippy::needless_range_loop)] // one index over six arrays
        for k in 0..N {
            let c;
            (ok[k], c) = pairs.test::<TUBE>(k, r);
            (out.t[k], out.s[k], out.dist2[k]) = (c.t, c.s, c.dist2);
            (out.sin2[k], out.lo[k], out.hi[k]) = (c.sin2, c.lo, c.hi);
        }
        for (k, ok) in ok.into_iter().enumerate() {
            out.mask |= (ok as u32) << k;
        }
        out
    }

    /// Calls `visit(k, crossing)` for the lanes that count and `keep` keeps, in lane order.
    fn visit(&self, keep: u32, mut visit: impl FnMut(usize, &Crossing)) {
        let mut mask = self.mask & keep;
        while mask != 0 {
            let k = mask.trailing_zeros() as usize;
            mask &= mask - 1;
            let c = Crossing {
                t: self.t[k],
                s: self.s[k],
                dist2: self.dist2[k],
                sin2: self.sin2[k],
                lo: self.lo[k],
                hi: self.hi[k],
            };
            visit(k, &c);
        }
    }
}

/// One pair the scalar way: eq2's [`pair`] itself, at r times the piece's scale.
fn scalar(
    o: Vec3,
    w: Vec3,
    span: (f32, f32),
    p: &BeamPiece,
    r: f32,
    kernel: BeamKernel,
) -> Option<Crossing> {
    let lines = (o.into(), w.into(), p.origin, p.dir);
    let (ok, c) = pair(kernel, lines, span, (p.s0, p.s1), r * p.scale);
    ok.then_some(c)
}

/// The lanes that a step of `n` lanes keeps when `left` pairs are left.
fn keep(left: usize) -> u32 {
    if left >= 32 {
        u32::MAX
    } else {
        (1u32 << left) - 1
    }
}

/// Runs `step(at, lanes)` over `0..len` in `isa`'s steps (8 or 16 lanes; AVX-512 takes 8
/// when no more are left) and returns where the scalar rest starts.
fn wide_steps(isa: Isa, len: usize, mut step: impl FnMut(usize, usize)) -> usize {
    if isa == Isa::Scalar {
        return 0;
    }
    let mut at = 0;
    while at < len {
        let n = if isa == Isa::Avx512 && len - at > 8 {
            16
        } else {
            8
        };
        step(at, n);
        at += n;
    }
    len
}

/// One beam piece seen from the rays' common origin (the splat).
pub struct Fixed<'a> {
    o: Vec3,
    piece: &'a BeamPiece,
    /// The pass's beam radius: a pair counts within it times its piece's scale.
    r: f32,
    kernel: BeamKernel,
}

impl<'a> Fixed<'a> {
    pub fn new(o: Vec3, piece: &'a BeamPiece, r: f32, kernel: BeamKernel) -> Fixed<'a> {
        Fixed {
            o,
            piece,
            r,
            kernel,
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
        let (start, len) = (range.start, range.len());
        let done = wide_steps(isa, len, |at, n| {
            let i = start + at;
            let v = |k: usize, c: &Crossing| visit(i + k, c);
            let row = Row(self, rays, i);
            // SAFETY: `wide_steps` takes n = 16 only for AVX-512 and n = 8 for AVX2 or
            // AVX-512, which `Isa` chooses only where the CPU runs them (with AVX2).
            unsafe { run(n, &row, (self.r, self.kernel), keep(len - at), v) }
        });
        for i in start + done..range.end {
            let w = Vec3::new(rays.x[i], rays.y[i], rays.z[i]);
            let span = (0.0, rays.t1[i]);
            if let Some(c) = scalar(self.o, w, span, self.piece, self.r, self.kernel) {
                visit(i, &c);
            }
        }
    }
}

/// What writes a step's pairs, for any lane count.
trait Fill {
    fn fill<const N: usize>(&self, p: &mut Pairs<N>);
}

/// The splat's pairs: the piece with rays `i..i + N`.
struct Row<'a, 'b>(&'a Fixed<'b>, &'a Rays, usize);

impl Fill for Row<'_, '_> {
    #[inline(always)]
    fn fill<const N: usize>(&self, p: &mut Pairs<N>) {
        let Row(f, rays, i) = *self;
        let lanes = |v: &[f32]| -> [f32; N] { v[i..i + N].try_into().expect("N lanes") };
        (p.w, p.t[1]) = (
            [lanes(&rays.x), lanes(&rays.y), lanes(&rays.z)],
            lanes(&rays.t1),
        );
        for k in 0..N {
            for a in 0..3 {
                p.o[a][k] = f.o[a];
            }
            p.t[0][k] = 0.0;
            p.set_piece(k, f.piece);
        }
    }
}

/// The gather's pairs: the ray with the first N `pieces` (the first piece where fewer).
struct Batch<'a> {
    o: Vec3,
    w: Vec3,
    span: (f32, f32),
    pieces: &'a [&'a BeamPiece],
}

impl Fill for Batch<'_> {
    #[inline(always)]
    fn fill<const N: usize>(&self, p: &mut Pairs<N>) {
        for k in 0..N {
            p.set_ray(k, self.o, self.w, self.span);
            p.set_piece(k, self.pieces.get(k).unwrap_or(&self.pieces[0]));
        }
    }
}

/// One camera segment against beam pieces (the gather): `push` the pieces a query
/// returns, in its order, and `finish`; `visit` sees the ones that count in that order.
pub struct Segment<'a, V: FnMut(&BeamPiece, &Crossing)> {
    isa: Isa,
    ray: &'a Ray,
    span: (f32, f32),
    r: f32,
    kernel: BeamKernel,
    batch: [&'a BeamPiece; PAD],
    len: usize,
    visit: V,
}

impl<'a, V: FnMut(&BeamPiece, &Crossing)> Segment<'a, V> {
    /// `first` fills the batch's unused slots.
    pub fn new(
        isa: Isa,
        ray: &'a Ray,
        span: (f32, f32),
        (r, kernel): (f32, BeamKernel),
        first: &'a BeamPiece,
        visit: V,
    ) -> Self {
        Segment {
            isa,
            ray,
            span,
            r,
            kernel,
            batch: [first; PAD],
            len: 0,
            visit,
        }
    }

    pub fn push(&mut self, piece: &'a BeamPiece) {
        self.batch[self.len] = piece;
        self.len += 1;
        let width = match self.isa {
            Isa::Scalar => 1,
            Isa::Avx2 => 8,
            Isa::Avx512 => 16,
        };
        if self.len == width {
            self.flush();
        }
    }

    /// Tests what is left.
    pub fn finish(mut self) {
        self.flush();
    }

    fn flush(&mut self) {
        let (len, batch, r, kernel) = (self.len, self.batch, self.r, self.kernel);
        let (o, w, span) = (self.ray.o, self.ray.d, self.span);
        self.len = 0;
        let visit = &mut self.visit;
        let done = wide_steps(self.isa, len, |at, n| {
            let pieces = &batch[at..];
            let v = |k: usize, c: &Crossing| visit(batch[at + k], c);
            let fill = Batch { o, w, span, pieces };
            // SAFETY: as in `Fixed::for_each_counted`.
            unsafe { run(n, &fill, (r, kernel), keep(len - at), v) }
        });
        for &piece in &batch[done..len] {
            if let Some(c) = scalar(o, w, span, piece, r, kernel) {
                visit(piece, &c);
            }
        }
    }
}

/// Tests the n = 8 or 16 pairs that `fill` writes on the instruction set of that width
/// and visits those that count (and `keep` keeps) in lane order.
///
/// # Safety
/// n = 8 needs AVX2, n = 16 AVX-512F.
#[inline(always)]
unsafe fn run(
    n: usize,
    fill: &impl Fill,
    (r, kernel): (f32, BeamKernel),
    keep: u32,
    visit: impl FnMut(usize, &Crossing),
) {
    #[cfg(target_arch = "x86_64")]
    {
        if n == 16 {
            // SAFETY: the caller's.
            unsafe { avx512(fill, r, kernel) }.visit(keep, visit)
        } else {
            // SAFETY: the caller's.
            unsafe { avx2(fill, r, kernel) }.visit(keep, visit)
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        let _ = (n, fill, r, kernel, keep, visit);
        unreachable!("wide steps only on x86_64")
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn avx2(fill: &impl Fill, r: f32, kernel: BeamKernel) -> Lanes<8> {
    Lanes::test(|p| fill.fill(p), r, kernel)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
fn avx512(fill: &impl Fill, r: f32, kernel: BeamKernel) -> Lanes<16> {
    Lanes::test(|p| fill.fill(p), r, kernel)
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
        let segments: Vec<(Vec3, f32)> = (0..n)
            .map(|_| {
                let d = (dir + v() * 0.1).normalize_or(Vec3::Y);
                (d, 1.0 + v().x)
            })
            .collect();
        let rays = Rays::new(segments.into_par_iter());
        let piece = BeamPiece {
            origin: (hit - psi * s_at).into(),
            s0: 0.2 + v().x,
            dir: psi.into(),
            s1: 1.0 + v().y,
            power: [1.0; 3],
            scale: 1.0,
        };
        (o, rays, piece, r)
    }

    /// Pairs that count, as (index, crossing bits).
    type Found = Vec<(usize, [u32; 6])>;

    fn bits(i: usize, c: &Crossing) -> (usize, [u32; 6]) {
        (i, [c.t, c.s, c.dist2, c.sin2, c.lo, c.hi].map(f32::to_bits))
    }

    /// Every instruction set this CPU runs finds the pairs of eq2's scalar [`crossing`] and
    /// each kernel's rule ([`scalar`]), with the same crossings bit for bit: the splat's
    /// rows, over runs that start and end off the lane grid, and the gather's batches, over
    /// queries of any length.
    #[test]
    fn every_isa_finds_the_scalar_pairs_bit_for_bit() {
        every_isa_finds_the_scalar_pairs(BeamKernel::Line);
        every_isa_finds_the_scalar_pairs(BeamKernel::Tube);
    }

    fn every_isa_finds_the_scalar_pairs(kernel: BeamKernel) {
        let mut rng = Rng::new(11, 0);
        let (mut counted, mut pairs) = (0, 0);
        for round in 0..400 {
            let n = 37 + round % 23;
            let (o, rays, piece, r) = case(&mut rng, n);
            let range = (round % 5)..n - (round % 3);
            let dir = |i: usize| Vec3::new(rays.x[i], rays.y[i], rays.z[i]);
            let reference: Found = range
                .clone()
                .filter_map(|i| {
                    let c = scalar(o, dir(i), (0.0, rays.t1[i]), &piece, r, kernel)?;
                    Some(bits(i, &c))
                })
                .collect();
            // The gather: ray 0 against `m` pieces that pass within about r of it, near
            // the ends of its span and of theirs.
            let m = round % 40;
            let mut u = || Vec3::new(rng.f32(), rng.f32(), rng.f32());
            let others: Vec<BeamPiece> = (0..m)
                .map(|_| {
                    let (a, b) = (u(), u());
                    let psi = (a * 2.0 - 1.0).normalize_or(Vec3::Z);
                    let hit = o + dir(0) * (0.1 + 1.1 * rays.t1[0] * b.x) + (u() * 2.0 - 1.0) * r;
                    BeamPiece {
                        origin: (hit - psi * 1.2 * b.y).into(),
                        dir: psi.into(),
                        s0: 0.1 * b.z,
                        s1: 1.0,
                        ..piece
                    }
                })
                .collect();
            let span = (0.1, rays.t1[0]);
            let gathered: Found = others
                .iter()
                .enumerate()
                .filter_map(|(i, p)| Some(bits(i, &scalar(o, dir(0), span, p, r, kernel)?)))
                .collect();
            for isa in Isa::ALL.into_iter().filter(|i| i.supported()) {
                let mut got = Found::new();
                let fixed = Fixed::new(o, &piece, r, kernel);
                fixed.for_each_counted(isa, &rays, range.clone(), |i, c| got.push(bits(i, c)));
                assert_eq!(got, reference, "row, round {round}, {isa:?}");
                let mut got = Found::new();
                let ray = Ray::new(o, dir(0));
                let index = |p: &BeamPiece| others.iter().position(|q| std::ptr::eq(p, q));
                let visit = |p: &BeamPiece, c: &Crossing| got.push(bits(index(p).unwrap(), c));
                let mut segment = Segment::new(isa, &ray, span, (r, kernel), &piece, visit);
                others.iter().for_each(|p| segment.push(p));
                segment.finish();
                assert_eq!(got, gathered, "gather, round {round}, {isa:?}");
            }
            counted += reference.len() + gathered.len();
            pairs += range.len() + m;
        }
        // The cases exercise the rule: many pairs count, more do not.
        eprintln!("{kernel:?}: {counted} of {pairs} pairs counted");
        assert!(
            counted > 2000 && 2 * counted < pairs,
            "{kernel:?}: {counted} of {pairs} counted"
        );
    }
}
