//! The GPU beam estimate's buffers as `Pod` structs, defined once: the CPU fills them from
//! [`Media`] and the traced pass, and `shaders/beam_estimate.wgsl` declares the same
//! layouts (checked by the naga test in `gpu::tests`). Beams travel as
//! [`crate::estimate::eq2::BeamPiece`] and [`crate::estimate::beams::BvhNode`].
use bytemuck::{Pod, Zeroable};

use crate::core::Ray;
use crate::error::{Error, Result};
use crate::estimate::beam_reach;
use crate::estimate::eq2::{BeamKernel, BeamPiece};
use crate::majorant::{Mode, Node};
use crate::media::grid::{Grid, SEARCH_SLOT};
use crate::media::{GridMedium, Media};
use crate::transport::camera::CameraPass;
use crate::transport::transmittance::SegmentTr;
use crate::transport::Beam;
use glam::{Vec2, Vec3};

/// Homogeneous media and grids the uniform block has room for.
pub const MAX_BOXES: usize = 16;
pub const MAX_GRIDS: usize = 8;

#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
pub struct MediumBox {
    pub min: [f32; 3],
    pub sigma_t: f32,
    pub max: [f32; 3],
    pub g: f32,
    pub albedo: [f32; 3],
    pub _pad: f32,
}

/// One grid medium: its world-to-index map (rows of a 3x4 matrix), world box, optics and
/// where its leaf table, leaf values and tiles start in the shared `grid_data` buffer.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
pub struct GridMeta {
    pub rows: [[f32; 4]; 3],
    pub bmin: [f32; 3],
    pub density_scale: f32,
    pub bmax: [f32; 3],
    pub g: f32,
    pub albedo: [f32; 3],
    pub background: f32,
    pub table_min: [i32; 3],
    pub leaf_base: u32,
    pub table_dim: [i32; 3],
    pub table_base: u32,
    pub tile_base: u32,
    pub tile_count: u32,
    pub _pad: [u32; 2],
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct Params {
    pub radius: f32,
    pub box_count: u32,
    pub grid_count: u32,
    /// The image width when primary segments are rasterised, 0 when they are gathered.
    pub raster_width: u32,
    /// This pass's key for camera transmittance tracked on the GPU ...
    pub pass_seed: u32,
    /// ... and whether it is (1), else the kernels read the CPU's estimate as steps (0).
    pub track_tr: u32,
    /// BVH walk iterations per segment per dispatch round: unbounded on hardware, a few
    /// thousand on software adapters, which end an invocation's loops after 65,535
    /// iterations in all; longer walks resume in further rounds.
    pub walk_budget: u32,
    /// The beam kernel: 0 eq. 2's line, 1 the tube ([`kernel_word`]).
    pub kernel: u32,
    pub boxes: [MediumBox; MAX_BOXES],
    pub grids: [GridMeta; MAX_GRIDS],
}

/// The segments or pixels one dispatch covers (dispatches are split so none runs long
/// enough to lose the device).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
pub struct Chunk {
    pub first: u32,
    pub count: u32,
    pub _pad: [u32; 2],
}

/// A camera segment [t0, t1) of a ray with path weight beta; its grid transmittance is
/// the step function `tr_steps[tr_first .. tr_first + tr_count]`, or, tracked on the GPU,
/// the realization keyed by `seed` (unique in its pass) and the pass.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
pub struct Segment {
    pub origin: [f32; 3],
    pub t0: f32,
    pub dir: [f32; 3],
    pub t1: f32,
    pub beta: [f32; 3],
    pub tr_first: u32,
    pub tr_count: u32,
    pub seed: u32,
    pub _pad: [u32; 2],
}

/// The media part of [`Params`] and the `grid_data` words (leaf tables, leaf values and
/// tiles of every grid, f32 stored as bits).
pub fn media_params(media: &Media) -> Result<(Params, Vec<u32>)> {
    if media.media.len() > MAX_BOXES || media.grids.len() > MAX_GRIDS {
        return Err(Error::Other(format!(
            "the GPU estimate handles up to {MAX_BOXES} homogeneous media and {MAX_GRIDS} grids; \
             this scene has {} and {} (use --device cpu)",
            media.media.len(),
            media.grids.len()
        )));
    }
    let mut p = Params {
        radius: 0.0,
        box_count: media.media.len() as u32,
        grid_count: media.grids.len() as u32,
        raster_width: 0,
        pass_seed: 0,
        track_tr: 0,
        walk_budget: u32::MAX,
        kernel: kernel_word(BeamKernel::Line),
        boxes: [MediumBox::default(); MAX_BOXES],
        grids: [GridMeta::default(); MAX_GRIDS],
    };
    for (b, m) in p.boxes.iter_mut().zip(&media.media) {
        *b = MediumBox {
            min: m.bounds[0].into(),
            sigma_t: m.sigma_t,
            max: m.bounds[1].into(),
            g: m.phase.g,
            albedo: m.albedo.into(),
            _pad: 0.0,
        };
    }
    let mut data = Vec::new();
    for (meta, g) in p.grids.iter_mut().zip(&media.grids) {
        *meta = grid_meta(g, &mut data)?;
    }
    Ok((p, data))
}

fn grid_meta(g: &GridMedium, data: &mut Vec<u32>) -> Result<GridMeta> {
    let grid: &Grid = &g.grid;
    let m = g.world_to_index.matrix3;
    let t = g.world_to_index.translation;
    let rows = [0, 1, 2].map(|r| {
        [
            m.col(0)[r] as f32,
            m.col(1)[r] as f32,
            m.col(2)[r] as f32,
            t[r] as f32,
        ]
    });
    let (table, table_min, table_dim) = grid.leaf_table();
    let offset = |data: &Vec<u32>| {
        u32::try_from(data.len())
            .map_err(|_| Error::Other(format!("{}: grid too large for the GPU", g.source)))
    };
    let table_base = offset(data)?;
    // The shader searches the tiles at every slot without a leaf or a whole tile.
    data.extend(
        table
            .iter()
            .map(|&s| if s == SEARCH_SLOT { u32::MAX } else { s }),
    );
    let leaf_base = offset(data)?;
    for (_, leaf) in grid.leaves() {
        data.extend(leaf.values().map(f32::to_bits));
    }
    let tile_base = offset(data)?;
    for tile in grid.tiles() {
        data.extend(tile.min.to_array().map(|v| v as u32));
        data.extend(tile.max.to_array().map(|v| v as u32));
        data.push(tile.value.to_bits());
    }
    offset(data)?;
    Ok(GridMeta {
        rows,
        bmin: g.bounds[0].into(),
        density_scale: g.density_scale,
        bmax: g.bounds[1].into(),
        g: g.phase.g,
        albedo: g.albedo.into(),
        background: grid.background,
        table_min: table_min.to_array(),
        leaf_base,
        table_dim: table_dim.to_array(),
        table_base,
        tile_base,
        tile_count: grid.tiles().len() as u32,
        _pad: [0; 2],
    })
}

/// A beam's rectangle on the film for the rasterised primary estimate: its corners in
/// normalised device coordinates (two-triangle strip order) and the beam itself.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct BeamQuad {
    pub corners: [[f32; 2]; 4],
    pub piece: BeamPiece,
}

impl BeamQuad {
    /// The quad of `beam` whose film rectangle is `rect` (pixels, y down) on a
    /// `width` x `height` image.
    pub fn new(rect: [Vec2; 4], beam: &Beam, width: u32, height: u32) -> Self {
        let (w, h) = (width as f32, height as f32);
        BeamQuad {
            corners: rect.map(|c| [2.0 * c.x / w - 1.0, 1.0 - 2.0 * c.y / h]),
            piece: BeamPiece::whole(beam),
        }
    }
}

/// One pass's camera segments as the kernels read them: segments in pixel order with
/// per-pixel ranges into them (`pixels + 1` entries), and the transmittance steps. When
/// primary segments are rasterised they are kept apart, one per pixel (an empty one where
/// the ray misses the media), and `segments` holds the later ones only. Without `steps`
/// (the GPU tracks transmittance itself) no steps are uploaded.
#[derive(Default)]
pub struct SegmentUpload {
    pub segments: Vec<Segment>,
    pub pixel_first: Vec<u32>,
    pub primaries: Vec<Segment>,
    pub tr_steps: Vec<[f32; 2]>,
}

impl SegmentUpload {
    pub fn build(
        origin: Vec3,
        pass: &CameraPass,
        media: &Media,
        raster: bool,
        steps: bool,
    ) -> SegmentUpload {
        let pixels = pass.primaries.len();
        let mut out = SegmentUpload {
            segments: Vec::with_capacity(if raster { 0 } else { pixels }),
            pixel_first: Vec::with_capacity(pixels + 1),
            primaries: Vec::with_capacity(if raster { pixels } else { 0 }),
            tr_steps: Vec::new(),
        };
        let Some(bounds) = media.bounds() else {
            out.pixel_first.resize(pixels + 1, 0);
            out.primaries
                .resize(if raster { pixels } else { 0 }, Segment::default());
            return out;
        };
        let mut next = pass.secondary.iter().peekable();
        // Seeds: a primary's is its pixel, a later segment's the pixel count plus its rank.
        let mut seed = pixels as u32;
        let tr = |t| steps.then_some(t);
        for (pixel, p) in pass.primaries.iter().enumerate() {
            out.pixel_first.push(out.segments.len() as u32);
            let ray = Ray::new(origin, p.dir);
            let primary = out.segment(&bounds, ray, p.t_surf, Vec3::ONE, tr(&p.tr), pixel as u32);
            match (raster, primary) {
                (true, s) => out.primaries.push(s.unwrap_or_default()),
                (false, Some(s)) => out.segments.push(s),
                (false, None) => {}
            }
            while let Some(s) = next.next_if(|s| s.pixel as usize == pixel) {
                if let Some(seg) = out.segment(&bounds, s.ray, s.t_surf, s.beta, tr(&s.tr), seed) {
                    out.segments.push(seg);
                }
                seed += 1;
            }
        }
        out.pixel_first.push(out.segments.len() as u32);
        out
    }

    /// The segment [0, t_surf) of `ray`, ended where it leaves the media's bounds or,
    /// with steps, where they fall to 0 for good (beyond, sigma_s or the transmittance and
    /// so every term is 0; an infinite end also upsets some shader
    /// compilers: lavapipe dropped crossings on segments ending at f32::MAX), with its
    /// transmittance steps (if given) appended. None for a segment that misses the bounds:
    /// it carries no beam radiance.
    fn segment(
        &mut self,
        b: &[Vec3; 2],
        ray: Ray,
        t_surf: f32,
        beta: Vec3,
        tr: Option<&SegmentTr>,
        seed: u32,
    ) -> Option<Segment> {
        // With the steps, as on the CPU: nothing past where the estimate is 0.
        let t_end = tr.map_or(t_surf, |tr| tr.seen_until(t_surf));
        let t1 = beam_reach(Some(b), &ray, t_end)?;
        let tr_first = self.tr_steps.len() as u32;
        if let Some(tr) = tr {
            tr.steps(&mut self.tr_steps);
        }
        Some(Segment {
            origin: ray.o.into(),
            t0: 0.0,
            dir: ray.d.into(),
            t1,
            beta: beta.into(),
            tr_first,
            tr_count: self.tr_steps.len() as u32 - tr_first,
            seed,
            _pad: [0; 2],
        })
    }
}
/// Where each grid's octree starts in the concatenated node buffer, each grid's global
/// majorant (Woodcock) and the mode; `Octrees` in `freepath.wgsl`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
pub struct Octrees {
    pub roots: [[u32; 4]; 2],
    pub majorants: [[f32; 4]; 2],
    /// 0: adaptive (the octree's leaves), 1: Woodcock.
    pub mode: u32,
    pub _pad: [u32; 3],
}

pub(crate) fn kernel_word(kernel: BeamKernel) -> u32 {
    match kernel {
        BeamKernel::Line => 0,
        BeamKernel::Tube => 1,
    }
}

pub(crate) fn mode_word(mode: Mode) -> u32 {
    match mode {
        Mode::Adaptive => 0,
        Mode::Woodcock => 1,
    }
}

/// Every grid's octree nodes, concatenated (children indices stay relative to their
/// grid's root, which `Octrees::roots` locates), and the [`Octrees`] block (mode 0).
pub fn octree_upload(media: &Media) -> Result<(Octrees, Vec<Node>)> {
    if media.grids.len() > MAX_GRIDS {
        return Err(Error::Other(format!(
            "the GPU handles up to {MAX_GRIDS} grids; this scene has {}",
            media.grids.len()
        )));
    }
    let mut o = Octrees::default();
    let mut nodes = Vec::new();
    for (i, g) in media.grids.iter().enumerate() {
        o.roots[i / 4][i % 4] = u32::try_from(nodes.len())
            .map_err(|_| Error::Other("octrees too large for the GPU".into()))?;
        o.majorants[i / 4][i % 4] = g.majorant();
        nodes.extend_from_slice(&g.octree().nodes);
    }
    if nodes.is_empty() {
        // A binding may not be empty.
        nodes.push(Node::default());
    }
    Ok((o, nodes))
}
