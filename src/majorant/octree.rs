//! The majorant octree of one density-grid medium (Yue et al. 2010, 2011).
//!
//! Each node stores a conservative majorant and minorant of sigma_t over everything the
//! trilinear lookup can return inside its box. Which nodes become leaves is decided by a
//! cost model of tracking work, solved exactly over a full pyramid of depth `max_depth`:
//! a ray crossing a leaf pays one traversal step plus the expected number of tentative
//! collisions, majorant x mean chord (4V/S for a box); a split node pays the sum over its
//! children of (probability a ray through the parent crosses the child = S_child / S_parent)
//! x the child's best cost. Bottom-up dynamic programming picks, for every node, the
//! cheaper of the two; the result minimises expected lookups per ray crossing the root
//! under that model, within the depth limit.
use bytemuck::{Pod, Zeroable};
use glam::{DVec3, IVec3, Vec3};
use rayon::prelude::*;

use crate::geometry::Ray;
use crate::media::homogeneous::ray_box;
use crate::media::GridMedium;

/// Default pyramid depth: 64^3 finest cells.
pub const DEFAULT_MAX_DEPTH: u32 = 6;
/// Work of one traversal step, in units of one density lookup.
pub const STEP_COST: f32 = 1.0;

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
}

/// Per-cell (majorant, minorant) of the finest level, x fastest.
struct Pyramid {
    levels: Vec<Vec<(f32, f32)>>,
}

impl Octree {
    /// Bakes the octree of `g` over its world bounds.
    pub fn build(g: &GridMedium, max_depth: u32) -> Octree {
        let depth = max_depth.clamp(0, 8);
        let pyramid = Pyramid::build(g, depth);
        let [lo, hi] = g.bounds;
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
        Octree { nodes }
    }

    pub fn root(&self) -> &Node {
        &self.nodes[0]
    }

    pub fn leaf_count(&self) -> usize {
        self.nodes.iter().filter(|n| n.first_child == 0).count()
    }

    /// Visits the leaves the ray crosses in [0, tmax], front to back, with their parametric
    /// span; stops when `f` returns false. Leaf marching: find the leaf holding the point
    /// just past the current distance by descending from the root (three comparisons per
    /// level), use its exit distance as the next start.
    pub fn walk(&self, ray: &Ray, tmax: f32, mut f: impl FnMut(&Node, f32, f32) -> bool) {
        let inv = ray.d.recip();
        let root = self.root();
        let Some((t0, t1)) = slab(ray, inv, root, 0.0, tmax) else {
            return;
        };
        let size = (Vec3::from(root.max) - Vec3::from(root.min)).max_element();
        let nudge = size * 1e-6;
        let (lo, hi) = (Vec3::from(root.min), Vec3::from(root.max));
        let mut t = t0;
        while t < t1 {
            let p = ray.at(t + nudge).clamp(lo, hi);
            let leaf = self.leaf_containing(p);
            let a = (Vec3::from(leaf.min) - ray.o) * inv;
            let b = (Vec3::from(leaf.max) - ray.o) * inv;
            let exit = a.max(b).min_element().max(t + nudge).min(t1);
            if !f(leaf, t, exit) {
                return;
            }
            t = exit;
        }
    }

    /// The leaf whose box holds `p` (a point inside the root box).
    fn leaf_containing(&self, p: Vec3) -> &Node {
        let mut n = &self.nodes[0];
        while n.first_child != 0 {
            let c = 0.5 * (Vec3::from(n.min) + Vec3::from(n.max));
            let o = (p.x >= c.x) as u32 | ((p.y >= c.y) as u32) << 1 | ((p.z >= c.z) as u32) << 2;
            n = &self.nodes[(n.first_child + o) as usize];
        }
        n
    }
}

fn slab(ray: &Ray, inv: Vec3, n: &Node, t0: f32, t1: f32) -> Option<(f32, f32)> {
    let a = (Vec3::from(n.min) - ray.o) * inv;
    let b = (Vec3::from(n.max) - ray.o) * inv;
    let near = a.min(b).max_element().max(t0);
    let far = a.max(b).min_element().min(t1);
    (near < far).then_some((near, far))
}

fn cell_index(res: i32, c: IVec3) -> usize {
    ((c.z * res + c.y) * res + c.x) as usize
}

impl Pyramid {
    /// Finest level from the grid's voxels: a cell's bounds cover every voxel whose
    /// trilinear support (one voxel around it) reaches into the cell.
    fn build(g: &GridMedium, depth: u32) -> Pyramid {
        let res = 1i32 << depth;
        let [lo, hi] = g.bounds;
        let cell = (hi - lo) / res as f32;
        let fine: Vec<(f32, f32)> = (0..res * res * res)
            .into_par_iter()
            .map(|i| {
                let c = IVec3::new(i % res, (i / res) % res, i / (res * res));
                let cmin = lo + cell * c.as_vec3();
                cell_bounds(g, cmin, cmin + cell)
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
                    let leaf = STEP_COST + self.levels[d][i as usize].0 * chord;
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
    let leaf_cost = STEP_COST + maj * chord;
    let split = d < depth as usize && best[d][cell_index(r, c)] < leaf_cost;
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

/// (majorant, minorant) of sigma_t over the world box [cmin, cmax].
fn cell_bounds(g: &GridMedium, cmin: Vec3, cmax: Vec3) -> (f32, f32) {
    let mut ilo = DVec3::splat(f64::MAX);
    let mut ihi = DVec3::splat(f64::MIN);
    for k in 0..8 {
        let w = Vec3::new(
            if k & 1 == 0 { cmin.x } else { cmax.x },
            if k & 2 == 0 { cmin.y } else { cmax.y },
            if k & 4 == 0 { cmin.z } else { cmax.z },
        );
        let i = g.world_to_index.transform_point3(w.as_dvec3());
        ilo = ilo.min(i);
        ihi = ihi.max(i);
    }
    // Trilinear values at any point come from the 8 voxels around it.
    let a = ilo.floor().as_ivec3();
    let b = ihi.floor().as_ivec3() + 1;
    let (mut max, mut min) = (0.0f32, f32::MAX);
    for z in a.z..=b.z {
        for y in a.y..=b.y {
            for x in a.x..=b.x {
                let v = g.grid.value(IVec3::new(x, y, z)).max(0.0);
                max = max.max(v);
                min = min.min(v);
            }
        }
    }
    (max * g.density_scale, min * g.density_scale)
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
mod tests {
    use super::*;
    use crate::media::procedural::{build, NoiseParams, Preset};
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
        GridMedium::new(
            Arc::new(grid),
            xf,
            10.0,
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

    /// The walk visits leaves in order, contiguously, covering the ray's span of the root.
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
            t.walk(&ray, 100.0, |_, s0, s1| {
                assert!((s0 - last).abs() < 1e-4, "gap {last} -> {s0}");
                assert!(s1 >= s0);
                last = s1;
                true
            });
            assert!((last - b).abs() < 1e-4);
        }
    }
}
