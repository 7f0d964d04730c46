//! The paper's eq. 2 (Jarosz et al. 2011, "beam x beam 1D") for one pair of a camera
//! segment and a beam stretch, written once. For a camera ray x + t w and a beam
//! y + s psi of power Phi and radius r,
//!   L += k_r(d) sigma_s(x_w) Phi Tr(x <-> x_w) f(psi . -w) / sin(theta),
//! where x_w is the point of the camera ray closest to the beam's line, d the distance
//! between the lines, theta the angle between them and k_r the normalized 1D box kernel
//! 1/(2r). Short beams carry no transmittance along the beam: the free-path sampling that
//! ended them already distributed it.
//!
//! [`term`] is what the CPU splat (`splat`, primary segments) and the CPU BVH gather
//! (`BeamMap::radiance`, segments after specular bounces) both evaluate, and
//! `piece_radiance` in `shaders/beam_estimate.wgsl` repeats it comparison for comparison.
//! The CPU paths reach it, or the tube kernel's term ([`tube`]), through the kernel's
//! [`pair`] rule and [`pair_term`];
//! [`camera_tr`](crate::transport::transmittance::camera_tr) is the camera-transmittance factor both CPU paths use (the shader's
//! `camera_tr` reads the same estimate as steps).
use bytemuck::{Pod, Zeroable};
use glam::Vec3;

use super::tube;
use crate::core::Ray;
use crate::core::Rgb;
pub use crate::settings::BeamKernel;

/// The stretch [s0, s1) of one beam (whose data it copies, so the map owns everything a
/// query reads). `origin` is the beam's origin: s is measured from it.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
pub struct BeamPiece {
    pub origin: [f32; 3],
    pub s0: f32,
    pub dir: [f32; 3],
    pub s1: f32,
    pub power: [f32; 3],
    /// The beam's [`crate::transport::Beam::scale`]: its kernel radius over the pass's.
    pub scale: f32,
}

/// The normalized 1D kernel of the squared distance d2 = d^2: 1/(2r) on the open interval
/// |d| < r, so it integrates to 1 over d and a crossing at distance exactly r counts
/// nothing. Squared, so that a candidate pair is rejected without a square root.
pub fn kernel(d2: f32, r: f32) -> f32 {
    if d2 < r * r {
        0.5 / r
    } else {
        0.0
    }
}

/// Closest approach of a camera ray and a beam line.
#[derive(Clone, Copy, Debug)]
pub struct Crossing {
    /// Parameter on the camera ray.
    pub t: f32,
    /// Parameter along the beam.
    pub s: f32,
    /// Squared distance between the lines there.
    pub dist2: f32,
    /// sin^2 of the angle between them.
    pub sin2: f32,
    /// The tube kernel's chord [lo, hi) on the ray ([`tube::pair`], which leaves t, s
    /// and dist2 0); eq. 2 leaves it 0.
    pub lo: f32,
    pub hi: f32,
}

/// Where the lines o + t w and y + s psi (unit directions) come closest; None when they
/// are parallel (sin^2 theta < 1e-10).
pub fn crossing(o: Vec3, w: Vec3, y: Vec3, psi: Vec3) -> Option<Crossing> {
    let c = closest_xyz(o.into(), w.into(), y.into(), psi.into());
    if c.sin2 < 1e-10 {
        None
    } else {
        Some(c)
    }
}

/// [`crossing`] without its test for parallel lines (whose t, s and d^2 are then inf or
/// NaN), on plain components: branch-free, so the wide tests (`estimate::lanes`) run it
/// lane by lane. The dot products sum x, y, z in that order, as glam's.
#[inline(always)]
pub fn closest_xyz(o: [f32; 3], w: [f32; 3], y: [f32; 3], psi: [f32; 3]) -> Crossing {
    let dot = |a: [f32; 3], b: [f32; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    let b = dot(w, psi);
    let sin2 = 1.0 - b * b;
    let w0 = [o[0] - y[0], o[1] - y[1], o[2] - y[2]];
    let d = dot(w, w0);
    let e = dot(psi, w0);
    let t = (b * e - d) / sin2;
    let s = (e - b * d) / sin2;
    let v = [0, 1, 2].map(|i| w0[i] + w[i] * t - psi[i] * s);
    let dist2 = dot(v, v);
    Crossing {
        t,
        s,
        dist2,
        sin2,
        lo: 0.0,
        hi: 0.0,
    }
}

/// Eq. 2 for the camera segment [t0, t1) of `ray` and the beam stretch `piece`
/// ([s0, s1) along its beam), or None when the pair does not count.
///
/// The edge rule, half-open everywhere: a crossing counts iff t0 <= t < t1, s0 <= s < s1
/// and d^2 < r^2. Half-open intervals partition: a segment cut into media spans, or a beam cut
/// into BVH pieces, counts a crossing on a cut exactly once; a camera segment includes its
/// start (the camera or the specular vertex it leaves from) and excludes its end (the
/// surface); a beam likewise includes its origin and excludes the point where its free
/// path ended. d^2 < r^2 is the support of [`kernel`] (a crossing that counts lies strictly
/// inside its piece's box grown by r, which the BVH query relies on).
///
/// `in_scatter(x, cos)` is sigma_s(x) f(cos) and `tr(t)` the camera transmittance from
/// the ray origin to t (for a segment of a camera pass: [`camera_tr`]).
pub fn term(
    ray: &Ray,
    span: (f32, f32),
    piece: &BeamPiece,
    r: f32,
    in_scatter: impl Fn(Vec3, f32) -> Rgb,
    tr: impl Fn(f32) -> f32,
) -> Option<Rgb> {
    nested_term(ray, span, piece, r, in_scatter, tr).map(|(l, _)| l)
}

/// [`term`] and whether the crossing also counts at radius r/2 (d^2 < r^2 / 4), where
/// the kernel is twice as high: the same pair's term at r/2 is 2 l or nothing.
pub fn nested_term(
    ray: &Ray,
    span: (f32, f32),
    piece: &BeamPiece,
    r: f32,
    in_scatter: impl Fn(Vec3, f32) -> Rgb,
    tr: impl Fn(f32) -> f32,
) -> Option<(Rgb, bool)> {
    let psi = Vec3::from(piece.dir);
    let c = crossing(ray.o, ray.d, Vec3::from(piece.origin), psi)?;
    let ends = (piece.s0, piece.s1);
    counts(&c, span, ends, r).then(|| counted_term(ray, &c, piece, r, in_scatter, tr))
}

/// The edge rule of [`nested_term`] for a crossing of the segment `span` [t0, t1) and the
/// piece [s0, s1).
#[inline(always)]
pub fn counts(c: &Crossing, (t0, t1): (f32, f32), (s0, s1): (f32, f32), r: f32) -> bool {
    // `&`, not `&&`: one hard-to-predict branch for the pair instead of five.
    (c.dist2 < r * r) & (t0 <= c.t) & (c.t < t1) & (s0 <= c.s) & (c.s < s1)
}

/// A pair's ray o + t w and piece line y + s psi, as plain components (unit w and psi).
pub type Lines = ([f32; 3], [f32; 3], [f32; 3], [f32; 3]);

/// Whether the pair of the ray and the piece's line `lines` over the segment `span` and
/// the piece's [s0, s1) = `ends` counts under `kernel` at radius r, and what its term
/// reads: eq. 2's crossing and edge rule ([`closest_xyz`], [`counts`]), or the tube's
/// chord ([`tube::pair`]). Lines nearer parallel than sin^2 = 1e-10 never count.
/// Branch-free for each kernel: the wide lanes run it, and give its bits.
#[inline(always)]
pub fn pair(
    kernel: BeamKernel,
    lines: Lines,
    span: (f32, f32),
    ends: (f32, f32),
    r: f32,
) -> (bool, Crossing) {
    match kernel {
        BeamKernel::Line => {
            let c = closest_xyz(lines.0, lines.1, lines.2, lines.3);
            ((c.sin2 >= 1e-10) & counts(&c, span, ends, r), c)
        }
        BeamKernel::Tube => tube::pair(lines, span, ends, r),
    }
}

/// The term of a pair that counts under `kernel` ([`pair`]), and whether it also counts at
/// r/2 (where the kernel is [`BeamKernel::inner_ratio`] times as high).
#[inline(always)]
pub fn pair_term(
    kernel: BeamKernel,
    ray: &Ray,
    (piece, c): (&BeamPiece, &Crossing),
    r: f32,
    in_scatter: impl Fn(Vec3, f32) -> Rgb,
    tr: impl Fn(f32) -> f32,
) -> (Rgb, bool) {
    match kernel {
        BeamKernel::Line => counted_term(ray, c, piece, r, in_scatter, tr),
        BeamKernel::Tube => tube::counted_term(ray, piece, c, r, in_scatter, tr),
    }
}

/// [`nested_term`] of a crossing that counts: the part past the edge rule, which the wide
/// crossing tests (`estimate::lanes`) share. Always inlined into the loops over pairs:
/// left to the compiler, whether it was depended on unrelated code and moved a pass's
/// time by a tenth.
#[inline(always)]
pub fn counted_term(
    ray: &Ray,
    c: &Crossing,
    piece: &BeamPiece,
    r: f32,
    in_scatter: impl Fn(Vec3, f32) -> Rgb,
    tr: impl Fn(f32) -> f32,
) -> (Rgb, bool) {
    let psi = Vec3::from(piece.dir);
    let f = in_scatter(ray.at(c.t), psi.dot(-ray.d));
    let half = 4.0 * c.dist2 < r * r;
    // Nothing scatters at a fifth to two fifths of the pairs (a beam's kernel reaches past
    // the density's edge): their term is 0 whatever the transmittance, so skip it.
    if f == Vec3::ZERO {
        return (Vec3::ZERO, half);
    }
    let l = f * Vec3::from(piece.power) * (kernel(c.dist2, r) * tr(c.t) / c.sin2.sqrt());
    (l, half)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::media::Media;
    use crate::transport::transmittance::{camera_tr, SegmentTr};

    /// 2^-10: offsets that keep every coordinate below exactly representable.
    const EPS: f32 = 1.0 / 1024.0;
    const R: f32 = 0.25;

    /// The camera ray from the origin along +x; sigma_s f depends on the point and cosine
    /// so that a wrong x or cos shows, and the transmittance on t.
    fn ray() -> Ray {
        Ray::new(Vec3::ZERO, Vec3::X)
    }
    fn in_scatter(x: Vec3, cos: f32) -> Rgb {
        Vec3::new(1.0 + x.x, 2.0 + cos, 0.5 + x.y)
    }
    fn tr(t: f32) -> f32 {
        1.0 / (1.0 + t)
    }

    /// A beam along +z through (tx, dy, 0) that starts at z = -s_at, so the camera ray
    /// crosses it at t = tx, s = s_at, distance |dy|, at a right angle (all exact).
    fn beam(tx: f32, dy: f32, s_at: f32, len: f32) -> BeamPiece {
        BeamPiece {
            origin: [tx, dy, -s_at],
            s0: 0.0,
            dir: [0.0, 0.0, 1.0],
            s1: len,
            power: [3.0, 5.0, 7.0],
            scale: 1.0,
        }
    }

    /// The closed form for [`beam`]: x = (tx, 0, 0), cos = 0, sin = 1.
    fn expected(tx: f32) -> Rgb {
        Vec3::new(1.0 + tx, 2.0, 0.5) * Vec3::new(3.0, 5.0, 7.0) * (0.5 / R * tr(tx))
    }

    /// Every edge of the rule, with the value the closed form gives where it counts.
    #[test]
    fn term_edge_rule_on_each_edge() {
        let (t0, t1) = (0.0, 2.0);
        // (case, beam, counts)
        let cases = [
            ("t = t0 (segment start)", beam(0.0, 0.1, 0.5, 1.0), true),
            ("t just before t0", beam(-EPS, 0.1, 0.5, 1.0), false),
            ("t just after t0", beam(EPS, 0.1, 0.5, 1.0), true),
            ("t = t1 (segment end)", beam(t1, 0.1, 0.5, 1.0), false),
            ("t just before t1", beam(t1 - EPS, 0.1, 0.5, 1.0), true),
            ("s = 0 (beam origin)", beam(1.0, 0.1, 0.0, 1.0), true),
            ("s just before 0", beam(1.0, 0.1, -EPS, 1.0), false),
            ("s = len (beam end)", beam(1.0, 0.1, 1.0, 1.0), false),
            ("s just before len", beam(1.0, 0.1, 1.0 - EPS, 1.0), true),
            ("s just past len", beam(1.0, 0.1, 1.0 + EPS, 1.0), false),
            ("d = r", beam(1.0, R, 0.5, 1.0), false),
            ("d = -r (other side)", beam(1.0, -R, 0.5, 1.0), false),
            ("d just inside r", beam(1.0, R - EPS, 0.5, 1.0), true),
            ("d just outside r", beam(1.0, R + EPS, 0.5, 1.0), false),
            ("d = 0", beam(1.0, 0.0, 0.5, 1.0), true),
        ];
        for (name, piece, counts) in cases {
            let got = term(&ray(), (t0, t1), &piece, R, in_scatter, tr);
            if counts {
                let want = expected(piece.origin[0]);
                // dy enters only sigma_s f's z through x.y = 0 (x is on the camera ray).
                assert_eq!(got, Some(want), "{name}");
            } else {
                assert_eq!(got, None, "{name}");
            }
        }
    }

    /// A segment that starts later: t = t0 > 0 counts, just before it does not.
    #[test]
    fn term_includes_a_later_segment_start() {
        let (t0, t1) = (0.75, 2.0);
        let at = term(
            &ray(),
            (t0, t1),
            &beam(t0, 0.0, 0.5, 1.0),
            R,
            in_scatter,
            tr,
        );
        assert_eq!(at, Some(expected(t0)));
        let before = term(
            &ray(),
            (t0, t1),
            &beam(t0 - EPS, 0.0, 0.5, 1.0),
            R,
            in_scatter,
            tr,
        );
        assert_eq!(before, None);
    }

    /// A piece [s0, s1) of a longer beam: s = s0 counts, s = s1 belongs to the next piece.
    #[test]
    fn term_pieces_partition_the_beam() {
        let mut a = beam(1.0, 0.1, 3.0, 6.0);
        a.s1 = 3.0;
        let mut b = a;
        (b.s0, b.s1) = (3.0, 6.0);
        let span = (0.0, 2.0);
        assert_eq!(term(&ray(), span, &a, R, in_scatter, tr), None);
        assert_eq!(
            term(&ray(), span, &b, R, in_scatter, tr),
            Some(expected(1.0))
        );
    }

    /// An oblique beam: 1/sin(theta) and the phase cosine. psi = (0.6, 0, 0.8) meets +x at
    /// cos 0.6 (sin 0.8) and crosses the ray at t = 2, s = 1, distance 0.1 (the offset is
    /// along y, normal to both lines).
    #[test]
    fn term_oblique_closed_form() {
        let psi = Vec3::new(0.6, 0.0, 0.8);
        let y = Vec3::new(2.0, 0.1, 0.0) - psi;
        let piece = BeamPiece {
            origin: y.into(),
            s0: 0.0,
            dir: psi.into(),
            s1: 1.5,
            power: [3.0, 5.0, 7.0],
            scale: 1.0,
        };
        let got = term(&ray(), (0.0, 4.0), &piece, R, in_scatter, tr).unwrap();
        let want =
            Vec3::new(3.0, 2.0 - 0.6, 0.5) * Vec3::new(3.0, 5.0, 7.0) * (2.0 * tr(2.0)) / 0.8;
        assert!(
            (got - want).abs().max_element() < 1e-5 * want.max_element(),
            "{got} vs {want}"
        );
        let parallel = BeamPiece {
            dir: [1.0, 0.0, 0.0],
            ..piece
        };
        assert!(term(&ray(), (0.0, 4.0), &parallel, R, in_scatter, tr).is_none());
    }

    #[test]
    fn kernel_is_normalized() {
        let r = 0.037;
        let n = 100_000;
        let h = 4.0 * r / n as f32;
        let integral: f32 = (0..n)
            .map(|i| kernel((-2.0 * r + (i as f32 + 0.5) * h).powi(2), r) * h)
            .sum();
        assert!((integral - 1.0).abs() < 1e-3);
    }

    #[test]
    fn crossing_of_perpendicular_lines() {
        let c = crossing(Vec3::ZERO, Vec3::X, Vec3::new(2.0, 0.3, -1.0), Vec3::Z).unwrap();
        assert!((c.t - 2.0).abs() < 1e-6 && (c.s - 1.0).abs() < 1e-6);
        assert!((c.dist2 - 0.09).abs() < 1e-6 && (c.sin2 - 1.0).abs() < 1e-6);
    }

    /// The camera transmittance: the box's exact exp(-sigma_t * chord) times the grid
    /// estimate, whose steps apply after their t (a ratio step exactly at t not yet).
    #[test]
    fn camera_tr_is_box_chord_times_grid_estimate() {
        use crate::media::{MediumDesc, Phase};
        use crate::transport::freepath::RatioSteps;
        let media = Media::new(vec![MediumDesc {
            bounds: [Vec3::new(1.0, -1.0, -1.0), Vec3::new(3.0, 1.0, 1.0)],
            sigma_t: 0.5,
            albedo: Vec3::ONE,
            phase: Phase { g: 0.0 },
        }]);
        let grids = SegmentTr::Ratio(RatioSteps::from_slice(&[(2.0, 0.25)]));
        let chords = media.chords(&ray());
        assert_eq!(camera_tr(&chords, &grids, 0.5), 1.0);
        assert_eq!(camera_tr(&chords, &grids, 2.0), (-0.5f32).exp());
        assert_eq!(camera_tr(&chords, &grids, 2.5), (-0.75f32).exp() * 0.25);
        assert_eq!(camera_tr(&chords, &grids, 4.0), (-1.0f32).exp() * 0.25);
    }

    /// The grid factor agrees with the steps the GPU reads (`grid_tr` in the shader: the
    /// value after the last step with t_k < t) at every step's t and between them, for
    /// free paths (one ending exactly at a step of another) and ratio tracking.
    #[test]
    fn grid_estimate_matches_gpu_steps_at_ties() {
        use crate::settings::MAX_TR_SAMPLES;
        use crate::transport::freepath::RatioSteps;
        let mut lengths = [f32::INFINITY; MAX_TR_SAMPLES];
        lengths[..4].copy_from_slice(&[1.0, 0.5, 1.0, 2.0]);
        let free = SegmentTr::FreePaths { lengths, m: 5 };
        let ratio = SegmentTr::Ratio(RatioSteps::from_slice(&[(0.5, 0.5), (1.0, 0.25)]));
        for tr in [free, ratio] {
            let mut steps = Vec::new();
            tr.steps(&mut steps);
            let gpu = |t: f32| {
                let i = steps.partition_point(|s| s[0] < t);
                if i == 0 {
                    1.0
                } else {
                    steps[i - 1][1]
                }
            };
            for t in [0.0, 0.25, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0] {
                assert_eq!(tr.eval(t), gpu(t), "{tr:?} at {t}");
            }
        }
    }
}
