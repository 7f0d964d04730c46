//! Participating media: homogeneous boxes ([`MediumDesc`]) and density grids
//! ([`Heterogeneous`], each owning its majorant octree), combined into the one extinction
//! field the transport code samples ([`Media`]). Overlapping media add their extinction; a
//! collision is attributed to one medium with probability sigma_t_i / sigma_t, which then
//! decides albedo and phase function.
pub mod blosc;
pub mod grid;
pub mod heterogeneous;
pub mod homogeneous;
pub mod nanovdb;
pub mod octrees;
pub mod openvdb;
pub mod phase;
pub mod procedural;

pub use heterogeneous::{GridMedium, Heterogeneous};

/// What the file readers' byte parsers return: the value or what was wrong, to be wrapped
/// with the file's name.
pub type Parse<T> = std::result::Result<T, String>;
pub use homogeneous::MediumDesc;
pub use phase::Phase;

use glam::Vec3;
use smallvec::SmallVec;

use crate::core::{ray_box, Ray, Rgb};
use crate::majorant::Occupancy;

/// A ray interval of constant total extinction.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Piece {
    pub t0: f32,
    pub t1: f32,
    pub sigma_t: f32,
}

/// Ray pieces, kept on the stack for the usual handful of media.
pub type Pieces = SmallVec<[Piece; 4]>;

/// Where a ray from t = 0 crosses one homogeneous box, and its extinction.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Chord {
    near: f32,
    far: f32,
    sigma_t: f32,
}

impl Chord {
    /// The box's share of the optical depth over [0, t]: what a box test clipped to t
    /// gives, with the same bits (the far end is the only one t can move).
    #[inline]
    fn depth(&self, t: f32) -> Option<f32> {
        let far = self.far.min(t);
        (self.near < far).then_some((far - self.near) * self.sigma_t)
    }
}

/// The homogeneous media's boxes along one camera segment. Eq. 2 asks for the camera
/// transmittance at every counted pair, where a box test per medium and pair (three
/// divisions and a slab) was a tenth of fog-box's pass.
#[derive(Clone, Debug, Default)]
pub struct Chords(SmallVec<[Chord; 2]>);

impl Chords {
    /// [`Media::optical_depth`] of the ray the chords were found on, bit for bit.
    #[inline]
    pub fn optical_depth(&self, t: f32) -> f32 {
        self.0.iter().filter_map(|c| c.depth(t)).sum()
    }
}

/// What [`Media::support`] builds once per render for [`Media::supported_spans`].
#[derive(Clone, Debug, Default)]
pub struct Support {
    grids: Vec<Occupancy>,
}

/// `spans` sorted by start, overlapping ones merged.
fn merge<A: smallvec::Array<Item = (f32, f32)>>(mut spans: SmallVec<A>) -> SmallVec<A> {
    spans.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut out: SmallVec<A> = SmallVec::new();
    for (a, b) in spans {
        match out.last_mut() {
            Some(last) if a <= last.1 => last.1 = last.1.max(b),
            _ => out.push((a, b)),
        }
    }
    out
}

/// All media of a scene, queried as one extinction field: homogeneous boxes (sampled and
/// attenuated analytically) plus density grids (sampled by tracking).
#[derive(Clone, Debug, Default)]
pub struct Media {
    pub media: Vec<MediumDesc>,
    /// Density grids, each with its majorants.
    pub grids: Vec<Heterogeneous>,
}

impl Media {
    pub fn new(media: Vec<MediumDesc>) -> Self {
        Media {
            media,
            grids: Vec::new(),
        }
    }

    pub fn with_grids(media: Vec<MediumDesc>, grids: Vec<Heterogeneous>) -> Self {
        Media { media, grids }
    }

    /// Homogeneous `media` and the `fields` with octrees `depth` levels deep baked now (no
    /// cache: tests and in-memory scenes).
    pub fn bake(media: Vec<MediumDesc>, fields: &[GridMedium], depth: u32) -> Self {
        let grids = fields
            .iter()
            .map(|g| Heterogeneous::build(g.clone(), depth))
            .collect();
        Media { media, grids }
    }

    pub fn is_empty(&self) -> bool {
        self.media.is_empty() && self.grids.is_empty()
    }

    pub fn has_grids(&self) -> bool {
        !self.grids.is_empty()
    }

    /// Union of the media boxes, if any.
    pub fn bounds(&self) -> Option<[Vec3; 2]> {
        let boxes = self.media.iter().map(|m| m.bounds);
        boxes
            .chain(self.grids.iter().map(|g| g.bounds))
            .fold(None, |acc, b| {
                Some(match acc {
                    None => b,
                    Some([lo, hi]) => [lo.min(b[0]), hi.max(b[1])],
                })
            })
    }

    /// Sum of the grids' extinction at `p` (1/m).
    pub fn grid_sigma_t(&self, p: Vec3) -> f32 {
        self.grids.iter().map(|g| g.sigma_t(p)).sum()
    }

    /// Whether the ray meets any grid's box over [0, tmax].
    pub fn crosses_grids(&self, ray: &Ray, tmax: f32) -> bool {
        self.grids.iter().any(|g| g.interval(ray, tmax).is_some())
    }

    /// The constant-extinction pieces of the ray inside any homogeneous medium, front to
    /// back.
    pub fn pieces(&self, ray: &Ray, tmax: f32) -> Pieces {
        // One box (a scene's fog): its span is the only piece, no cuts to sort. Every
        // light-path free path asks, so this is a share of free-path time.
        let [m] = &self.media[..] else {
            return self.swept_pieces(ray, tmax);
        };
        let mut out = Pieces::new();
        if m.sigma_t > 0.0 {
            if let Some((t0, t1)) = ray_box(ray, &m.bounds, 0.0, tmax) {
                let sigma_t = m.sigma_t;
                out.push(Piece { t0, t1, sigma_t });
            }
        }
        out
    }

    /// [`Self::pieces`] for any number of boxes: a sweep over their sorted entry and exit
    /// distances.
    fn swept_pieces(&self, ray: &Ray, tmax: f32) -> Pieces {
        let mut out = Pieces::new();
        let spans: SmallVec<[(f32, f32, f32); 4]> = self
            .media
            .iter()
            .filter_map(|m| ray_box(ray, &m.bounds, 0.0, tmax).map(|(a, b)| (a, b, m.sigma_t)))
            .collect();
        let mut cuts: SmallVec<[f32; 8]> = spans.iter().flat_map(|s| [s.0, s.1]).collect();
        cuts.sort_by(f32::total_cmp);
        push_pieces(&cuts, &spans, &mut out);
        out
    }

    /// Merged spans of the ray inside any medium box (homogeneous or grid), front to back.
    pub fn spans(&self, ray: &Ray, tmax: f32) -> SmallVec<[(f32, f32); 4]> {
        self.padded_spans(ray, tmax, 0.0)
    }

    /// [`Self::spans`] with each box's span widened by `pad` (m) on both sides, within
    /// [0, tmax], before spans that then overlap are merged.
    pub fn padded_spans(&self, ray: &Ray, tmax: f32, pad: f32) -> SmallVec<[(f32, f32); 4]> {
        let spans: SmallVec<[(f32, f32); 4]> = self
            .media
            .iter()
            .map(|m| m.bounds)
            .chain(self.grids.iter().map(|g| g.bounds))
            .filter_map(|b| ray_box(ray, &b, 0.0, tmax))
            .map(|(a, b)| ((a - pad).max(0.0), (b + pad).min(tmax)))
            .collect();
        merge(spans)
    }

    /// Where the media can scatter light: each grid's cells with their distances to
    /// positive density, resolved up to `reach` (m; see [`Occupancy`]).
    pub fn support(&self, reach: f32) -> Support {
        let grids = self
            .grids
            .iter()
            .map(|g| Occupancy::new(g.field(), reach))
            .collect();
        Support { grids }
    }

    /// The merged stretches of the ray within [0, tmax] that come within `pad` of a point
    /// where some medium scatters light: the homogeneous boxes with extinction grown by
    /// `pad`, and each grid's cells nearer than `pad` to its density (for a `pad` past
    /// what its cells resolve, the grid's whole box grown by `pad`). A beam estimated with
    /// a kernel of radius `pad` is worth storing only there: elsewhere each camera point
    /// its kernel reaches has no in-scattering.
    pub fn supported_spans(
        &self,
        support: &Support,
        ray: &Ray,
        tmax: f32,
        pad: f32,
    ) -> SmallVec<[(f32, f32); 8]> {
        let padded = |(a, b): (f32, f32)| ((a - pad).max(0.0), (b + pad).min(tmax));
        let mut spans: SmallVec<[(f32, f32); 8]> = SmallVec::new();
        for m in self.media.iter().filter(|m| m.sigma_t > 0.0) {
            spans.extend(ray_box(ray, &m.bounds, 0.0, tmax).map(padded));
        }
        let ours = support.grids.len() == self.grids.len();
        for (i, g) in self.grids.iter().enumerate() {
            match support.grids.get(i).filter(|o| ours && pad <= o.max_reach) {
                Some(occ) => occ.runs(ray, 0.0, tmax, pad, |a, b| spans.push((a, b))),
                None => spans.extend(g.interval(ray, tmax).map(padded)),
            }
        }
        merge(spans)
    }

    /// Integral of the homogeneous media's sigma_t along the ray over [0, t].
    pub fn optical_depth(&self, ray: &Ray, t: f32) -> f32 {
        self.chord_iter(ray).filter_map(|c| c.depth(t)).sum()
    }

    /// The homogeneous media's boxes along `ray`, found once for the many distances a
    /// camera segment is asked about ([`Chords::optical_depth`]).
    pub fn chords(&self, ray: &Ray) -> Chords {
        Chords(self.chord_iter(ray).collect())
    }

    fn chord_iter<'a>(&'a self, ray: &'a Ray) -> impl Iterator<Item = Chord> + 'a {
        self.media.iter().filter_map(|m| {
            let (near, far) = ray_box(ray, &m.bounds, 0.0, f32::INFINITY)?;
            let sigma_t = m.sigma_t;
            Some(Chord { near, far, sigma_t })
        })
    }

    /// The largest |g| of the media's phase functions (0: all isotropic).
    pub fn anisotropy(&self) -> f32 {
        let homogeneous = self.media.iter().map(|m| m.phase.g.abs());
        let grids = self.grids.iter().map(|g| g.phase.g.abs());
        homogeneous.chain(grids).fold(0.0, f32::max)
    }

    /// Total extinction at `p` (1/m).
    pub fn sigma_t(&self, p: Vec3) -> f32 {
        self.homogeneous_sigma_t(p) + self.grid_sigma_t(p)
    }

    fn homogeneous_sigma_t(&self, p: Vec3) -> f32 {
        self.media
            .iter()
            .filter(|m| contains(&m.bounds, p))
            .map(|m| m.sigma_t)
            .sum()
    }

    /// sum_i sigma_s,i(p) * phase_i(cos): what a beam estimate multiplies by (1/(m sr)).
    #[inline]
    pub fn in_scatter(&self, p: Vec3, cos_theta: f32) -> Rgb {
        let mut sum = Vec3::ZERO;
        self.for_each_component(p, |s, albedo, phase| {
            sum += albedo * (s * phase.eval(cos_theta));
            true
        });
        sum
    }

    /// Density of the direction [`Self::pick_collider`]'s phase function draws at `p`:
    /// the phase functions' mixture by sigma_t (1/sr; 0 where nothing scatters).
    pub fn phase_pdf(&self, p: Vec3, cos_theta: f32) -> f32 {
        let (mut sum, mut total) = (0.0, 0.0);
        self.for_each_component(p, |s, _, phase| {
            sum += s * phase.eval(cos_theta);
            total += s;
            true
        });
        if total > 0.0 {
            sum / total
        } else {
            0.0
        }
    }

    /// Calls `f(sigma_t, albedo, phase)` for every medium present at `p`, homogeneous
    /// boxes first, until it returns false. Plain loops, always inlined: as an iterator
    /// chain it stayed an out-of-line call at every beam-pixel pair (7 % of a
    /// glass-caustic profile).
    #[inline(always)]
    fn for_each_component(&self, p: Vec3, mut f: impl FnMut(f32, Rgb, Phase) -> bool) {
        for m in self.media.iter().filter(|m| contains(&m.bounds, p)) {
            if !f(m.sigma_t, m.albedo, m.phase) {
                return;
            }
        }
        for g in &self.grids {
            let s = g.sigma_t(p);
            if s > 0.0 && !f(s, g.albedo, g.phase) {
                return;
            }
        }
    }

    /// Albedo and phase function of the medium a collision at `p` belongs to, chosen with
    /// probability sigma_t,i / sigma_t.
    pub fn pick_collider(&self, p: Vec3, u: f32) -> Option<(Rgb, Phase)> {
        // A lone grid is the collider: a collision in it has sigma_t > 0 there (a tracking
        // lookup or a positive minorant said so), so the two lookups below would pick it.
        if let ([], [g]) = (self.media.as_slice(), self.grids.as_slice()) {
            return Some((g.albedo, g.phase));
        }
        let total = self.sigma_t(p);
        let mut target = u * total;
        let mut last = None;
        self.for_each_component(p, |s, albedo, phase| {
            last = Some((albedo, phase));
            let picked = target < s;
            target -= s;
            !picked
        });
        last
    }
}

fn contains(b: &[Vec3; 2], p: Vec3) -> bool {
    p.cmpge(b[0]).all() && p.cmple(b[1]).all()
}

fn push_pieces(cuts: &[f32], spans: &[(f32, f32, f32)], out: &mut Pieces) {
    for w in cuts.windows(2) {
        let (t0, t1) = (w[0], w[1]);
        if t1 <= t0 {
            continue;
        }
        let mid = 0.5 * (t0 + t1);
        let sigma_t: f32 = spans
            .iter()
            .filter(|s| s.0 <= mid && mid <= s.1)
            .map(|s| s.2)
            .sum();
        if sigma_t > 0.0 {
            match out.last_mut() {
                Some(last) if last.t1 == t0 && last.sigma_t == sigma_t => last.t1 = t1,
                _ => out.push(Piece { t0, t1, sigma_t }),
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fog(lo: [f32; 3], hi: [f32; 3], s: f32) -> MediumDesc {
        MediumDesc {
            bounds: [Vec3::from(lo), Vec3::from(hi)],
            sigma_t: s,
            albedo: Vec3::ONE,
            phase: Phase::ISOTROPIC,
        }
    }

    /// Padding widens each box's span within [0, tmax] and merges spans it makes overlap.
    #[test]
    fn padded_spans_merge_and_clamp() {
        let media = Media::new(vec![
            fog([0.0, -1.0, -1.0], [1.0, 1.0, 1.0], 1.0),
            fog([1.3, -1.0, -1.0], [2.0, 1.0, 1.0], 1.0),
        ]);
        let ray = Ray::new(Vec3::new(-0.1, 0.0, 0.0), Vec3::X);
        let near = |a: &[(f32, f32)], b: &[(f32, f32)]| {
            a.len() == b.len()
                && a.iter()
                    .zip(b)
                    .all(|(x, y)| (x.0 - y.0).abs() < 1e-5 && (x.1 - y.1).abs() < 1e-5)
        };
        let plain = media.spans(&ray, 1.8);
        assert!(near(&plain, &[(0.1, 1.1), (1.4, 1.8)]), "{plain:?}");
        let padded = media.padded_spans(&ray, 1.8, 0.2);
        assert!(near(&padded, &[(0.0, 1.8)]), "{padded:?}");
        let thin = media.padded_spans(&ray, 10.0, 0.1);
        assert!(near(&thin, &[(0.0, 1.2), (1.3, 2.2)]), "{thin:?}");
    }

    /// The one-box shortcut of `pieces` gives the sweep's pieces exactly, over rays that
    /// start inside, outside, miss, or stop in the box, and for a box without extinction.
    #[test]
    fn one_box_pieces_match_the_sweep() {
        let mut rng = crate::sampling::Rng::new(5, 0);
        for sigma_t in [0.0, 0.02, 3.0] {
            let media = Media::new(vec![fog([-1.0, 0.0, -2.0], [2.0, 1.5, 1.0], sigma_t)]);
            let mut v = || Vec3::new(rng.f32(), rng.f32(), rng.f32()) * 2.0 - 1.0;
            for _ in 0..2000 {
                let (o, d) = (v() * 4.0, v().normalize_or(Vec3::X));
                let ray = Ray::new(o, d);
                let tmax = (v().x + 1.0) * 5.0;
                let (fast, swept) = (media.pieces(&ray, tmax), media.swept_pieces(&ray, tmax));
                assert_eq!(fast.len(), swept.len(), "{ray:?} {tmax}");
                for (a, b) in fast.iter().zip(swept.iter()) {
                    assert_eq!((a.t0, a.t1, a.sigma_t), (b.t0, b.t1, b.sigma_t));
                }
            }
        }
    }

    /// The chords found once per ray give, at every t, the bits of a box test clipped to
    /// [0, t] per medium: rays that start inside, outside, miss, graze or stop in the
    /// boxes, t before, inside and past them, and axis-parallel rays.
    #[test]
    fn chords_give_the_clipped_box_tests_depth() {
        let media = Media::new(vec![
            fog([-1.0, 0.0, -2.0], [2.0, 1.5, 1.0], 0.7),
            fog([0.5, -1.0, -1.0], [3.0, 1.0, 0.5], 2.5),
            fog([-3.0, -3.0, -3.0], [-2.0, 3.0, 3.0], 0.0),
        ]);
        let clipped = |ray: &Ray, t: f32| -> f32 {
            let chord =
                |m: &MediumDesc| ray_box(ray, &m.bounds, 0.0, t).map(|(a, b)| (b - a) * m.sigma_t);
            media.media.iter().filter_map(chord).sum()
        };
        let mut rng = crate::sampling::Rng::new(7, 3);
        let mut v = || Vec3::new(rng.f32(), rng.f32(), rng.f32()) * 2.0 - 1.0;
        let (mut inside, mut positive) = (0, 0);
        for i in 0..4000 {
            let o = v() * 4.0;
            let d = match i % 4 {
                0 => Vec3::X * v().x.signum(),
                _ => v().normalize_or(Vec3::Z),
            };
            let ray = Ray::new(o, d);
            let chords = media.chords(&ray);
            for t in [
                0.0,
                (v().x + 1.0) * 4.0,
                v().y.abs() * 0.5,
                1e3,
                f32::INFINITY,
            ] {
                let (got, want) = (chords.optical_depth(t), clipped(&ray, t));
                assert_eq!(got.to_bits(), want.to_bits(), "{ray:?} t = {t}");
                assert_eq!(media.optical_depth(&ray, t).to_bits(), want.to_bits());
                positive += usize::from(want > 0.0);
            }
            inside += usize::from(media.sigma_t(o) > 0.0);
        }
        assert!(inside > 100 && positive > 1000, "{inside} {positive}");
    }

    #[test]
    fn overlapping_media_add() {
        let media = Media::new(vec![
            fog([-1.0, -1.0, -1.0], [1.0, 1.0, 1.0], 1.0),
            fog([0.0, -1.0, -1.0], [3.0, 1.0, 1.0], 2.0),
        ]);
        let ray = Ray::new(Vec3::new(-5.0, 0.0, 0.0), Vec3::X);
        let seg = media.pieces(&ray, 100.0);
        let expect = [(4.0, 5.0, 1.0), (5.0, 6.0, 3.0), (6.0, 8.0, 2.0)];
        assert_eq!(seg.len(), 3);
        for (s, e) in seg.iter().zip(expect) {
            assert!((s.t0 - e.0).abs() < 1e-5 && (s.t1 - e.1).abs() < 1e-5 && s.sigma_t == e.2);
        }
        let tau = media.optical_depth(&ray, 100.0);
        assert!((tau - (2.0 + 6.0)).abs() < 1e-4);
        assert_eq!(media.sigma_t(Vec3::new(0.5, 0.0, 0.0)), 3.0);
    }
}
