//! The beam estimate along primary camera segments by splatting (the original PPB's
//! rasterised beams, done on the CPU): every beam is drawn as a thick 2D line over the
//! pixels its radius-inflated projection can touch, and eq. 2 is evaluated exactly for
//! each of those pixels' jittered rays. The work is the true beam/ray crossings plus a
//! thin margin, where a BVH query from each ray visits several times more candidates.
//! A row's run of pixels is skipped where every segment's transmittance estimate has
//! reached 0 before the beam's nearest possible crossing (a beam inside or behind a
//! cloud): the same pairs count.
//!
//! Rows are cut into bands processed in parallel; each band reads its beams in beam order,
//! so sums (and images) do not depend on the thread count.
use glam::{Vec2, Vec3};
use rayon::prelude::*;

use super::beam_reach;
use super::eq2::{pair_term, BeamKernel, BeamPiece, Crossing};
use super::lanes::{Fixed, Rays};
use crate::core::simd::Isa;
use crate::core::Nested;
use crate::core::Ray;
use crate::core::Rgb;
use crate::media::Media;
use crate::transport::camera::{Pinhole, Primary};
use crate::transport::transmittance::camera_tr;
use crate::transport::Beam;

/// Rows per parallel band.
const BAND: usize = 4;
/// Pixels per run of a row whose farthest seen distance the occlusion test keeps.
const RUN: usize = 16;
/// Beams closer than this to the camera plane are clipped (m).
const NEAR: f32 = 1e-3;

/// Accumulates `kernel`'s term for all beams along all primary segments; returns per-pixel
/// radiance (with its nested half-radius difference) and the number of kernel evaluations
/// that contributed. `isa` tests a row's pixels for a beam that many at a time; every
/// choice gives the same bits.
pub fn splat(
    cam: &Pinhole,
    primaries: &[Primary],
    beams: &[Beam],
    (radius, kernel): (f32, BeamKernel),
    media: &Media,
    isa: Isa,
) -> (Vec<Nested>, u64) {
    let (w, h) = (cam.width() as usize, cam.height() as usize);
    let bands = h.div_ceil(BAND);
    let reach = reach_per_radius(cam);
    let origin = cam.origin();
    // Each beam on the film, with the nearest camera distance at which it can count.
    let lines: Vec<Option<(Line, f32)>> = beams
        .par_iter()
        .map(|b| {
            let r = radius * b.scale;
            let line = Line::project(cam, b, r, reach)?;
            Some((
                line,
                nearest_crossing(origin, &BeamPiece::whole(b), r, kernel),
            ))
        })
        .collect();
    let mut per_band: Vec<Vec<u32>> = vec![Vec::new(); bands];
    for (i, l) in lines.iter().enumerate() {
        if let Some((l, _)) = l {
            let y0 = (l.ymin.max(0.0) as usize).min(h - 1);
            let y1 = (l.ymax.max(0.0) as usize).min(h - 1);
            for list in &mut per_band[y0 / BAND..=y1 / BAND] {
                list.push(i as u32);
            }
        }
    }
    // Crossings past where a segment's transmittance estimate is 0 weigh nothing.
    let bounds = media.bounds();
    let rays = Rays::new(primaries.par_iter().map(|p| {
        let reach = beam_reach(
            bounds.as_ref(),
            &Ray::new(origin, p.dir),
            p.tr.seen_until(p.t_surf),
        );
        (p.dir, reach.unwrap_or(0.0))
    }));
    let seen = Seen::new(&rays, w, h);
    let mut img = vec![Nested::default(); w * h];
    // Each band writes its rows of the image in place: no serial assembly after.
    let evals = img
        .par_chunks_mut(BAND * w)
        .zip(per_band.par_iter())
        .enumerate()
        .map(|(band, (img, list))| {
            let row0 = band * BAND;
            let rows = img.len() / w;
            let mut evals = 0u64;
            for &bi in list {
                let Some((line, nearest)) = &lines[bi as usize] else {
                    continue;
                };
                let piece = BeamPiece::whole(&beams[bi as usize]);
                let fixed = Fixed::new(origin, &piece, radius, kernel);
                let own = radius * piece.scale;
                for y in row0..row0 + rows {
                    let Some((x0, x1)) = line.row_span(y as f32, w) else {
                        continue;
                    };
                    if seen.hidden(y, x0, x1, *nearest) {
                        continue;
                    }
                    let pixels = y * w + x0..y * w + x1 + 1;
                    fixed.for_each_counted(isa, &rays, pixels, |i, c| {
                        let pair = (&piece, c, own, kernel);
                        let l = contribution(origin, &primaries[i], pair, media);
                        img[i - row0 * w].add_in(l, kernel.inner_ratio());
                        evals += 1;
                    });
                }
            }
            evals
        })
        .sum();
    (img, evals)
}

/// The farthest distance any primary segment of a run of [`RUN`] pixels of a row still sees
/// (where its transmittance estimate is not yet 0): a beam wholly beyond it in every run a
/// row span touches counts nothing there. Two fifths of cloud-hg's candidate pairs were
/// beams inside or behind the cloud, where every camera estimate had reached 0 (measured
/// in docs/benchmarks.md).
struct Seen {
    runs: usize,
    far: Vec<f32>,
}

impl Seen {
    fn new(rays: &Rays, w: usize, h: usize) -> Seen {
        let runs = w.div_ceil(RUN);
        let far = (0..h * runs)
            .into_par_iter()
            .map(|k| {
                let (y, run) = (k / runs, k % runs);
                let row = &rays.t1[y * w..(y + 1) * w];
                row[run * RUN..((run + 1) * RUN).min(w)]
                    .iter()
                    .fold(f32::NEG_INFINITY, |a, &t| a.max(t))
            })
            .collect();
        Seen { runs, far }
    }

    /// Whether no pixel of row y's span [x0, x1] sees as far as `nearest`.
    fn hidden(&self, y: usize, x0: usize, x1: usize, nearest: f32) -> bool {
        let row = &self.far[y * self.runs..(y + 1) * self.runs];
        row[x0 / RUN..=x1 / RUN].iter().all(|&far| far <= nearest)
    }
}

/// A lower bound on the camera distance t at which any pair of `piece` that counts at
/// radius `r` is evaluated, D being the piece's nearest distance to the origin `o`.
/// - Line: at a crossing the beam point p and the camera ray's point at t are less than r
///   apart along a line square to the ray, so |p - o|^2 = t^2 + d^2 with d < r, and
///   t > sqrt(D^2 - r^2).
/// - Tube: every point of a chord is within r of the piece, so t > D - r.
///
/// Lowered by a relative 1e-4 for the rounding of t in
/// [`closest_xyz`](super::eq2::closest_xyz) and of the chord's ends.
fn nearest_crossing(o: Vec3, piece: &BeamPiece, r: f32, kernel: BeamKernel) -> f32 {
    let (a, d) = (Vec3::from(piece.origin), Vec3::from(piece.dir));
    let s = (o - a).dot(d).clamp(piece.s0, piece.s1);
    let dist2 = (a + d * s - o).length_squared();
    let t = match kernel {
        BeamKernel::Line => (dist2 - r * r).max(0.0).sqrt(),
        BeamKernel::Tube => (dist2.sqrt() - r).max(0.0),
    };
    t * (1.0 - 1e-4) - 1e-4 * r
}

/// The kernel's term for one beam and one primary segment whose crossing `c` counts at
/// radius r.
#[inline(always)]
fn contribution(
    o: Vec3,
    p: &Primary,
    (beam, c, r, kernel): (&BeamPiece, &Crossing, f32, BeamKernel),
    media: &Media,
) -> (Rgb, bool) {
    let ray = Ray::new(o, p.dir);
    let scatter = |x, cos| media.in_scatter(x, cos);
    pair_term(kernel, &ray, (beam, c), r, scatter, |t| {
        camera_tr(&p.chords, &p.tr, t)
    })
}

/// A beam projected to the film: a 2D segment whose half-width in pixels varies linearly
/// along it (from `h0` at `p0` to `h1` at `p1`).
pub(crate) struct Line {
    p0: Vec2,
    p1: Vec2,
    h0: f32,
    h1: f32,
    ymin: f32,
    ymax: f32,
}

/// Slack on the half-width for float rounding of projections and jittered pixel positions.
const SLACK_SCALE: f32 = 1.001;
const SLACK_PIXELS: f32 = 0.01;

/// How far from the projected beam a counting pixel's film position can be, per unit of
/// radius: a beam point within r of the pixel's ray, at depth z, projects within
/// r sqrt(1 + k^2) pixel widths at depth z of the ray's film position
/// (k: [`Pinhole::film_slope_bound`]).
pub(crate) fn reach_per_radius(cam: &Pinhole) -> f32 {
    (1.0 + cam.film_slope_bound().powi(2)).sqrt()
}

impl Line {
    /// The thick line of beam `b` of radius `r`, `reach` being [`reach_per_radius`]. 1/z
    /// is linear along the projected segment, so the half-width is too; it is evaluated at
    /// the clipped ends.
    pub(crate) fn project(cam: &Pinhole, b: &Beam, r: f32, reach: f32) -> Option<Line> {
        let a = Vec3::from(b.origin);
        let d = Vec3::from(b.dir);
        let (mut s0, mut s1) = (0.0f32, b.length);
        // Clip to the half-space in front of the camera (with the radius as margin).
        let z0 = cam.depth(a);
        let dz = cam.depth(a + d) - z0;
        let near = NEAR + r;
        if dz.abs() < 1e-12 {
            if z0 < near {
                return None;
            }
        } else {
            let s_near = (near - z0) / dz;
            if dz > 0.0 {
                s0 = s0.max(s_near);
            } else {
                s1 = s1.min(s_near);
            }
        }
        if s0 >= s1 {
            return None;
        }
        let (e0, e1) = (a + d * s0, a + d * s1);
        let half = |e: Vec3| {
            let z = cam.depth(e).max(NEAR);
            r * reach * cam.pixels_per_unit_at(z) * SLACK_SCALE + SLACK_PIXELS
        };
        let (h0, h1) = (half(e0), half(e1));
        let p0 = cam.project(e0);
        let p1 = cam.project(e1);
        let h = h0.max(h1);
        let ymin = p0.y.min(p1.y) - h;
        let ymax = p0.y.max(p1.y) + h;
        if ymax < 0.0 || ymin >= cam.height() as f32 {
            return None;
        }
        let xmin = p0.x.min(p1.x) - h;
        let xmax = p0.x.max(p1.x) + h;
        if xmax < 0.0 || xmin >= cam.width() as f32 {
            return None;
        }
        Some(Line {
            p0,
            p1,
            h0,
            h1,
            ymin,
            ymax,
        })
    }

    /// The corners of a rectangle holding every pixel centre whose pixel can count: the
    /// segment grown by its largest half-width plus the distance from a pixel's centre to
    /// any film position in it (sqrt(1/2), rounded up), along and across it. In the order
    /// of a two-triangle strip: start right, start left, end right, end left.
    pub(crate) fn rectangle(&self) -> [Vec2; 4] {
        let grow = self.h0.max(self.h1) + 0.75;
        let d = self.p1 - self.p0;
        let along = if d.length_squared() > 1e-12 {
            d.normalize() * grow
        } else {
            Vec2::X * grow
        };
        let across = along.perp();
        let (a, b) = (self.p0 - along, self.p1 + along);
        [a - across, a + across, b - across, b + across]
    }

    /// Half-width at parameter u of the segment.
    fn half_at(&self, u: f32) -> f32 {
        self.h0 + (self.h1 - self.h0) * u
    }

    /// Pixel columns of row `y` (covering [y, y+1)) the thick line can touch: the part of
    /// the segment within the widest half-width of the row's band, widened by the largest
    /// half-width on that part.
    fn row_span(&self, y: f32, w: usize) -> Option<(usize, usize)> {
        let h = self.h0.max(self.h1);
        let (lo, hi) = (y - h, y + 1.0 + h);
        let d = self.p1 - self.p0;
        let (xa, xb, local) = if d.y.abs() < 1e-6 {
            if self.p0.y < lo || self.p0.y > hi {
                return None;
            }
            (self.p0.x.min(self.p1.x), self.p0.x.max(self.p1.x), h)
        } else {
            let ua = ((lo - self.p0.y) / d.y).clamp(0.0, 1.0);
            let ub = ((hi - self.p0.y) / d.y).clamp(0.0, 1.0);
            if ua == ub {
                return None;
            }
            let (xa, xb) = (self.p0.x + d.x * ua, self.p0.x + d.x * ub);
            let local = self.half_at(ua).max(self.half_at(ub));
            (xa.min(xb), xa.max(xb), local)
        };
        // Truncation is floor on what is not negative (and `floor` a libm call in the
        // portable build); a right end below 0 leaves nothing.
        let x0 = (xa - local).max(0.0) as usize;
        let x1 = (xb + local).min(w as f32 - 1.0);
        (x1 >= 0.0 && x0 <= x1 as usize).then_some((x0, x1 as usize))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::estimate::eq2::{counts, crossing};
    use crate::estimate::tube;
    use crate::sampling::{orthonormal_basis, uniform_sphere, Rng};

    /// No pair that counts crosses nearer than [`nearest_crossing`] (line kernel), and no
    /// tube chord starts nearer than the tube's bound. 400,000 rays pass
    /// a random beam's nearest point to the camera at a random distance below the radius
    /// (where the bound is nearly attained), half of them within 1e-5 to 1e-2 radians of
    /// the beam's direction (where t's rounding is largest), at radii from 1e-3 to 1.
    #[test]
    fn no_counted_crossing_is_nearer_than_the_bound() {
        let mut rng = Rng::new(21, 0);
        let (mut counted, mut tight, mut tube_tight) = (0, 0, 0);
        for k in 0..400_000 {
            let o = (uniform_sphere(rng.vec2()) * 3.0).round();
            let r = 10f32.powf(-3.0 * rng.f32());
            let d = uniform_sphere(rng.vec2());
            let length = 10f32.powf(2.0 * rng.f32() - 1.5);
            // The beam's nearest point p, D from o along u (u square to d).
            let (u, v) = orthonormal_basis(d);
            let big_d = r * (1.0 + 10f32.powf(3.0 * rng.f32() - 1.0));
            let s_near = length * rng.f32();
            let p = o + u * big_d;
            let a = p - d * s_near;
            let piece = BeamPiece {
                origin: a.into(),
                s0: 0.0,
                dir: d.into(),
                s1: length,
                power: [1.0; 3],
                scale: 1.0,
            };
            // Aim at a point rho < r from p, off the line o-p, along v (square to u, d).
            let rho = r * (1.0 - rng.f32().powi(4));
            let mut w = (p + v * rho - o).normalize();
            if k % 2 == 0 {
                let tilt = 10f32.powf(-5.0 + 3.0 * rng.f32());
                w = (d * w.dot(d).signum() + uniform_sphere(rng.vec2()) * tilt).normalize();
            }
            let Some(c) = crossing(o, w, a, d) else {
                continue;
            };
            let (span, ends) = ((0.0, f32::INFINITY), (0.0, length));
            let lines = (o.into(), w.into(), a.into(), d.into());
            if crate::estimate::eq2::pair(BeamKernel::Tube, lines, span, ends, r).0 {
                let lo = tube::chord(o.into(), w.into(), a.into(), d.into(), span, ends, r).lo;
                let bound = nearest_crossing(o, &piece, r, BeamKernel::Tube);
                assert!(lo >= bound, "chord from {lo} < bound {bound} (r {r})");
                tube_tight += (lo < bound + 0.01 * r) as u32;
            }
            if counts(&c, span, ends, r) {
                counted += 1;
                let bound = nearest_crossing(o, &piece, r, BeamKernel::Line);
                assert!(
                    c.t >= bound,
                    "t {} < bound {bound} (r {r}, sin2 {})",
                    c.t,
                    c.sin2
                );
                tight += (c.t < bound + 0.01 * r) as u32;
            }
        }
        assert!(counted > 100_000, "{counted} pairs counted");
        assert!(tight > 1_000, "{tight} pairs within r / 100 of the bound");
        assert!(
            tube_tight > 1_000,
            "{tube_tight} chords within r / 100 of the bound"
        );
    }

    /// A row span is hidden only where every run it touches sees no farther than the bound.
    #[test]
    fn a_span_is_hidden_only_behind_every_run() {
        let (w, h) = (40, 2);
        let rays = Rays::new((0..w * h).into_par_iter().map(|i| (Vec3::X, i as f32)));
        let seen = Seen::new(&rays, w, h);
        // Row 0, pixels 0..=15 see up to 15; 16..=31 up to 31.
        assert!(seen.hidden(0, 0, 15, 15.0));
        assert!(!seen.hidden(0, 0, 15, 14.9));
        assert!(!seen.hidden(0, 3, 16, 20.0));
        assert!(seen.hidden(0, 3, 16, 31.0));
        // Row 1's last run (pixels 32..=39 of it) sees up to 79.
        assert!(!seen.hidden(1, 35, 39, 78.0));
        assert!(seen.hidden(1, 35, 39, 79.0));
    }
}
