//! The beam estimate along primary camera segments by splatting (the original PPB's
//! rasterised beams, done on the CPU): every beam is drawn as a thick 2D line over the
//! pixels its radius-inflated projection can touch, and eq. 2 is evaluated exactly for
//! each of those pixels' jittered rays. The work is the true beam/ray crossings plus a
//! thin margin, where a BVH query from each ray visits several times more candidates.
//!
//! Rows are cut into bands processed in parallel; each band reads its beams in beam order,
//! so sums (and images) do not depend on the thread count.
use glam::{Vec2, Vec3};
use rayon::prelude::*;

use super::eq2::{counted_term, BeamPiece, Crossing};
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
/// Beams closer than this to the camera plane are clipped (m).
const NEAR: f32 = 1e-3;

/// Accumulates eq. 2 for all beams along all primary segments; returns per-pixel radiance
/// (with its nested half-radius difference) and the number of kernel evaluations that
/// contributed. `isa` tests a row's pixels for a beam that many at a time; every choice
/// gives the same bits.
pub fn splat(
    cam: &Pinhole,
    primaries: &[Primary],
    beams: &[Beam],
    radius: f32,
    media: &Media,
    isa: Isa,
) -> (Vec<Nested>, u64) {
    let (w, h) = (cam.width() as usize, cam.height() as usize);
    let bands = h.div_ceil(BAND);
    let reach = reach_per_radius(cam);
    let lines: Vec<Option<Line>> = beams
        .par_iter()
        .map(|b| Line::project(cam, b, radius * b.scale, reach))
        .collect();
    let mut per_band: Vec<Vec<u32>> = vec![Vec::new(); bands];
    for (i, l) in lines.iter().enumerate() {
        if let Some(l) = l {
            let y0 = (l.ymin.max(0.0) as usize).min(h - 1);
            let y1 = (l.ymax.max(0.0) as usize).min(h - 1);
            for list in &mut per_band[y0 / BAND..=y1 / BAND] {
                list.push(i as u32);
            }
        }
    }
    let origin = cam.origin();
    // Crossings past where a segment's transmittance estimate is 0 weigh nothing.
    let rays = Rays::new(
        primaries
            .par_iter()
            .map(|p| (p.dir, p.tr.seen_until(p.t_surf))),
    );
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
                let Some(line) = &lines[bi as usize] else {
                    continue;
                };
                let piece = BeamPiece::whole(&beams[bi as usize]);
                let fixed = Fixed::new(origin, &piece, radius);
                let own = radius * piece.scale;
                for y in row0..row0 + rows {
                    let Some((x0, x1)) = line.row_span(y as f32, w) else {
                        continue;
                    };
                    let pixels = y * w + x0..y * w + x1 + 1;
                    fixed.for_each_counted(isa, &rays, pixels, |i, c| {
                        let l = contribution(origin, &primaries[i], &piece, c, own, media);
                        img[i - row0 * w].add(l);
                        evals += 1;
                    });
                }
            }
            evals
        })
        .sum();
    (img, evals)
}

/// Eq. 2 for one beam and one primary segment [0, t_surf) whose crossing `c` counts.
#[inline(always)]
fn contribution(
    o: Vec3,
    p: &Primary,
    beam: &BeamPiece,
    c: &Crossing,
    r: f32,
    media: &Media,
) -> (Rgb, bool) {
    let ray = Ray::new(o, p.dir);
    let scatter = |x, cos| media.in_scatter(x, cos);
    counted_term(&ray, c, beam, r, scatter, |t| {
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
