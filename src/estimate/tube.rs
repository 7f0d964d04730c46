//! The tube kernel ("beam x beam 2D", Jarosz et al. 2011): a beam of power Phi blurred by a
//! 2D box of radius r across its direction is a tube of flux density Phi / (pi r^2) between
//! the planes through its ends, and a camera segment gathers it over its chord through the
//! tube:
//!   L += Phi / (pi r^2) * integral over the chord of sigma_s(x(t)) f(psi . -w) Tr(t) dt,
//! estimated at one point drawn uniformly on the chord (so the transmittance and density
//! along a long chord in a dense medium are averaged, not taken at one end).
//!
//! Eq. 2's line kernel is this term integrated over the distance d between the lines, for
//! an infinite beam: it weighs a pair by 1/sin(theta). For a short beam seen end-on that
//! weight has no finite variance (the pairs that count get rarer as sin(theta), their
//! weight grows as 1/sin(theta)); the tube's chord is never longer than the piece's
//! extent along the ray. Where a forward-scattering phase function sends the beams toward
//! the camera (cloud-hg, HG g = 0.7), a third of the per-pixel noise was that tail
//! (docs/benchmarks.md, "The tube kernel").
use glam::Vec3;

use super::eq2::{BeamPiece, Crossing, Lines};
use crate::core::Ray;
use crate::core::Rgb;
use crate::sampling::hash_unit;

/// A pair's chord: the part of the camera segment within r of the piece's axis and
/// between its end planes, [lo, hi) (it counts when lo < hi, see [`counts`]), with the
/// quadratic q(t) = a t^2 + 2 h t + c of the squared distance from the ray's point at t to
/// the axis.
#[derive(Clone, Copy, Debug)]
pub struct Chord {
    pub lo: f32,
    pub hi: f32,
    a: f32,
    h: f32,
    c: f32,
}

/// The [`Chord`] of the ray o + t w over `span` and the piece y + s psi over `ends`
/// [s0, s1), on plain components (w and psi of unit length). Computed from the lines'
/// offset from the axis, not from the lines' closest approach, whose t and s lose all
/// precision as the lines turn parallel (the tube's end-on pairs are the ones that
/// matter): the axis parameter is s(t) = e + b t, the offset p + t q (q's length is
/// sin(theta), not 1 - cos^2 rounded), and the roots are taken in the stable form.
/// Branch-free, so the wide lanes run it; they and the term give the same bits.
#[inline(always)]
pub fn chord(
    o: [f32; 3],
    w: [f32; 3],
    y: [f32; 3],
    psi: [f32; 3],
    (t0, t1): (f32, f32),
    (s0, s1): (f32, f32),
    r: f32,
) -> Chord {
    let dot = |a: [f32; 3], b: [f32; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    let w0 = [o[0] - y[0], o[1] - y[1], o[2] - y[2]];
    let b = dot(w, psi);
    let e = dot(psi, w0);
    // The ray's offset from the axis is p + t q, both square to psi.
    let p = [0, 1, 2].map(|i| w0[i] - e * psi[i]);
    let q = [0, 1, 2].map(|i| w[i] - b * psi[i]);
    let (a, h, c) = (dot(q, q), dot(p, q), dot(p, p));
    let cr = c - r * r;
    // q(t) < r^2 between the roots, where the discriminant is positive.
    let k = -(h + (h * h - a * cr).sqrt().copysign(h));
    let (ra, rb) = (k / a, cr / k);
    let inv_b = 1.0 / b;
    let (sa, sb) = ((s0 - e) * inv_b, (s1 - e) * inv_b);
    let lo = ra.min(rb).max(sa.min(sb)).max(t0);
    let hi = ra.max(rb).min(sa.max(sb)).min(t1);
    Chord { lo, hi, a, h, c }
}

impl Chord {
    /// Whether the ray passes closer than r to the axis (the discriminant is positive)
    /// and the chord is not empty.
    #[inline(always)]
    pub fn counts(&self, r: f32) -> bool {
        (self.h * self.h - self.a * (self.c - r * r) > 0.0) & (self.lo < self.hi)
    }
}

/// Whether the pair of `lines` over `span` and `ends` counts under the tube kernel at
/// radius r (the lines at least sin^2 = 1e-10 from parallel, as for eq. 2), as
/// [`super::eq2::pair`] says it: the chord in the crossing's `lo` and `hi`, sin^2 in its
/// `sin2`, its t, s and dist2 0 (the term reads none of them).
#[inline(always)]
pub fn pair(lines: Lines, span: (f32, f32), ends: (f32, f32), r: f32) -> (bool, Crossing) {
    let ch = chord(lines.0, lines.1, lines.2, lines.3, span, ends, r);
    let c = Crossing {
        t: 0.0,
        s: 0.0,
        dist2: 0.0,
        sin2: ch.a,
        lo: ch.lo,
        hi: ch.hi,
    };
    ((ch.a >= 1e-10) & ch.counts(r), c)
}

/// The chord of `ray` over `span` and `piece` at radius r.
#[cfg(test)]
pub(crate) fn piece_chord(ray: &Ray, piece: &BeamPiece, span: (f32, f32), r: f32) -> Chord {
    let (o, w) = (ray.o.into(), ray.d.into());
    chord(o, w, piece.origin, piece.dir, span, (piece.s0, piece.s1), r)
}

/// A uniform number in [0, 1) for a pair, from its camera ray's and its piece's bits
/// (the pieces of one beam differ in s0): the same pair gets the same number on every
/// thread, lane count, walker and device (`shaders/beam_estimate.wgsl` hashes the same
/// words), and the pairs of a pass (whose rays are jittered) get numbers as good as
/// independent of each other and of the integrand along the chord.
#[inline(always)]
fn pair_u(ray: &Ray, piece: &BeamPiece) -> f32 {
    let (o, w, y) = (ray.o, ray.d, piece.origin);
    hash_unit([
        o.x.to_bits(),
        o.y.to_bits(),
        o.z.to_bits(),
        w.x.to_bits(),
        w.y.to_bits(),
        w.z.to_bits(),
        y[0].to_bits(),
        y[1].to_bits(),
        y[2].to_bits(),
        piece.s0.to_bits(),
    ])
}

/// The tube's term for a pair that counts, its chord in `c` ([`pair`]), and whether its
/// point is also within r/2 of the axis, where the kernel is 4 times as high (the nested
/// estimate's inner term is then 4 l, else 0: see `Nested::add_in`).
#[inline(always)]
pub fn counted_term(
    ray: &Ray,
    piece: &BeamPiece,
    c: &Crossing,
    r: f32,
    in_scatter: impl Fn(Vec3, f32) -> Rgb,
    tr: impl Fn(f32) -> f32,
) -> (Rgb, bool) {
    let chord = (c.lo, c.hi);
    term_at(ray, piece, chord, r, pair_u(ray, piece), in_scatter, tr)
}

/// [`counted_term`] at the chord's point lo + u (hi - lo).
#[inline(always)]
fn term_at(
    ray: &Ray,
    piece: &BeamPiece,
    (lo, hi): (f32, f32),
    r: f32,
    u: f32,
    in_scatter: impl Fn(Vec3, f32) -> Rgb,
    tr: impl Fn(f32) -> f32,
) -> (Rgb, bool) {
    let t = lo + u * (hi - lo);
    let x = ray.at(t);
    let (y, psi) = (Vec3::from(piece.origin), Vec3::from(piece.dir));
    let off = x - y;
    let inner = 4.0 * (off - psi * off.dot(psi)).length_squared() < r * r;
    let f = in_scatter(x, psi.dot(-ray.d));
    if f == Vec3::ZERO {
        return (Vec3::ZERO, inner);
    }
    let area = std::f32::consts::PI * r * r;
    let l = f * Vec3::from(piece.power) * ((hi - lo) * tr(t) / area);
    (l, inner)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::{uniform_sphere, Rng};
    use crate::transport::Beam;

    /// The whole beam from `y` along `psi`, `len` long, of power `power` in each channel.
    fn piece(y: Vec3, psi: Vec3, len: f32, power: f32) -> BeamPiece {
        BeamPiece::whole(&Beam::new(y, psi, len, Vec3::splat(power)))
    }

    /// The length of the ray's part over `span` within r of the piece's axis and between
    /// its end planes, by midpoint sums over n steps.
    fn brute_chord(ray: &Ray, span: (f32, f32), p: &BeamPiece, r: f32, n: usize) -> f64 {
        let (y, psi) = (Vec3::from(p.origin), Vec3::from(p.dir));
        let h = (span.1 - span.0) as f64 / n as f64;
        (0..n)
            .filter(|&i| {
                let x = ray.at(span.0 + ((i as f64 + 0.5) * h) as f32);
                let s = (x - y).dot(psi);
                let d2 = (x - y - psi * s).length_squared();
                s >= p.s0 && s < p.s1 && d2 < r * r
            })
            .count() as f64
            * h
    }

    /// A random piece near the ray from the origin along +x; `tilt` > 0 turns it to within
    /// that many radians of the ray's line (end-on).
    fn random_pair(rng: &mut Rng, r: f32, tilt: f32) -> (Ray, BeamPiece) {
        let ray = Ray::new(Vec3::ZERO, Vec3::X);
        let psi = if tilt > 0.0 {
            let side = if rng.f32() < 0.5 { 1.0 } else { -1.0 };
            (Vec3::X * side + uniform_sphere(rng.vec2()) * tilt).normalize()
        } else {
            uniform_sphere(rng.vec2())
        };
        let centre = Vec3::new(1.0 + rng.f32(), (rng.f32() - 0.5) * 3.0 * r, 0.0);
        let len = 4.0 * r * rng.f32();
        let y = centre - psi * (len * rng.f32());
        (ray, piece(y, psi, len, 1.0))
    }

    /// The chord's length against midpoint sums along the ray, for pieces at every angle
    /// and for pieces within 1e-4 to 1e-2 radians of end-on, that the segment may cut:
    /// equal within the sums' step.
    #[test]
    fn chord_is_the_ray_inside_the_tube() {
        let (r, n) = (0.1f32, 200_000);
        let mut rng = Rng::new(5, 1);
        let mut counted = [0; 2];
        for k in 0..600 {
            let tilt = if k % 2 == 0 {
                0.0
            } else {
                10f32.powf(-4.0 + 2.0 * rng.f32())
            };
            let (ray, piece) = random_pair(&mut rng, r, tilt);
            let span = (0.0, 1.2 + rng.f32());
            let want = brute_chord(&ray, span, &piece, r, n);
            let ch = piece_chord(&ray, &piece, span, r);
            let got = if ch.counts(r) {
                counted[k % 2] += 1;
                (ch.hi - ch.lo) as f64
            } else {
                0.0
            };
            let step = (span.1 - span.0) as f64 / n as f64;
            assert!(
                (got - want).abs() <= 3.0 * step + 1e-5,
                "{got} vs {want}, tilt {tilt}"
            );
        }
        assert!(counted[0] > 100 && counted[1] > 50, "{counted:?}");
    }

    /// Chi-square of numbers in [0, 1) in 20 bins, against its 99.9th percentile (43.8 for
    /// 19 degrees of freedom).
    fn assert_uniform(u: &[f32]) {
        let mut bins = [0u32; 20];
        for &u in u {
            assert!((0.0..1.0).contains(&u));
            bins[(u * 20.0) as usize] += 1;
        }
        let e = u.len() as f64 / 20.0;
        let chi2: f64 = bins.iter().map(|&b| (b as f64 - e).powi(2) / e).sum();
        assert!(chi2 < 43.8, "{chi2} {bins:?}");
    }

    /// The pairs' numbers are uniform: the counted pairs of 100,000 random pieces along
    /// one ray.
    #[test]
    fn pair_numbers_are_uniform() {
        let mut rng = Rng::new(11, 4);
        let mut u = Vec::new();
        for _ in 0..100_000 {
            let (ray, piece) = random_pair(&mut rng, 0.1, 0.0);
            if piece_chord(&ray, &piece, (0.0, 3.0), 0.1).counts(0.1) {
                u.push(pair_u(&ray, &piece));
            }
        }
        assert!(u.len() > 30_000, "{}", u.len());
        assert_uniform(&u);
    }

    /// The numbers of one piece's pairs with the rays of neighbouring pixels (a regular
    /// 400 x 400 grid of directions, whose bits differ least) are uniform, and those of
    /// horizontal neighbours uncorrelated: the sample correlation within 4.5 of its
    /// standard error 1/sqrt(n).
    #[test]
    fn neighbouring_pixels_get_independent_numbers() {
        let piece = piece(Vec3::new(-0.1, 0.0, 1.0), Vec3::X, 0.2, 1.0);
        let n = 400;
        let mut rows = Vec::new();
        for y in 0..n {
            let row: Vec<Option<f32>> = (0..n)
                .map(|x| {
                    let at = |i: usize| (i as f32 + 0.5) / n as f32 * 0.3 - 0.15;
                    let ray = Ray::new(Vec3::ZERO, Vec3::new(at(x), at(y), 1.0).normalize());
                    let counts = piece_chord(&ray, &piece, (0.0, 3.0), 0.05).counts(0.05);
                    counts.then(|| pair_u(&ray, &piece))
                })
                .collect();
            rows.push(row);
        }
        let all: Vec<f32> = rows.iter().flatten().flatten().copied().collect();
        assert!(all.len() > 20_000, "{}", all.len());
        assert_uniform(&all);
        let pairs: Vec<(f64, f64)> = rows
            .iter()
            .flat_map(|r| r.windows(2))
            .filter_map(|w| Some((w[0]? as f64 - 0.5, w[1]? as f64 - 0.5)))
            .collect();
        let m = pairs.len() as f64;
        let cov = pairs.iter().map(|(a, b)| a * b).sum::<f64>() / m;
        let corr = cov / (1.0 / 12.0);
        assert!(corr.abs() < 4.5 / m.sqrt(), "{corr} over {m} pairs");
    }

    /// The term's mean over its uniform point is the chord integral of sigma_s f Tr (the
    /// point drawn from a stream, as the jittered rays of many passes give): a dense
    /// medium's transmittance falling along a long chord, 40,000 draws, within 5 standard
    /// errors of the draws' own spread.
    #[test]
    fn term_mean_is_the_chord_integral() {
        let r = 0.2f32;
        let psi = Vec3::new(-0.96, 0.28, 0.0);
        let ray = Ray::new(Vec3::ZERO, Vec3::X);
        let piece = piece(Vec3::new(1.5, 0.05, 0.0) - psi * 0.3, psi, 0.6, 2.0);
        let ch = piece_chord(&ray, &piece, (0.0, 10.0), r);
        assert!(ch.counts(r) && ch.hi - ch.lo > 0.3, "a long chord: {ch:?}");
        let g = |t: f32| (1.0 + t) * (-8.0 * t).exp();
        let scatter = |x: Vec3, _cos: f32| Vec3::splat(1.0 + x.x);
        let tr = |t: f32| (-8.0 * t).exp();
        let n = 40_000;
        let mut rng = Rng::new(9, 3);
        let draws: Vec<f64> = (0..n)
            .map(|_| {
                term_at(&ray, &piece, (ch.lo, ch.hi), r, rng.f32(), scatter, tr)
                    .0
                    .x as f64
            })
            .collect();
        let mean = draws.iter().sum::<f64>() / n as f64;
        let var = draws.iter().map(|d| (d - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
        let m = 100_000;
        let h = (ch.hi - ch.lo) as f64 / m as f64;
        let integral: f64 = (0..m)
            .map(|i| g(ch.lo + ((i as f64 + 0.5) * h) as f32) as f64 * h)
            .sum();
        let want = 2.0 * integral / (std::f64::consts::PI * (r * r) as f64);
        let se = (var / n as f64).sqrt();
        assert!((mean - want).abs() < 5.0 * se, "{mean} vs {want} (se {se})");
        assert!(se < 0.01 * want, "the test resolves 1 %: se {se}");
    }

    /// The inner flag: the term's point is within r/2 of the axis, checked against the
    /// point's distance computed from the geometry, over 20,000 random pairs and points.
    #[test]
    fn inner_flag_is_the_half_radius_tube() {
        let r = 0.1f32;
        let mut rng = Rng::new(13, 2);
        let (mut inner, mut counted) = (0, 0);
        for _ in 0..20_000 {
            let (ray, piece) = random_pair(&mut rng, r, 0.0);
            let ch = piece_chord(&ray, &piece, (0.0, 3.0), r);
            if !ch.counts(r) {
                continue;
            }
            counted += 1;
            let u = rng.f32();
            let chord = (ch.lo, ch.hi);
            let (_, flag) = term_at(&ray, &piece, chord, r, u, |_, _| Vec3::ONE, |_| 1.0);
            let x = ray.at(ch.lo + u * (ch.hi - ch.lo));
            let (y, psi) = (Vec3::from(piece.origin), Vec3::from(piece.dir));
            let d = (x - y - psi * (x - y).dot(psi)).length();
            if (d - 0.5 * r).abs() > 1e-4 {
                assert_eq!(flag, d < 0.5 * r, "d {d}");
            }
            inner += flag as u32;
        }
        assert!(counted > 5_000 && inner > 1_000, "{inner} of {counted}");
    }

    /// Over the offsets d of parallel rays crossing a beam long against its chords, the
    /// tube's chords integrate to 1 / sin(theta) (a chord 2 sqrt(r^2 - d^2) / sin over
    /// pi r^2): the same as the line kernel's 1/(2r sin) over d in (-r, r).
    #[test]
    fn chords_over_offsets_match_the_line_kernel() {
        let r = 0.05f32;
        let psi = Vec3::new(0.5, 0.0, 0.75f32.sqrt());
        let sin = 0.75f64.sqrt();
        let n = 20_000;
        let h = 2.0 * r as f64 / n as f64;
        let mut sum = 0.0f64;
        for i in 0..n {
            let d = -r as f64 + (i as f64 + 0.5) * h;
            let ray = Ray::new(Vec3::new(0.0, d as f32, 0.0), Vec3::X);
            let piece = piece(Vec3::new(1.0, 0.0, 0.0) - psi * 5.0, psi, 10.0, 1.0);
            let ch = piece_chord(&ray, &piece, (0.0, 10.0), r);
            if ch.counts(r) {
                sum += (ch.hi - ch.lo) as f64 * h / (std::f64::consts::PI * (r * r) as f64);
            }
        }
        assert!((sum * sin - 1.0).abs() < 2e-3, "{}", sum * sin);
    }
}
