// Free-path sampling on the GPU, mirroring `transport::freepath::FreePath`: each grid's
// majorant segments along a ray (the octree leaves, `Octree::walk`, or one segment at the
// global majorant for Woodcock), delta tracking through all grids (the nearest collision
// wins, the minorant shortcut as `sample_grids`) and ratio tracking. Appended, like
// media.wgsl (which it needs), to a kernel's source; the kernel declares
// `octree_nodes: array<Node>` (storage, every grid's nodes concatenated) and
// `octrees: Octrees` (uniform), both from `src/gpu/freepath.rs` (`octree_upload`).
//
// Random numbers: PCG-RXS-M-XS 32 (O'Neill 2014, 32-bit state, an odd increment per
// stream), since WGSL has no u64; the CPU's PCG32 stream is not reproduced, only its
// distribution. Each grid is tracked with its own stream keyed by (seed, grid), so a
// realization does not depend on how far another grid was tracked: `ratio_tr_to` with one
// seed and growing t sees the same tentative collisions and multiplies more of them.
//
// Leaves are located by descent from the root (no `CellIndex` table is uploaded); one
// descent level per loop iteration. Every loop here is flat (one loop, state variables,
// no early return inside): Mesa's gallivm miscompiled nested divergent loops before.

const FP_WOODCOCK: u32 = 1u;
const FP_DELTA: u32 = 0u;
const FP_RATIO: u32 = 1u;
// f32::EPSILON, for the walk's nudge.
const FP_EPS: f32 = 1.1920929e-7;
// Iterations one tracking loop may take (descent levels, segments and tentative
// collisions together): a guard against a walk that stops advancing, never reached in
// practice.
const FP_MAX_ITERS: u32 = 4194304u;
// `transport::freepath::ROULETTE_BELOW` (a test keeps the two equal).
const ROULETTE_BELOW: f32 = 0.02;

// `majorant::Node`: children are 8 consecutive nodes, `first_child` counts from the
// grid's root (0: a leaf).
struct Node {
    min: vec3<f32>,
    majorant: f32,
    max: vec3<f32>,
    minorant: f32,
    first_child: u32,
    depth: u32,
    _pad0: u32,
    _pad1: u32,
}

// Per grid i: its root's index in `octree_nodes` (roots[i / 4][i % 4]) and its global
// majorant density_scale * max_density (Woodcock); `mode` 1 = Woodcock, 0 = adaptive.
struct Octrees {
    roots: array<vec4<u32>, 2>,
    majorants: array<vec4<f32>, 2>,
    mode: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

struct Rng {
    state: u32,
    inc: u32,
}

// PCG-RXS-M-XS 32 as a hash (Jarzynski and Olano 2020): spreads structured keys.
fn pcg_hash(x: u32) -> u32 {
    let s = x * 747796405u + 2891336453u;
    let w = ((s >> ((s >> 28u) + 4u)) ^ s) * 277803737u;
    return (w >> 22u) ^ w;
}

// One seed from two keys (e.g. a segment index and a pass seed).
fn fp_key(a: u32, b: u32) -> u32 {
    return pcg_hash(a ^ pcg_hash(b + 0x9e3779b9u));
}

fn rng_next(r: ptr<function, Rng>) -> u32 {
    let old = (*r).state;
    (*r).state = old * 747796405u + (*r).inc;
    let w = ((old >> ((old >> 28u) + 4u)) ^ old) * 277803737u;
    return (w >> 22u) ^ w;
}

// Uniform in [0, 1), 24 bits, as `Rng::f32`.
fn rng_f32(r: ptr<function, Rng>) -> f32 {
    return f32(rng_next(r) >> 8u) * (1.0 / 16777216.0);
}

// Russian roulette on one grid's ratio-tracking product, `transport::freepath::roulette`:
// below ROULETTE_BELOW it becomes ROULETTE_BELOW with probability tr / ROULETTE_BELOW, else 0.
fn roulette(tr: f32, r: ptr<function, Rng>) -> f32 {
    if tr >= ROULETTE_BELOW || tr <= 0.0 {
        return tr;
    }
    if rng_f32(r) * ROULETTE_BELOW < tr {
        return ROULETTE_BELOW;
    }
    return 0.0;
}

// The stream for (key, stream), seeded as pcg32's srandom.
fn rng_new(key: u32, stream: u32) -> Rng {
    var r = Rng(0u, (pcg_hash(stream ^ pcg_hash(key)) << 1u) | 1u);
    _ = rng_next(&r);
    r.state += pcg_hash(key);
    _ = rng_next(&r);
    return r;
}

fn fp_max3(v: vec3<f32>) -> f32 {
    return max(max(v.x, v.y), v.z);
}

fn fp_min3(v: vec3<f32>) -> f32 {
    return min(min(v.x, v.y), v.z);
}

// A grid's majorant segments along a ray, one `walk_step` at a time.
struct Walk {
    o: vec3<f32>,
    d: vec3<f32>,
    inv: vec3<f32>,
    // The root's box (adaptive) or the grid's (Woodcock), as the CPU uses.
    lo: vec3<f32>,
    hi: vec3<f32>,
    // The point being located and the node reached by the descent.
    p: vec3<f32>,
    base: u32,
    node: u32,
    t: f32,
    t1: f32,
    size_nudge: f32,
    far: f32,
    nudge: f32,
    // The segment the last `walk_step` returning true handed out.
    s0: f32,
    s1: f32,
    maj: f32,
    mino: f32,
    woodcock: bool,
    descending: bool,
    done: bool,
}

// Grid `gi`'s walk over [0, tmax] (`Heterogeneous::majorants` in `octrees.mode`).
fn walk_begin(gi: u32, o: vec3<f32>, d: vec3<f32>, tmax: f32) -> Walk {
    var w: Walk;
    w.o = o;
    w.d = d;
    w.inv = safe_inv(d);
    w.woodcock = octrees.mode == FP_WOODCOCK;
    w.base = octrees.roots[gi / 4u][gi % 4u];
    if w.woodcock {
        w.lo = params.grids[gi].bmin;
        w.hi = params.grids[gi].bmax;
        w.maj = octrees.majorants[gi / 4u][gi % 4u];
        w.mino = 0.0;
    } else {
        let root = octree_nodes[w.base];
        w.lo = root.min;
        w.hi = root.max;
    }
    let s = slab(o, w.inv, w.lo, w.hi, 0.0, tmax);
    w.t = s.x;
    w.t1 = s.y;
    w.done = !(w.t < w.t1);
    w.node = w.base;
    w.descending = false;
    // `Octree::walk`: a box-relative nudge, at least a few ulps of t and of the point.
    w.size_nudge = fp_max3(w.hi - w.lo) * 1e-6;
    w.far = max(fp_max3(abs(o)), max(fp_max3(abs(w.lo)), fp_max3(abs(w.hi))));
    return w;
}

// One step of the walk: locate the point just past t (start a descent), go one level
// down, or hand out the leaf reached as the segment [s0, s1] (returns true). `done` once
// the walk has reached t1.
fn walk_step(w: ptr<function, Walk>) -> bool {
    var emitted = false;
    if (*w).woodcock {
        (*w).s0 = (*w).t;
        (*w).s1 = (*w).t1;
        (*w).t = (*w).t1;
        (*w).done = true;
        emitted = true;
    } else if !(*w).descending {
        let t = (*w).t;
        (*w).nudge = max((*w).size_nudge, (abs(t) + (*w).far) * 16.0 * FP_EPS);
        (*w).p = clamp((*w).o + (*w).d * (t + (*w).nudge), (*w).lo, (*w).hi);
        (*w).node = (*w).base;
        (*w).descending = true;
    } else {
        let n = octree_nodes[(*w).node];
        if n.first_child != 0u {
            let c = 0.5 * (n.min + n.max);
            let p = (*w).p;
            let oct = select(0u, 1u, p.x >= c.x) | select(0u, 2u, p.y >= c.y) | select(0u, 4u, p.z >= c.z);
            (*w).node = (*w).base + n.first_child + oct;
        } else {
            let t = (*w).t;
            let a = (n.min - (*w).o) * (*w).inv;
            let b = (n.max - (*w).o) * (*w).inv;
            let exit = min(max(fp_min3(max(a, b)), t + (*w).nudge), (*w).t1);
            (*w).s0 = t;
            (*w).s1 = exit;
            (*w).maj = n.majorant;
            (*w).mino = n.minorant;
            (*w).t = exit;
            (*w).descending = false;
            (*w).done = !(exit < (*w).t1);
            emitted = true;
        }
    }
    return emitted;
}

// What tracking found: the collision (delta: `hit`, at t) or the ratio estimate `tr`, and
// its work (density lookups, majorant segments).
struct Track {
    t: f32,
    hit: bool,
    tr: f32,
    lookups: u32,
    steps: u32,
    // The loop ended before every grid was tracked (an adapter's loop limit, or
    // FP_MAX_ITERS): the result is not an estimate.
    cut: bool,
}

// Tracking through every grid over [0, tmax] with the realization keyed by `seed`:
// `kind` FP_DELTA draws a free path (`FreePath::sample_grids`; later grids are tracked
// only up to the nearest collision so far), FP_RATIO multiplies 1 - sigma_t / majorant
// over the tentative collisions, each grid's product through the roulette
// (`FreePath::ratio_transmittance`). The optical depth left
// is carried across a grid's segments; segments of majorant 0 are skipped.
fn fp_track(o: vec3<f32>, d: vec3<f32>, tmax: f32, seed: u32, kind: u32) -> Track {
    var out = Track(tmax, false, 1.0, 0u, 0u, false);
    var limit = tmax;
    var gi = 0u;
    var w: Walk;
    var rng: Rng;
    var tau = 0.0;
    var tc = 0.0;
    // This grid's ratio-tracking product (each grid's goes through the roulette alone).
    var gtr = 1.0;
    var started = false;
    var in_seg = false;
    var iters = 0u;
    loop {
        if gi >= params.grid_count || iters >= FP_MAX_ITERS {
            break;
        }
        iters += 1u;
        if !started {
            w = walk_begin(gi, o, d, limit);
            rng = rng_new(seed, gi);
            tau = -log(1.0 - rng_f32(&rng));
            gtr = 1.0;
            started = true;
            in_seg = false;
        } else if !in_seg {
            if w.done {
                out.tr *= gtr;
                gi += 1u;
                started = false;
            } else if walk_step(&w) {
                in_seg = true;
                tc = w.s0;
                out.steps += 1u;
            }
        } else {
            let room = (w.s1 - tc) * w.maj;
            if w.maj <= 0.0 || tau >= room {
                if w.maj > 0.0 {
                    tau -= room;
                }
                in_seg = false;
            } else {
                tc += tau / w.maj;
                let p = o + d * tc;
                if kind == FP_DELTA {
                    // Below the minorant the collision is real without a lookup.
                    let u = rng_f32(&rng) * w.maj;
                    var real = u < w.mino;
                    if !real {
                        out.lookups += 1u;
                        real = u < grid_sigma_t(gi, p);
                    }
                    if real {
                        out.t = tc;
                        out.hit = true;
                        limit = tc;
                        gi += 1u;
                        started = false;
                    }
                } else {
                    out.lookups += 1u;
                    gtr = roulette(gtr * max(1.0 - grid_sigma_t(gi, p) / w.maj, 0.0), &rng);
                    if gtr <= 0.0 {
                        // On to the next grid, not to the end: a later grid's tentative
                        // collisions stay those of the realization at every t.
                        out.tr = 0.0;
                        gi += 1u;
                        started = false;
                    }
                }
                tau = -log(1.0 - rng_f32(&rng));
            }
        }
    }
    out.cut = gi < params.grid_count;
    return out;
}

// A free path through the grids in (0, tmax): `hit` false if the ray gets through.
fn free_path(o: vec3<f32>, d: vec3<f32>, tmax: f32, seed: u32) -> Track {
    return fp_track(o, d, tmax, seed, FP_DELTA);
}

// Ratio-tracking estimate of the grids' transmittance from o to o + t d for the
// realization `seed`. Tracking always starts at 0 with the same per-grid streams and
// stops past t, so calls with one seed and different t share their tentative collisions:
// the values are non-increasing in t and each is the product over those before t (one
// realization per camera segment serves every beam crossing on it).
// LOOP_CUT if tracking was cut short.
fn ratio_tr_to(o: vec3<f32>, d: vec3<f32>, t: f32, seed: u32) -> f32 {
    let r = fp_track(o, d, t, seed, FP_RATIO);
    return select(r.tr, LOOP_CUT, r.cut);
}
