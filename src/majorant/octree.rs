//! The majorant octree of one density-grid medium (Yue et al. 2010, 2011).
//!
//! Each node stores a conservative majorant and minorant of sigma_t over everything the
//! trilinear lookup can return inside its box. Which nodes become leaves is decided by a
//! cost model of tracking work, solved exactly over a full pyramid of depth `max_depth`:
//! a ray crossing a leaf pays one traversal step plus its expected tentative collisions,
//! majorant x mean chord (4V/S for a box): those drawn below the minorant are decided
//! without a lookup and cost [`TENTATIVE_COST`], the others one lookup; a split node pays
//! the sum over its children of (probability a ray through the parent crosses the child =
//! S_child / S_parent) x the child's best cost. Bottom-up dynamic programming picks, for every node, the
//! cheaper of the two; the result minimises expected lookups per ray crossing the root
//! under that model, within the depth limit.
use bytemuck::{Pod, Zeroable};
use glam::{DVec3, IVec3, UVec3, Vec3};
use rayon::prelude::*;

use super::Field;
use crate::core::{ray_box, slab, Ray};

/// Deepest pyramid a build uses unless asked for less: 256^3 finest cells, which the
/// memory budget allows. A grid's own depth is lower when its voxels are fewer, see
/// [`depth_for`].
pub const DEFAULT_MAX_DEPTH: u32 = 8;
/// Memory the build's pyramid may take: per finest cell a (majorant, minorant) pair and a
/// cost, 12 bytes, plus 1/7 for the coarser levels.
pub const PYRAMID_BUDGET_BYTES: u64 = 256 << 20;
/// Work of one traversal step, in units of one density lookup. `ppb bench` (3 runs each,
/// 2 cores) on the dense smoke, smoke-grid, cloud-hg and the size cloud at 64^3 to 1024^3
/// put 0.25, 0.5 and 1 within their run-to-run spread in free-path time on the conformance
/// scenes; 0.5 was ahead on 4 of 5 sizes of the cloud and does 1.3-1.6x fewer lookups
/// (a machine-independent count) than 1.
pub const STEP_COST: f32 = 0.5;
/// Work of a tentative collision decided by the minorant (a random number and a
/// logarithm, no lookup), in lookups.
pub const TENTATIVE_COST: f32 = 0.15;

/// The pyramid depth for `g`: finest cells about one voxel wide, so the cost model can
/// split down to single voxels where the field varies, capped by `max_depth` and by
/// [`PYRAMID_BUDGET_BYTES`]. A 64^3 grid gets 6, a 1024^3 one 8 (4 voxels per cell).
pub fn depth_for(g: &impl Field, max_depth: u32) -> u32 {
    let [lo, hi] = g.bounds();
    let (ilo, ihi) = index_box(g, lo, hi);
    let voxels = (ihi - ilo).max_element().max(1.0);
    let data = voxels.log2().ceil() as u32;
    let per_cell = 12.0 * 8.0 / 7.0;
    let budget = ((PYRAMID_BUDGET_BYTES as f64 / per_cell).log2() / 3.0).floor() as u32;
    data.min(budget).min(max_depth)
}

/// Expected work of a ray crossing a leaf with these bounds along a mean chord.
fn leaf_cost((majorant, minorant): (f32, f32), chord: f32) -> f32 {
    let minorant = if minorant == f32::MAX { 0.0 } else { minorant };
    STEP_COST + chord * (majorant - (1.0 - TENTATIVE_COST) * minorant)
}

/// One octree node; children are 8 consecutive nodes in octant order (bit 0: +x half,
/// bit 1: +y, bit 2: +z). Also the on-disk layout of the cache.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct Node {
    pub min: [f32; 3],
    /// Bound above sigma_t in the box (1/m).
    pub majorant: f32,
    pub max: [f32; 3],
    /// Bound below sigma_t in the box (1/m).
    pub minorant: f32,
    /// Index of the first child, 0 for a leaf.
    pub first_child: u32,
    pub depth: u32,
    pub _pad: [u32; 2],
}

#[derive(Clone, Debug, PartialEq)]
pub struct Octree {
    pub nodes: Vec<Node>,
    /// Point location in one read instead of a descent from the root; derived from
    /// `nodes` when the tree is made or loaded, never stored.
    index: CellIndex,
}

/// What the walk hands out per leaf: the bounds tracking uses there.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LeafBounds {
    pub majorant: f32,
    pub minorant: f32,
}

/// Deepest level the point-location table resolves (64^3 cells, 1 MiB of u32).
const INDEX_MAX_LEVEL: u32 = 6;
/// Table entry bits: a node to descend from (tree deeper than the table) ...
const DEEP: u32 = 1 << 31;
/// ... else the leaf's depth above a leaf number.
const DEPTH_SHIFT: u32 = 27;
const INDEX_MASK: u32 = (1 << DEPTH_SHIFT) - 1;

/// Point location for the walk, derived from the nodes when a tree is made or loaded and
/// never stored. A uniform grid of cells over the root at the leaves' deepest level (at
/// most [`INDEX_MAX_LEVEL`]) names each cell's leaf and depth; the leaf's bounds sit in a
/// compact array and its box follows from the cell and depth: two small reads per leaf
/// instead of a chain of dependent node reads from the root.
#[derive(Clone, Debug, PartialEq)]
struct CellIndex {
    level: u32,
    res: u32,
    lo: Vec3,
    /// Cells per metre along each axis.
    scale: Vec3,
    /// Box size of a node at each depth up to `level`.
    sizes: Vec<Vec3>,
    cells: Vec<u32>,
    leaves: Vec<LeafBounds>,
}

/// Per-cell (majorant, minorant) of the finest level, x fastest.
struct Pyramid {
    levels: Vec<Vec<(f32, f32)>>,
}

impl Octree {
    /// Bakes the octree of `g` over its world bounds.
    pub fn build(g: &impl Field, max_depth: u32) -> Octree {
        let depth = depth_for(g, max_depth);
        let pyramid = Pyramid::build(g, depth);
        let [lo, hi] = g.bounds();
        let mut nodes = vec![Node::default()];
        let best = pyramid.best_costs(lo, hi);
        emit(
            &pyramid,
            &best,
            &mut nodes,
            0,
            depth,
            IVec3::ZERO,
            0,
            lo,
            hi,
        );
        Octree::from_nodes(nodes)
    }

    /// The tree over `nodes` (root first, children after their parent, as [`build`]
    /// emits them and the cache stores them).
    ///
    /// [`build`]: Octree::build
    pub fn from_nodes(nodes: Vec<Node>) -> Octree {
        let index = CellIndex::new(&nodes);
        Octree { nodes, index }
    }

    pub fn root(&self) -> &Node {
        &self.nodes[0]
    }

    /// The deepest level of any node (0: the root alone).
    pub fn depth(&self) -> u32 {
        self.nodes.iter().map(|n| n.depth).max().unwrap_or(0)
    }

    pub fn leaf_count(&self) -> usize {
        self.nodes.iter().filter(|n| n.first_child == 0).count()
    }

    /// Visits the leaves the ray crosses in [0, tmax], front to back, with their parametric
    /// span; stops when `f` returns false. Leaf marching: locate the leaf holding the point
    /// just past the current distance (one table read, see [`CellIndex`]), use its exit
    /// distance as the next start.
    pub fn walk(&self, ray: &Ray, tmax: f32, mut f: impl FnMut(LeafBounds, f32, f32) -> bool) {
        let inv = ray.inv_d();
        let root = self.root();
        let (lo, hi) = (Vec3::from(root.min), Vec3::from(root.max));
        let Some((t0, t1)) = slab(ray.o, inv, lo, hi, 0.0, tmax) else {
            return;
        };
        let size_nudge = (hi - lo).max_element() * 1e-6;
        // Far from the root, a box-relative step is lost in float32 rounding of t and of
        // the point; it must also exceed a few ulps of both, or the walk stops advancing.
        let far = ray
            .o
            .abs()
            .max_element()
            .max(lo.abs().max_element())
            .max(hi.abs().max_element());
        let mut t = t0;
        while t < t1 {
            let nudge = size_nudge.max((t.abs() + far) * 16.0 * f32::EPSILON);
            let p = ray.at(t + nudge).clamp(lo, hi);
            let (bounds, bmin, bmax) = self.locate(p);
            let a = (bmin - ray.o) * inv;
            let b = (bmax - ray.o) * inv;
            let exit = a.max(b).min_element().max(t + nudge).min(t1);
            if !f(bounds, t, exit) {
                return;
            }
            t = exit;
        }
    }

    /// The bounds and box of the leaf holding `p` (a point inside the root box). A point
    /// that rounding puts on the far side of a table cell's face is located again by a
    /// descent from the root.
    #[inline(always)]
    fn locate(&self, p: Vec3) -> (LeafBounds, Vec3, Vec3) {
        let ix = &self.index;
        let c = ((p - ix.lo) * ix.scale)
            .max(Vec3::ZERO)
            .as_uvec3()
            .min(UVec3::splat(ix.res - 1));
        let e = ix.cells[((c.z * ix.res + c.y) * ix.res + c.x) as usize];
        let found = if e & DEEP != 0 {
            node_leaf(self.descend(&self.nodes[(e & !DEEP) as usize], p))
        } else {
            let depth = e >> DEPTH_SHIFT;
            let size = ix.sizes[depth as usize];
            let min = ix.lo + size * (c >> (ix.level - depth)).as_vec3();
            (ix.leaves[(e & INDEX_MASK) as usize], min, min + size)
        };
        if p.cmpge(found.1).all() && p.cmple(found.2).all() {
            found
        } else {
            node_leaf(self.leaf_containing(p))
        }
    }

    /// The leaf whose box holds `p`, by descent from the root.
    fn leaf_containing(&self, p: Vec3) -> &Node {
        self.descend(&self.nodes[0], p)
    }

    /// From node `n` down to the leaf on `p`'s side of every split.
    fn descend<'a>(&'a self, mut n: &'a Node, p: Vec3) -> &'a Node {
        while n.first_child != 0 {
            let c = 0.5 * (Vec3::from(n.min) + Vec3::from(n.max));
            let o = (p.x >= c.x) as u32 | ((p.y >= c.y) as u32) << 1 | ((p.z >= c.z) as u32) << 2;
            n = &self.nodes[(n.first_child + o) as usize];
        }
        n
    }
}

impl CellIndex {
    fn new(nodes: &[Node]) -> CellIndex {
        let root = &nodes[0];
        let deepest = nodes.iter().map(|n| n.depth).max().unwrap_or(0);
        let level = deepest.min(INDEX_MAX_LEVEL);
        let res = 1u32 << level;
        let (lo, hi) = (Vec3::from(root.min), Vec3::from(root.max));
        let extent = (hi - lo).max(Vec3::splat(f32::MIN_POSITIVE));
        let mut ix = CellIndex {
            level,
            res,
            lo,
            scale: res as f32 / extent,
            sizes: (0..=level).map(|d| extent / (1u32 << d) as f32).collect(),
            cells: vec![0; (res * res * res) as usize],
            leaves: Vec::new(),
        };
        ix.fill(nodes, 0, 0, UVec3::ZERO);
        ix
    }

    /// Writes node `i` (at depth `d`, cell `c` of its level) into every table cell it
    /// covers, or recurses into its children above the table's level.
    fn fill(&mut self, nodes: &[Node], i: u32, d: u32, c: UVec3) {
        let n = &nodes[i as usize];
        if n.first_child != 0 && d < self.level {
            for o in 0..8u32 {
                let cc = c * 2 + UVec3::new(o & 1, (o >> 1) & 1, o >> 2);
                self.fill(nodes, n.first_child + o, d + 1, cc);
            }
            return;
        }
        let entry = if n.first_child != 0 {
            DEEP | i
        } else {
            self.leaves.push(LeafBounds {
                majorant: n.majorant,
                minorant: n.minorant,
            });
            (d << DEPTH_SHIFT) | (self.leaves.len() as u32 - 1)
        };
        let span = 1u32 << (self.level - d);
        let base = c * span;
        for z in base.z..base.z + span {
            for y in base.y..base.y + span {
                let row = ((z * self.res + y) * self.res) as usize;
                self.cells[row + base.x as usize..row + (base.x + span) as usize].fill(entry);
            }
        }
    }
}

/// A node's bounds and box.
fn node_leaf(n: &Node) -> (LeafBounds, Vec3, Vec3) {
    let bounds = LeafBounds {
        majorant: n.majorant,
        minorant: n.minorant,
    };
    (bounds, Vec3::from(n.min), Vec3::from(n.max))
}

fn cell_index(res: i32, c: IVec3) -> usize {
    ((c.z * res + c.y) * res + c.x) as usize
}

impl Pyramid {
    /// Finest level from the grid's voxels: a cell's bounds cover every voxel whose
    /// trilinear support (one voxel around it) reaches into the cell.
    fn build(g: &impl Field, depth: u32) -> Pyramid {
        let res = 1i32 << depth;
        let [lo, hi] = g.bounds();
        let cell = (hi - lo) / res as f32;
        let aligned = axis_aligned(g);
        let fine: Vec<(f32, f32)> = (0..res * res * res)
            .into_par_iter()
            .map_init(Scratch::default, |scratch, i| {
                let c = IVec3::new(i % res, (i / res) % res, i / (res * res));
                let cmin = lo + cell * c.as_vec3();
                cell_bounds(g, aligned, cmin, cmin + cell, scratch)
            })
            .collect();
        let mut levels = vec![fine];
        for d in (0..depth).rev() {
            let r = 1i32 << d;
            let below = levels.last().expect("finest level");
            let mut up = vec![(0.0f32, f32::MAX); (r * r * r) as usize];
            for z in 0..r {
                for y in 0..r {
                    for x in 0..r {
                        let mut m = (0.0f32, f32::MAX);
                        for o in 0..8 {
                            let c =
                                IVec3::new(x, y, z) * 2 + IVec3::new(o & 1, (o >> 1) & 1, o >> 2);
                            let v = below[cell_index(r * 2, c)];
                            m = (m.0.max(v.0), m.1.min(v.1));
                        }
                        up[cell_index(r, IVec3::new(x, y, z))] = m;
                    }
                }
            }
            levels.push(up);
        }
        levels.reverse();
        Pyramid { levels }
    }

    /// Best expected cost of every pyramid cell (same layout as `levels`).
    fn best_costs(&self, lo: Vec3, hi: Vec3) -> Vec<Vec<f32>> {
        let depth = self.levels.len() - 1;
        let mut best: Vec<Vec<f32>> = vec![Vec::new(); depth + 1];
        for d in (0..=depth).rev() {
            let r = 1i32 << d;
            let size = (hi - lo) / r as f32;
            let chord = 4.0 * size.x * size.y * size.z / surface(size);
            best[d] = (0..r * r * r)
                .map(|i| {
                    let leaf = leaf_cost(self.levels[d][i as usize], chord);
                    if d == depth {
                        return leaf;
                    }
                    let c = IVec3::new(i % r, (i / r) % r, i / (r * r));
                    let p = surface(size * 0.5) / surface(size);
                    let split: f32 = (0..8)
                        .map(|o| {
                            let cc = c * 2 + IVec3::new(o & 1, (o >> 1) & 1, o >> 2);
                            best[d + 1][cell_index(r * 2, cc)]
                        })
                        .sum::<f32>()
                        * p;
                    leaf.min(split)
                })
                .collect();
        }
        best
    }
}

fn surface(s: Vec3) -> f32 {
    2.0 * (s.x * s.y + s.y * s.z + s.z * s.x)
}

#[allow(clippy::too_many_arguments)]
fn emit(
    p: &Pyramid,
    best: &[Vec<f32>],
    nodes: &mut Vec<Node>,
    idx: usize,
    depth: u32,
    c: IVec3,
    d: usize,
    lo: Vec3,
    hi: Vec3,
) {
    let r = 1i32 << d;
    let size = (hi - lo) / r as f32;
    let min = lo + size * c.as_vec3();
    let (maj, mino) = p.levels[d][cell_index(r, c)];
    let chord = 4.0 * size.x * size.y * size.z / surface(size);
    let split = d < depth as usize && best[d][cell_index(r, c)] < leaf_cost((maj, mino), chord);
    let first = if split { nodes.len() as u32 } else { 0 };
    nodes[idx] = Node {
        min: min.into(),
        majorant: maj,
        max: (min + size).into(),
        minorant: if mino == f32::MAX { 0.0 } else { mino },
        first_child: first,
        depth: d as u32,
        _pad: [0; 2],
    };
    if split {
        nodes.resize(nodes.len() + 8, Node::default());
        for o in 0..8 {
            let cc = c * 2 + IVec3::new(o & 1, (o >> 1) & 1, o >> 2);
            emit(
                p,
                best,
                nodes,
                first as usize + o as usize,
                depth,
                cc,
                d + 1,
                lo,
                hi,
            );
        }
    }
}

/// Cells at most this many voxels wide get exact bounds (see [`exact_range`]).
const EXACT_MAX_VOXELS: f64 = 4.0;

/// (majorant, minorant) of sigma_t over the world box [cmin, cmax], from the voxels whose
/// trilinear support reaches into it (read as one block, see `Grid::fill_block`); exact
/// for small cells of an axis-aligned grid (`aligned`: [`axis_aligned`] of `g`, worked out
/// once per build).
fn cell_bounds(
    g: &impl Field,
    aligned: bool,
    cmin: Vec3,
    cmax: Vec3,
    scratch: &mut Scratch,
) -> (f32, f32) {
    let Scratch { block, lerps } = scratch;
    let (ilo, ihi) = index_box(g, cmin, cmax);
    // Trilinear values at any point come from the 8 voxels around it.
    let a = ilo.floor().as_ivec3();
    let b = ihi.floor().as_ivec3() + 1;
    let s = g.density_scale();
    if !g.fill_block(a, b, block) {
        let v = g.background().max(0.0) * s;
        return (v, v);
    }
    // Tile interiors: a constant field.
    if block.iter().all(|&v| v == block[0]) {
        let v = block[0].max(0.0) * s;
        return (v, v);
    }
    if aligned && (ihi - ilo).max_element() <= EXACT_MAX_VOXELS {
        let origin = a.as_dvec3();
        let (max, min) = exact_range(block, b - a + 1, ilo - origin, ihi - origin, lerps);
        // A relative margin of 1e-5 covers the lookup's float rounding.
        return (max * s * (1.0 + 1e-5), min * s * (1.0 - 1e-5));
    }
    let (max, min) = block.iter().fold((0.0f32, f32::MAX), |(hi, lo), &v| {
        let v = v.max(0.0);
        (hi.max(v), lo.min(v))
    });
    (max * s, min * s)
}

/// Reused buffers of [`cell_bounds`], one per worker.
#[derive(Default)]
struct Scratch {
    block: Vec<f32>,
    lerps: Vec<f32>,
}

/// Index-space bounding box of a world box.
pub(super) fn index_box(g: &impl Field, cmin: Vec3, cmax: Vec3) -> (DVec3, DVec3) {
    let mut ilo = DVec3::splat(f64::MAX);
    let mut ihi = DVec3::splat(f64::MIN);
    for k in 0..8 {
        let w = Vec3::new(
            if k & 1 == 0 { cmin.x } else { cmax.x },
            if k & 2 == 0 { cmin.y } else { cmax.y },
            if k & 4 == 0 { cmin.z } else { cmax.z },
        );
        let i = g.world_to_index().transform_point3(w.as_dvec3());
        ilo = ilo.min(i);
        ihi = ihi.max(i);
    }
    (ilo, ihi)
}

/// Whether index space is world space scaled and shifted per axis (no rotation or shear).
fn axis_aligned(g: &impl Field) -> bool {
    let m = g.world_to_index().matrix3;
    let off_diagonal = [
        m.x_axis.y, m.x_axis.z, m.y_axis.x, m.y_axis.z, m.z_axis.x, m.z_axis.y,
    ];
    off_diagonal.iter().all(|&v| v == 0.0)
}

/// Exact (max, min) of the trilinear field, clamped at 0, over the box [lo, hi] given in
/// the local index space of `block` (values of `n` voxels, x slowest). The field is
/// multilinear inside each voxel cell, so its extremes lie at the corners of the box's
/// pieces: the points whose every coordinate is a box face or a voxel-centre plane
/// inside the box. Tighter than the voxel-support bound, it lowers the majorant and
/// raises the minorant, both of which save lookups. Evaluated one axis at a time.
fn exact_range(
    block: &[f32],
    n: IVec3,
    lo: DVec3,
    hi: DVec3,
    scratch: &mut Vec<f32>,
) -> (f32, f32) {
    let (xs, ys, zs) = (
        Stops::new(lo.x, hi.x),
        Stops::new(lo.y, hi.y),
        Stops::new(lo.z, hi.z),
    );
    let (ny, nz) = (n.y as usize, n.z as usize);
    scratch.clear();
    // Along x: (x stop, voxel y, voxel z).
    for &(i, t) in xs.get() {
        for yz in 0..ny * nz {
            scratch.push(lerp_at(|x| block[x * ny * nz + yz], i, t));
        }
    }
    // Along y: (x stop, y stop, voxel z), after the x stage.
    let vx = scratch.len();
    for sx in 0..xs.len {
        for &(j, t) in ys.get() {
            for z in 0..nz {
                let v = lerp_at(|y| scratch[(sx * ny + y) * nz + z], j, t);
                scratch.push(v);
            }
        }
    }
    let (mut max, mut min) = (0.0f32, f32::MAX);
    for row in scratch[vx..].chunks(nz) {
        for &(k, t) in zs.get() {
            let v = lerp_at(|z| row[z], k, t).max(0.0);
            max = max.max(v);
            min = min.min(v);
        }
    }
    (max, min)
}

/// Linear interpolation between items `i` and `i + 1` at `t` (item `i` alone at 0).
fn lerp_at(at: impl Fn(usize) -> f32, i: usize, t: f32) -> f32 {
    if t == 0.0 {
        at(i)
    } else {
        at(i) + (at(i + 1) - at(i)) * t
    }
}

/// The evaluation points along one axis of a box at most [`EXACT_MAX_VOXELS`] wide: its
/// two faces and the voxel-centre planes between, as (voxel below, fraction).
struct Stops {
    items: [(usize, f32); EXACT_MAX_VOXELS as usize + 3],
    len: usize,
}

impl Stops {
    fn new(lo: f64, hi: f64) -> Stops {
        let mut s = Stops {
            items: [(0, 0.0); EXACT_MAX_VOXELS as usize + 3],
            len: 0,
        };
        let inner = (lo.floor() as i64 + 1..=hi.ceil() as i64 - 1).map(|k| k as f64);
        for p in std::iter::once(lo).chain(inner).chain(std::iter::once(hi)) {
            s.items[s.len] = (p.floor() as usize, (p - p.floor()) as f32);
            s.len += 1;
        }
        s
    }

    fn get(&self) -> &[(usize, f32)] {
        &self.items[..self.len]
    }
}

/// Leaf nodes whose box the ray can enter (used by tests and `ppb info`).
pub fn leaf_for_point(t: &Octree, p: Vec3) -> Option<&Node> {
    let mut n = t.root();
    let inside = |n: &Node| p.cmpge(Vec3::from(n.min)).all() && p.cmple(Vec3::from(n.max)).all();
    if !inside(n) {
        return None;
    }
    while n.first_child != 0 {
        n = (0..8)
            .map(|o| &t.nodes[(n.first_child + o) as usize])
            .find(|c| inside(c))?;
    }
    Some(n)
}

/// Parametric span of a ray over an octree's root box.
pub fn root_span(t: &Octree, ray: &Ray, tmax: f32) -> Option<(f32, f32)> {
    let r = t.root();
    ray_box(ray, &[Vec3::from(r.min), Vec3::from(r.max)], 0.0, tmax)
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::media::procedural::{build, NoiseParams, Preset};
    use crate::media::GridMedium;
    use crate::media::Phase;
    use crate::sampling::Rng;
    use glam::DAffine3;
    use std::sync::Arc;

    pub(crate) fn noise_medium(rotate: bool) -> GridMedium {
        let grid = build(&NoiseParams {
            preset: Preset::Smoke,
            bounds: [Vec3::new(-1.0, 0.0, -1.0), Vec3::new(1.0, 2.0, 1.0)],
            seed: 3,
            octaves: 4,
            frequency: 3.0,
            resolution: 40,
        });
        let xf = if rotate {
            DAffine3::from_rotation_y(0.5) * DAffine3::from_scale(DVec3::new(1.0, 0.7, 1.3))
        } else {
            DAffine3::IDENTITY
        };
        medium(grid, xf, 10.0)
    }

    /// A white, isotropic medium of `grid` placed by `xf`, sigma_t = `scale` x density.
    fn medium(grid: crate::media::grid::Grid, xf: DAffine3, scale: f32) -> GridMedium {
        GridMedium::new(
            Arc::new(grid),
            xf,
            scale,
            Vec3::ONE,
            Phase::ISOTROPIC,
            "noise".into(),
            [0; 32],
        )
    }

    /// Every leaf's majorant bounds (and minorant underbounds) every trilinear sample in
    /// it: 200 000 random probes, axis-aligned and rotated grids.
    #[test]
    fn leaf_bounds_hold_under_dense_probing() {
        for rotate in [false, true] {
            let g = noise_medium(rotate);
            let t = Octree::build(&g, 5);
            assert!(t.leaf_count() > 8, "the cost model split nothing");
            let mut rng = Rng::new(1, 1);
            let [lo, hi] = g.bounds;
            for _ in 0..200_000 {
                let p = lo + (hi - lo) * Vec3::new(rng.f32(), rng.f32(), rng.f32());
                let leaf = leaf_for_point(&t, p).expect("inside the root");
                let s = g.sigma_t(p);
                assert!(
                    s <= leaf.majorant * (1.0 + 1e-5) + 1e-6,
                    "{s} > {}",
                    leaf.majorant
                );
                assert!(
                    s >= leaf.minorant * (1.0 - 1e-5) - 1e-6,
                    "{s} < {}",
                    leaf.minorant
                );
            }
        }
    }

    /// Brute force: the trilinear lookup at every corner of the box's pieces.
    fn corner_extremes(g: &GridMedium, a: Vec3, b: Vec3) -> (f32, f32) {
        let (lo, hi) = index_box(g, a, b);
        let planes = |lo: f64, hi: f64| -> Vec<f64> {
            let mut v = vec![lo, hi];
            v.extend((lo.floor() as i64 + 1..=hi.ceil() as i64 - 1).map(|k| k as f64));
            v
        };
        let (mut max, mut min) = (0.0f32, f32::MAX);
        for &z in &planes(lo.z, hi.z) {
            for &y in &planes(lo.y, hi.y) {
                for &x in &planes(lo.x, hi.x) {
                    let v = g.grid.sample_index(DVec3::new(x, y, z)).max(0.0) * g.density_scale;
                    (max, min) = (max.max(v), min.min(v));
                }
            }
        }
        (max, min)
    }

    /// On small cells of an axis-aligned grid the bounds are the field's exact extremes
    /// (the lookup at the corners of the box's pieces), and tighter than the voxel-support
    /// bound on many cells; on a rotated grid they still bound those corners.
    #[test]
    fn small_cells_get_exact_bounds() {
        let mut scratch = Scratch::default();
        for rotate in [false, true] {
            let g = noise_medium(rotate);
            let [lo, hi] = g.bounds;
            let cell = (hi - lo) / 32.0;
            let mut tighter = 0;
            for i in 0..32 * 32 * 32 {
                let c = IVec3::new(i % 32, (i / 32) % 32, i / 1024).as_vec3();
                let (a, b) = (lo + cell * c, lo + cell * (c + 1.0));
                let (max, min) = cell_bounds(&g, axis_aligned(&g), a, b, &mut scratch);
                let (cmax, cmin) = corner_extremes(&g, a, b);
                let tol = 2e-5 * cmax.max(1e-3);
                assert!(
                    max >= cmax - tol && min <= cmin + tol,
                    "{max} {min} vs {cmax} {cmin}"
                );
                if !rotate {
                    assert!(
                        max <= cmax + tol && min >= cmin - tol,
                        "{max} {min} vs {cmax} {cmin}"
                    );
                    let support = scratch.block.iter().fold(0.0f32, |m, &v| m.max(v.max(0.0)));
                    tighter += (max < support * g.density_scale * 0.99) as u32;
                }
            }
            if !rotate {
                assert!(tighter > 1000, "only {tighter} cells tighter");
            }
        }
    }

    /// The walk visits leaves in order, contiguously, covering the ray's span of the root,
    /// and hands out the bounds of the leaf the tree holds there.
    #[test]
    fn walk_is_ordered_and_gapless() {
        let g = noise_medium(false);
        let t = Octree::build(&g, 5);
        let mut rng = Rng::new(2, 2);
        for _ in 0..500 {
            let o = Vec3::new(rng.f32() * 6.0 - 3.0, rng.f32() * 4.0 - 1.0, 3.0);
            let d = (Vec3::new(rng.f32() - 0.5, rng.f32() - 0.5, -1.0)).normalize();
            let ray = Ray::new(o, d);
            let Some((a, b)) = root_span(&t, &ray, 100.0) else {
                continue;
            };
            let mut last = a;
            t.walk(&ray, 100.0, |bounds, s0, s1| {
                assert!((s0 - last).abs() < 1e-4, "gap {last} -> {s0}");
                assert!(s1 >= s0);
                // The table's leaf is the tree's leaf at the span's middle.
                if s1 - s0 > 1e-3 {
                    let leaf = leaf_for_point(&t, ray.at(0.5 * (s0 + s1))).expect("inside");
                    assert_eq!(bounds.majorant, leaf.majorant);
                    assert_eq!(bounds.minorant, leaf.minorant);
                }
                last = s1;
                true
            });
            assert!((last - b).abs() < 1e-4);
        }
    }

    /// A tree deeper than the point-location table (a dense cloud at 128 voxels): the walk
    /// hands out the bounds of the leaf a descent from the root finds, through the table's
    /// entries that continue with a descent.
    #[test]
    fn walk_below_the_table_matches_the_descent() {
        let grid = build(&NoiseParams {
            preset: Preset::Cloud,
            bounds: [Vec3::new(-2.2, 0.9, -1.5), Vec3::new(2.2, 3.2, 1.5)],
            seed: 15,
            octaves: 6,
            frequency: 3.0,
            resolution: 128,
        });
        let g = medium(grid, DAffine3::IDENTITY, 3000.0);
        let t = Octree::build(&g, DEFAULT_MAX_DEPTH);
        assert!(t.depth() > INDEX_MAX_LEVEL, "depth {}", t.depth());
        let [lo, hi] = g.bounds;
        let mut rng = Rng::new(3, 3);
        for _ in 0..2000 {
            let o = Vec3::new(rng.f32() * 8.0 - 4.0, rng.f32() * 4.0, 8.0);
            let target = lo + (hi - lo) * Vec3::new(rng.f32(), rng.f32(), rng.f32());
            let ray = Ray::new(o, (target - o).normalize());
            t.walk(&ray, 100.0, |b, s0, s1| {
                if s1 - s0 > 1e-4 {
                    let leaf = leaf_for_point(&t, ray.at(0.5 * (s0 + s1))).expect("inside");
                    assert_eq!((b.majorant, b.minorant), (leaf.majorant, leaf.minorant));
                }
                true
            });
        }
    }

    /// A camera tens of box sizes away: the walk still crosses the whole box (a
    /// box-relative nudge alone vanished in float32 there and the walk never advanced).
    #[test]
    fn walk_advances_from_far_away() {
        let g = noise_medium(false);
        let t = Octree::build(&g, 6);
        for dist in [40.0f32, 400.0, 4000.0] {
            let o = Vec3::new(0.1, 1.0, dist);
            let ray = Ray::new(o, (Vec3::new(0.0, 1.0, 0.0) - o).normalize());
            let (a, b) = root_span(&t, &ray, 1e5).expect("hits the box");
            let (mut steps, mut last) = (0, a);
            t.walk(&ray, 1e5, |_, s0, s1| {
                assert!(s1 > s0 || s1 >= b, "stalled at {s0} from {dist} m");
                steps += 1;
                last = s1;
                steps < 10_000
            });
            assert!(steps < 10_000, "{steps} leaves from {dist} m");
            assert_eq!(last, b);
        }
    }
}
