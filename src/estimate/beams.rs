//! The beam map of one pass for the beam radiance estimate (eq. 2, see [`super::eq2`]).
//!
//! Beams are cut into pieces of at most [`PIECE_RADII`] radii and put in an obvhs BVH of
//! their radius-inflated boxes, so a camera segment only visits beams it can touch. The
//! pieces are `Pod` and the same for both walkers; the tree is the one its walker runs
//! fastest ([`Walker`]): the GPU estimate (`gpu::beams`) walks a binary tree's nodes
//! without a stack, the CPU gather an 8-wide tree.
use bytemuck::{Pod, Zeroable};
use glam::{Vec3, Vec3A};
use obvhs::cwbvh::{builder::build_cwbvh, CwBvh};
use obvhs::{aabb::Aabb, bvh2::builder::build_bvh2, bvh2::Bvh2, BvhBuildParams};
use std::time::Duration;

use super::eq2::{pair_term, BeamKernel, BeamPiece, Crossing};
use super::lanes::Segment;
use crate::core::simd;
use crate::core::Nested;
use crate::core::Ray;
use crate::core::Rgb;
use crate::transport::Beam;

/// Longest beam piece in the BVH, in beam radii: shorter pieces give tighter boxes but
/// more of them, and the build is single-threaded. On glass-caustic (24 passes from pass
/// 0 and from pass 400) 24 radii halved the build against 12 and left the gather's time
/// the same, 1.10-1.17x per pass; 48 made the gather slower by more than it saved.
pub const PIECE_RADII: f32 = 24.0;

/// A BVH node as the GPU walks it, without a stack: nodes are in depth-first pre-order, so
/// an inner node's first child is the next node, and `skip` is the node after its whole
/// subtree (`u32::MAX` past the end). A leaf (count > 0) holds pieces
/// `first .. first + count`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
pub struct BvhNode {
    pub min: [f32; 3],
    pub skip: u32,
    pub max: [f32; 3],
    pub first: u32,
    pub count: u32,
    pub _pad: [u32; 3],
}

impl BeamPiece {
    /// All of `beam`: s in [0, length).
    pub fn whole(beam: &Beam) -> Self {
        BeamPiece {
            origin: beam.origin,
            s0: 0.0,
            dir: beam.dir,
            s1: beam.length,
            power: beam.power,
            scale: beam.scale,
        }
    }
}

/// Which walk a beam map's tree is built for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Walker {
    /// The CPU gather alone: an 8-wide tree (obvhs's compressed wide BVH), whose node
    /// test takes a ray against 8 boxes at once. On glass-caustic its gather took about a
    /// fifth less time than the binary tree's; its build takes twice as long and runs
    /// beside the camera paths (`pass::Tracer::trace`).
    Cpu,
    /// The GPU's walk (and the CPU's, where one pass feeds both): a binary tree, whose
    /// nodes [`BeamMap::nodes`] lays out for a walk without a stack.
    Gpu,
}

/// What an estimator needs of a pass's beam BVH: the walker that reads it, and whether
/// every pass needs one (the GPU's gathered segments) or only a pass whose camera meets
/// specular surfaces (its segments after them).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MapNeed {
    pub walker: Walker,
    pub every_pass: bool,
}

impl MapNeed {
    /// The CPU estimate's: the wide tree, where the camera meets specular surfaces.
    pub const CPU: MapNeed = MapNeed {
        walker: Walker::Cpu,
        every_pass: false,
    };
    /// The binary tree for every pass: the GPU's gather, and a pass both devices estimate.
    pub const GPU_EVERY_PASS: MapNeed = MapNeed {
        walker: Walker::Gpu,
        every_pass: true,
    };
}

enum Tree {
    Binary(Bvh2),
    Wide(CwBvh),
}

impl Tree {
    fn build(boxes: &[Aabb], walker: Walker) -> Tree {
        let (params, mut t) = (BvhBuildParams::very_fast_build(), Duration::default());
        match walker {
            Walker::Gpu => Tree::Binary(build_bvh2(boxes, params, &mut t)),
            Walker::Cpu => Tree::Wide(build_cwbvh(boxes, params, &mut t)),
        }
    }

    /// Input index of the primitive at each leaf position.
    fn order(&self) -> &[u32] {
        match self {
            Tree::Binary(b) => &b.primitive_indices,
            Tree::Wide(w) => &w.primitive_indices,
        }
    }
}

pub struct BeamMap {
    /// In the tree's primitive order, so leaves index them directly.
    pieces: Vec<BeamPiece>,
    tree: Option<Tree>,
    /// The pass's beam radius; a piece's kernel reaches `radius * piece.scale`.
    radius: f32,
}

/// Appends obvhs node `n`'s subtree in pre-order; recursion depth is the tree's depth.
fn preorder(bvh: &Bvh2, n: u32, out: &mut Vec<BvhNode>) {
    let node = &bvh.nodes[n as usize];
    let me = out.len();
    let leaf = node.prim_count > 0;
    out.push(BvhNode {
        min: Vec3::from(node.aabb.min).into(),
        skip: 0,
        max: Vec3::from(node.aabb.max).into(),
        first: if leaf { node.first_index } else { 0 },
        count: node.prim_count,
        _pad: [0; 3],
    });
    if !leaf {
        preorder(bvh, node.first_index, out);
        preorder(bvh, node.first_index + 1, out);
    }
    out[me].skip = out.len() as u32;
}

impl BeamMap {
    pub fn build(beams: &[Beam], radius: f32, walker: Walker) -> Self {
        let mut pieces = Vec::with_capacity(beams.len() * 2);
        let mut boxes = Vec::with_capacity(beams.len() * 2);
        for b in beams {
            let r = radius * b.scale;
            let n = (b.length / (PIECE_RADII * r)).ceil().max(1.0) as u32;
            let step = b.length / n as f32;
            let (y, psi) = (Vec3A::from(b.origin), Vec3A::from(b.dir));
            for k in 0..n {
                // The last piece ends at the beam's length exactly (n * step may round
                // past or short of it), so the pieces partition [0, length).
                let s0 = k as f32 * step;
                let s1 = if k + 1 == n {
                    b.length
                } else {
                    (k + 1) as f32 * step
                };
                let (a, c) = (y + psi * s0, y + psi * s1);
                pieces.push(BeamPiece {
                    s0,
                    s1,
                    ..BeamPiece::whole(b)
                });
                boxes.push(Aabb::new(a.min(c) - r, a.max(c) + r));
            }
        }
        let tree = (!boxes.is_empty()).then(|| Tree::build(&boxes, walker));
        if let Some(tree) = &tree {
            pieces = tree.order().iter().map(|&i| pieces[i as usize]).collect();
        }
        BeamMap {
            pieces,
            tree,
            radius,
        }
    }

    pub fn radius(&self) -> f32 {
        self.radius
    }

    /// The pieces in the order [`Self::nodes`]' leaves index them.
    pub fn pieces(&self) -> &[BeamPiece] {
        &self.pieces
    }

    /// The BVH in the layout the GPU walks (empty when there are no beams); None for a
    /// map built for [`Walker::Cpu`].
    pub fn nodes(&self) -> Option<Vec<BvhNode>> {
        let bvh = match &self.tree {
            None => return Some(Vec::new()),
            Some(Tree::Wide(_)) => return None,
            Some(Tree::Binary(bvh)) => bvh,
        };
        let mut out = Vec::with_capacity(bvh.nodes.len());
        preorder(bvh, 0, &mut out);
        let end = out.len() as u32;
        for n in &mut out {
            if n.skip == end {
                n.skip = u32::MAX;
            }
        }
        Some(out)
    }

    /// Sum of eq. 2 (`eq2::term`, with its edge rule: the line kernel) over the beam pieces near the camera
    /// segment [t0, t1) of `ray`. `in_scatter(x, cos)` is sigma_s(x) f(cos) and `tr(t)` the
    /// camera transmittance from the ray origin to t.
    pub fn radiance(
        &self,
        ray: &Ray,
        t0: f32,
        t1: f32,
        in_scatter: impl Fn(Vec3, f32) -> Rgb,
        tr: impl Fn(f32) -> f32,
        evaluations: &mut u64,
    ) -> Rgb {
        let kernel = BeamKernel::Line;
        self.nested_radiance(ray, (t0, t1), kernel, in_scatter, tr, evaluations)
            .l
    }

    /// [`Self::radiance`] under `kernel`, with its nested half-radius difference
    /// ([`Nested`]).
    pub fn nested_radiance(
        &self,
        ray: &Ray,
        (t0, t1): (f32, f32),
        kernel: BeamKernel,
        in_scatter: impl Fn(Vec3, f32) -> Rgb,
        tr: impl Fn(f32) -> f32,
        evaluations: &mut u64,
    ) -> Nested {
        let mut sum = Nested::default();
        let Some(tree) = &self.tree else {
            return sum;
        };
        let q = obvhs::ray::Ray::new(Vec3A::from(ray.o), Vec3A::from(ray.d), t0, t1);
        let r = self.radius;
        let visit = |piece: &BeamPiece, c: &Crossing| {
            *evaluations += 1;
            let own = r * piece.scale;
            let term = pair_term(kernel, ray, (piece, c), own, &in_scatter, &tr);
            sum.add_in(term, kernel.inner_ratio());
        };
        let first = &self.pieces[0];
        let mut segment = Segment::new(simd::isa(), ray, (t0, t1), (r, kernel), first, visit);
        let pieces = &self.pieces;
        match tree {
            Tree::Binary(b) => b.ray_traverse_anyhit(q, |_, id| segment.push(&pieces[id])),
            Tree::Wide(w) => w.ray_traverse_anyhit(q, |_, id| segment.push(&pieces[id])),
        }
        segment.finish();
        sum
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::estimate::eq2::{crossing, kernel, pair, term};
    use crate::sampling::{uniform_sphere, Rng};

    /// With sigma_s f = 1 the estimate integrates the fluence along the camera segment;
    /// isotropic beams of unit power and line-length density lambda (m/m^3) have fluence
    /// lambda, so the mean per unit length must be lambda. Each trial draws a fresh beam
    /// set (the beams' own Poisson fluctuation is part of the error); bound: 5 standard
    /// errors of the trial means. Trials alternate between the two walkers' trees.
    #[test]
    fn estimate_recovers_beam_length_density() {
        recovers_beam_length_density(|_| 1.0, BeamKernel::Line);
    }

    /// The same with every third beam's kernel 2.5 times as wide (smooth beams): each
    /// kernel integrates to 1 at its own radius, so the mean is the same.
    #[test]
    fn estimate_with_wider_kernels_recovers_beam_length_density() {
        recovers_beam_length_density(|i| if i % 3 == 0 { 2.5 } else { 1.0 }, BeamKernel::Line);
    }

    /// Both with the tube kernel: its disk integrates to 1 across the beam too.
    #[test]
    fn tube_recovers_beam_length_density() {
        recovers_beam_length_density(|_| 1.0, BeamKernel::Tube);
        recovers_beam_length_density(|i| if i % 3 == 0 { 2.5 } else { 1.0 }, BeamKernel::Tube);
    }

    fn recovers_beam_length_density(scale: impl Fn(usize) -> f32, kernel: BeamKernel) {
        let mut rng = Rng::new(11, 2);
        let (n, len, trials, probes, seg) = (30_000, 0.5f32, 40, 20, 0.6f32);
        let mut means = Vec::with_capacity(trials);
        for _ in 0..trials {
            let beams: Vec<Beam> = (0..n)
                .map(|i| {
                    let c = Vec3::new(rng.f32(), rng.f32(), rng.f32()) * 2.0 - 1.0;
                    let d = uniform_sphere(rng.vec2());
                    Beam::new(c - d * (len * 0.5), d, len, Vec3::ONE).scaled(scale(i))
                })
                .collect();
            let walker = if means.len() % 2 == 0 {
                Walker::Cpu
            } else {
                Walker::Gpu
            };
            let map = BeamMap::build(&beams, 0.05, walker);
            let mut evals = 0;
            let mut sum = 0.0f64;
            // Probes stay within 0.5 of the centre, where every beam covering a point is
            // inside the [-1, 1]^3 box of beam centres.
            for _ in 0..probes {
                let o = (Vec3::new(rng.f32(), rng.f32(), rng.f32()) * 2.0 - 1.0) * 0.2;
                let d = uniform_sphere(rng.vec2());
                let ray = Ray::new(o - d * (seg * 0.5), d);
                let one = |_, _| Vec3::ONE;
                let l = map.nested_radiance(&ray, (0.0, seg), kernel, one, |_| 1.0, &mut evals);
                sum += l.l.x as f64 / seg as f64;
            }
            means.push(sum / probes as f64);
        }
        let mean = means.iter().sum::<f64>() / trials as f64;
        let var = means.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (trials - 1) as f64;
        let expect = n as f64 * len as f64 / 8.0;
        let bound = 5.0 * (var / trials as f64).sqrt();
        assert!(
            (mean - expect).abs() < bound,
            "{mean} vs {expect} +- {bound}"
        );
        assert!(bound < 0.05 * expect, "test too weak: {bound}");
    }

    /// The tube kernel over the gather's pieces: with sigma_s f = 1 and Tr = 1 a term is
    /// power * chord / (pi r^2) wherever its point falls, so the pieces' terms must sum to
    /// the whole beams' (each beam's own chord against the segment, by brute force): 300
    /// rays among 3,000 beams up to 40 radii long (cut into pieces of 24), some at 2.5
    /// times the radius, on both walkers' trees. Equal up to the sums' rounding.
    #[test]
    fn tube_pieces_sum_to_the_whole_beams() {
        let mut rng = Rng::new(17, 5);
        let r = 0.05;
        let beams: Vec<Beam> = (0..3000)
            .map(|i| {
                let c = Vec3::new(rng.f32(), rng.f32(), rng.f32()) * 2.0 - 1.0;
                let d = uniform_sphere(rng.vec2());
                let len = 40.0 * r * rng.f32();
                let scale = if i % 3 == 0 { 2.5 } else { 1.0 };
                Beam::new(c - d * (len * 0.5), d, len, Vec3::ONE).scaled(scale)
            })
            .collect();
        let maps = [Walker::Cpu, Walker::Gpu].map(|w| BeamMap::build(&beams, r, w));
        let one = |_, _| Vec3::ONE;
        let (mut total, mut pieces) = (0.0f64, 0u64);
        for _ in 0..300 {
            let o = (Vec3::new(rng.f32(), rng.f32(), rng.f32()) * 2.0 - 1.0) * 0.3;
            let d = uniform_sphere(rng.vec2());
            let ray = Ray::new(o - d * 0.5, d);
            let span = (0.0, 1.0);
            let whole: f64 = beams
                .iter()
                .map(|b| {
                    let p = BeamPiece::whole(b);
                    let own = r * b.scale;
                    let lines = (ray.o.into(), ray.d.into(), p.origin, p.dir);
                    let (counts, c) = pair(BeamKernel::Tube, lines, span, (p.s0, p.s1), own);
                    if !counts {
                        return 0.0;
                    }
                    let term = pair_term(BeamKernel::Tube, &ray, (&p, &c), own, one, |_| 1.0);
                    term.0.x as f64
                })
                .sum();
            for map in &maps {
                let mut evals = 0;
                let got =
                    map.nested_radiance(&ray, span, BeamKernel::Tube, one, |_| 1.0, &mut evals);
                pieces += evals;
                assert!(
                    (got.l.x as f64 - whole).abs() <= 1e-4 * whole.max(1.0),
                    "{} vs {whole}",
                    got.l.x
                );
            }
            total += whole;
        }
        assert!(total > 1000.0 && pieces > 3000, "{total} {pieces}");
    }

    /// The BVH query finds exactly the crossings a brute-force loop over all beams finds,
    /// each beam at its own radius (every third one 2.5 times as wide), over either
    /// walker's tree.
    #[test]
    fn bvh_matches_brute_force() {
        let mut rng = Rng::new(11, 2);
        let beams: Vec<Beam> = (0..20000)
            .map(|i| {
                let c = Vec3::new(rng.f32(), rng.f32(), rng.f32()) * 2.0 - 1.0;
                let d = uniform_sphere(rng.vec2());
                let scale = if i % 3 == 0 { 2.5 } else { 1.0 };
                Beam::new(c - d * 0.25, d, 0.5, Vec3::ONE).scaled(scale)
            })
            .collect();
        let r = 0.05;
        let maps = [Walker::Cpu, Walker::Gpu].map(|w| BeamMap::build(&beams, r, w));
        let (mut e, mut brute) = ([0; 2], 0);
        for _ in 0..50 {
            let o = (Vec3::new(rng.f32(), rng.f32(), rng.f32()) * 2.0 - 1.0) * 0.2;
            let d = uniform_sphere(rng.vec2());
            let ray = Ray::new(o, d);
            let mut a = [0.0; 2];
            for (k, map) in maps.iter().enumerate() {
                a[k] = map
                    .radiance(&ray, 0.0, 0.6, |_, _| Vec3::ONE, |_| 1.0, &mut e[k])
                    .x;
            }
            let mut b = 0.0;
            for bm in &beams {
                let r = r * bm.scale;
                if let Some(c) = crossing(o, d, Vec3::from(bm.origin), Vec3::from(bm.dir)) {
                    if c.dist2 < r * r && c.t >= 0.0 && c.t < 0.6 && c.s >= 0.0 && c.s < bm.length {
                        b += kernel(c.dist2, r) / c.sin2.sqrt();
                        brute += 1;
                    }
                }
            }
            for a in a {
                assert!((a - b).abs() < 1e-3 * b.max(1.0), "{a} vs {b}");
            }
        }
        assert_eq!(e, [brute; 2], "evaluations");
    }

    /// Each beam's pieces partition [0, length) exactly: the first starts at 0, each starts
    /// where the previous ends, and the last ends at the length (lengths here are chosen
    /// among those where n * (length / n) rounds away from the length).
    #[test]
    fn pieces_partition_each_beam_exactly() {
        let r = 0.01;
        let mut rng = Rng::new(3, 1);
        let lengths: Vec<f32> = std::iter::repeat_with(|| rng.f32() * 5.0)
            .filter(|&l| {
                let n = (l / (PIECE_RADII * r)).ceil().max(1.0);
                n * (l / n) != l
            })
            .take(50)
            .collect();
        // Each beam on its own line (y = its number), so its pieces are told by origin.
        let beams: Vec<Beam> = lengths
            .iter()
            .enumerate()
            .map(|(i, &l)| Beam::new(Vec3::Y * i as f32, Vec3::X, l, Vec3::ONE))
            .collect();
        let map = BeamMap::build(&beams, r, Walker::Cpu);
        for (i, b) in beams.iter().enumerate() {
            let mut mine: Vec<&BeamPiece> = map
                .pieces()
                .iter()
                .filter(|p| p.origin[1] == i as f32)
                .collect();
            mine.sort_by(|a, b| a.s0.total_cmp(&b.s0));
            assert_eq!(mine[0].s0, 0.0);
            for w in mine.windows(2) {
                assert_eq!(w[0].s1, w[1].s0);
            }
            assert_eq!(mine.last().unwrap().s1, b.length, "beam {i}");
        }
    }

    /// The gather applies the pair rule of [`term`] over either walker's tree: a beam of 4
    /// pieces crossed exactly on a cut between two pieces counts once, as the whole beam
    /// would; crossings at the segment start, on the beam's end or at distance r follow
    /// the rule too.
    #[test]
    fn gather_counts_edge_crossings_by_the_pair_rule() {
        let r = 0.25;
        let eps = 1.0 / 1024.0;
        let scatter = |x: Vec3, _| Vec3::new(1.0 + x.x, 1.0, 1.0);
        let tr = |t: f32| 1.0 / (1.0 + t);
        let ray = Ray::new(Vec3::ZERO, Vec3::X);
        // A beam along +z crossing the ray at t = tx, s = s_at, distance dy.
        let beam = |tx: f32, dy: f32, s_at: f32, len: f32| {
            Beam::new(Vec3::new(tx, dy, -s_at), Vec3::Z, len, Vec3::splat(2.0))
        };
        // Four pieces (exact in float32): crossings on the cuts count once.
        let piece = PIECE_RADII * r;
        let len = 4.0 * piece;
        let cases = [
            (beam(1.0, 0.1, piece, len), true),
            (beam(1.0, 0.1, 2.0 * piece, len), true),
            (beam(1.0, 0.1, len, len), false),
            (beam(1.0, 0.1, len - eps, len), true),
            (beam(0.0, 0.1, 1.0, 2.0), true),
            (beam(-eps, 0.1, 1.0, 2.0), false),
            (beam(2.0, 0.1, 1.0, 2.0), false),
            (beam(1.0, r, 1.0, 2.0), false),
            (beam(1.0, r - eps, 1.0, 2.0), true),
        ];
        for (k, (b, counts)) in cases.into_iter().enumerate() {
            for walker in [Walker::Cpu, Walker::Gpu] {
                let map = BeamMap::build(&[b], r, walker);
                let mut evals = 0;
                let got = map.radiance(&ray, 0.0, 2.0, scatter, tr, &mut evals);
                let want = term(&ray, (0.0, 2.0), &BeamPiece::whole(&b), r, scatter, tr);
                assert_eq!(want.is_some(), counts, "case {k}");
                assert_eq!(evals, u64::from(counts), "case {k} {walker:?}");
                assert_eq!(got, want.unwrap_or(Rgb::ZERO), "case {k} {walker:?}");
            }
        }
        assert_eq!(
            BeamMap::build(&[beam(1.0, 0.1, piece, len)], r, Walker::Cpu)
                .pieces()
                .len(),
            4
        );
    }
}
