// The beam radiance estimate (eq. 2) for every camera segment of one pass, in two kernels:
// `segment_main`, one invocation per segment, walks the beam BVH and writes
// beta * sum(k_r(d) sigma_s(x) f(cos) Phi Tr(t) / sin(theta)) (and, in w, the number of
// kernel evaluations), then the nested half-radius difference (`estimate::eq2::Nested`);
// `pixel_main`, one invocation per pixel, adds its segments' results to the pixel's
// float32 accumulators in segment order (deterministic sums). Segment results and
// accumulators hold two vec4 each: the estimate and count, then the nested difference.
// Primary segments may instead be rasterised (the original PPB's beam quads): `quad_vs`
// draws each beam as a film rectangle covering every pixel its kernel can reach, and
// `quad_fs` evaluates the same term for the pixel's primary segment into an additively
// blended float32 target, which `pixel_main` adds first. Blending follows primitive order,
// so the sums stay in beam order, as on the CPU. Mirrors
// `estimate::eq2` (the pair's term with its edge rule, the camera transmittance),
// `estimate::beams::BeamMap::radiance` and `media::Media` exactly; the structs match the
// `Pod` types in `src/gpu/layout.rs`, `src/estimate/eq2.rs` and `src/estimate/beams.rs`.

struct Chunk {
    first: u32,
    count: u32,
    _pad0: u32,
    _pad1: u32,
}

struct Segment {
    origin: vec3<f32>,
    t0: f32,
    dir: vec3<f32>,
    t1: f32,
    beta: vec3<f32>,
    tr_first: u32,
    tr_count: u32,
    seed: u32,
    _pad1: u32,
    _pad2: u32,
}

struct BvhNode {
    min: vec3<f32>,
    skip: u32,
    max: vec3<f32>,
    first: u32,
    count: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

struct BeamPiece {
    origin: vec3<f32>,
    s0: f32,
    dir: vec3<f32>,
    s1: f32,
    power: vec3<f32>,
    scale: f32,
}

struct BeamQuad {
    corners: array<vec2<f32>, 4>,
    piece: BeamPiece,
}

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<uniform> chunk: Chunk;
@group(0) @binding(2) var<storage, read> segments: array<Segment>;
@group(0) @binding(3) var<storage, read> pixel_first: array<u32>;
@group(0) @binding(4) var<storage, read> tr_steps: array<vec2<f32>>;
@group(0) @binding(5) var<storage, read> nodes: array<BvhNode>;
@group(0) @binding(6) var<storage, read> pieces: array<BeamPiece>;
@group(0) @binding(7) var<storage, read> grid_data: array<u32>;
@group(0) @binding(8) var<storage, read_write> accum: array<vec4<f32>>;
@group(0) @binding(9) var<storage, read_write> seg_out: array<vec4<f32>>;
@group(0) @binding(10) var primary_sums: texture_2d<f32>;
@group(0) @binding(11) var<storage, read> primaries: array<Segment>;
@group(0) @binding(12) var<storage, read> quads: array<BeamQuad>;
@group(0) @binding(13) var<storage, read> octree_nodes: array<Node>;
@group(0) @binding(14) var<uniform> octrees: Octrees;
// Where each segment's BVH walk stands (node, piece; node EMPTY: done), zero before a
// pass's first round, and how many walks a round left unfinished ([0]) or had cut ([1]).
@group(0) @binding(15) var<storage, read_write> walk_state: array<vec2<u32>>;
@group(0) @binding(16) var<storage, read_write> walks_left: array<atomic<u32>, 2>;
@group(0) @binding(17) var primary_nested: texture_2d<f32>;

// The grid transmittance estimate at t: the value after the last step before t.
fn grid_tr(seg: Segment, t: f32) -> f32 {
    var lo = 0u;
    var hi = seg.tr_count;
    while lo < hi {
        let mid = (lo + hi) / 2u;
        if tr_steps[seg.tr_first + mid].x < t {
            lo = mid + 1u;
        } else {
            hi = mid;
        }
    }
    var tr = 1.0;
    if lo > 0u {
        tr = tr_steps[seg.tr_first + lo - 1u].y;
    }
    return tr;
}

// The camera-transmittance factor, as `transport::transmittance::camera_tr`: the boxes' exact
// exp(-tau) from the segment origin to t times the grid estimate, the CPU's as steps or
// ratio tracking here (the segment's realization, the same for every t).
fn camera_tr(seg: Segment, inv: vec3<f32>, t: f32) -> f32 {
    var tau = 0.0;
    for (var i = 0u; i < params.box_count; i++) {
        let b = params.boxes[i];
        tau += box_overlap(seg.origin, inv, b.min, b.max, 0.0, t) * b.sigma_t;
    }
    var grid = 1.0;
    if params.track_tr != 0u {
        grid = ratio_tr_to(seg.origin, seg.dir, t, fp_key(seg.seed, params.pass_seed));
    } else {
        grid = grid_tr(seg, t);
    }
    return exp(-tau) * grid;
}

// A pair's eq. 2 term in l.xyz and 1 in l.w when it counts, and its nested half-radius
// difference in d.xyz: +l where it counts at r/2 too (d^2 < r^2 / 4), else -l.
struct Term {
    l: vec4<f32>,
    d: vec4<f32>,
}

// The piece's eq. 2 term: `estimate::eq2::nested_term`, the same arithmetic (`crossing`)
// and the same half-open edge rule, t0 <= t < t1, s0 <= s < s1, d^2 < r^2
// (sin^2 theta >= 1e-10: not parallel).
fn piece_radiance(seg: Segment, inv: vec3<f32>, p: BeamPiece) -> Term {
    let r = params.radius * p.scale;
    let w = seg.dir;
    let psi = p.dir;
    let b = dot(w, psi);
    let sin2 = 1.0 - b * b;
    let w0 = seg.origin - p.origin;
    let d = dot(w, w0);
    let e = dot(psi, w0);
    let sin2_safe = max(sin2, 1e-10);
    let t = (b * e - d) / sin2_safe;
    let s = (e - b * d) / sin2_safe;
    let v = w0 + w * t - psi * s;
    let ok = sin2 >= 1e-10 && dot(v, v) < r * r && seg.t0 <= t && t < seg.t1 && p.s0 <= s && s < p.s1;
    var out = Term(vec4<f32>(0.0), vec4<f32>(0.0));
    if ok {
        let x = seg.origin + w * t;
        let f = in_scatter(x, dot(psi, -w));
        let l = f * p.power * ((0.5 / r) * camera_tr(seg, inv, t) / sqrt(sin2));
        out.l = vec4<f32>(l, 1.0);
        out.d = vec4<f32>(select(-l, l, 4.0 * dot(v, v) < r * r), 0.0);
    }
    return out;
}

// `tube::chord`: the part [lo, hi) of the segment within r of the piece's axis and between
// its end planes, from the ray's offset p + t q from the axis (the same arithmetic, so the
// same bits where the adapter rounds as the CPU does), and whether the pair counts
// (the lines at least sin^2 = 1e-10 from parallel, the discriminant positive, lo < hi).
struct Chord {
    lo: f32,
    hi: f32,
    counts: bool,
}

// Rust's f32::copysign: the magnitude of m with the sign bit of s.
fn copysign(m: f32, s: f32) -> f32 {
    return bitcast<f32>((bitcast<u32>(m) & 0x7fffffffu) | (bitcast<u32>(s) & 0x80000000u));
}

fn tube_chord(seg: Segment, p: BeamPiece, r: f32) -> Chord {
    let w = seg.dir;
    let psi = p.dir;
    let w0 = seg.origin - p.origin;
    let b = dot(w, psi);
    let e = dot(psi, w0);
    let off = w0 - e * psi;
    let q = w - b * psi;
    let a = dot(q, q);
    let h = dot(off, q);
    let c = dot(off, off);
    let cr = c - r * r;
    let k = -(h + copysign(sqrt(h * h - a * cr), h));
    let ra = k / a;
    let rb = cr / k;
    let inv_b = 1.0 / b;
    let sa = (p.s0 - e) * inv_b;
    let sb = (p.s1 - e) * inv_b;
    let lo = max(max(min(ra, rb), min(sa, sb)), seg.t0);
    let hi = min(min(max(ra, rb), max(sa, sb)), seg.t1);
    let counts = a >= 1e-10 && h * h - a * (c - r * r) > 0.0 && lo < hi;
    return Chord(lo, hi, counts);
}

// `tube::pair_u`: the pair's uniform number from the segment's ray and the piece's bits,
// `sampling::hash_unit` with its first ten `HASH_WEIGHTS` as literals (the gpu module's
// tests check them).
fn pair_u(seg: Segment, p: BeamPiece) -> f32 {
    let o = bitcast<vec3<u32>>(seg.origin);
    let w = bitcast<vec3<u32>>(seg.dir);
    let y = bitcast<vec3<u32>>(p.origin);
    let h = o.x * 0xa8beea3du + o.y * 0x7a7ecc89u + o.z * 0x7f0ef6bdu
        + w.x * 0x28780865u + w.y * 0x80d0d707u + w.z * 0xf150b1a5u
        + y.x * 0x7e67121du + y.y * 0x1b6bacc5u + y.z * 0x4d978925u
        + bitcast<u32>(p.s0) * 0x70009581u;
    return f32(pcg_hash(pcg_hash(h)) >> 8u) * (1.0 / 16777216.0);
}

// The tube kernel's term (`estimate::tube::counted_term`) at the pair's point on its chord,
// and its nested difference: 3 l where that point is within r/2 of the axis (the kernel
// there is 4 times as high), else -l.
fn tube_radiance(seg: Segment, inv: vec3<f32>, p: BeamPiece) -> Term {
    let r = params.radius * p.scale;
    let ch = tube_chord(seg, p, r);
    var out = Term(vec4<f32>(0.0), vec4<f32>(0.0));
    if ch.counts {
        let t = ch.lo + pair_u(seg, p) * (ch.hi - ch.lo);
        let x = seg.origin + seg.dir * t;
        let off = x - p.origin;
        let across = off - p.dir * dot(off, p.dir);
        let inner = 4.0 * dot(across, across) < r * r;
        let f = in_scatter(x, dot(p.dir, -seg.dir));
        let area = PI * r * r;
        let l = f * p.power * ((ch.hi - ch.lo) * camera_tr(seg, inv, t) / area);
        out.l = vec4<f32>(l, 1.0);
        out.d = vec4<f32>(select(-l, 3.0 * l, inner), 0.0);
    }
    return out;
}

// The pair's term under the render's kernel.
fn pair_radiance(seg: Segment, inv: vec3<f32>, p: BeamPiece) -> Term {
    if params.kernel == 1u {
        return tube_radiance(seg, inv, p);
    }
    return piece_radiance(seg, inv, p);
}

// Whether the walk enters node `n`: the slab test, a box the segment only touches included.
fn hits(n: BvhNode, o: vec3<f32>, inv: vec3<f32>, t0: f32, t1: f32) -> bool {
    let s = slab(o, inv, n.min, n.max, t0, t1);
    return s.x <= s.y;
}

// Stackless walk of the pre-ordered BVH, one node or one piece per iteration (a flat loop:
// nested divergent loops were miscompiled by Mesa's gallivm): a hit inner node continues
// with its first child (the next node); a missed node or a finished leaf jumps past its
// subtree. The walk resumes from `walk_state[i]` and stops after `params.walk_budget`
// iterations (software adapters end long loops early); `segment_main` saves where it
// stopped.
fn segment_radiance(seg: Segment, i: u32) -> Walked {
    let inv = safe_inv(seg.dir);
    var sum = Term(vec4<f32>(0.0), vec4<f32>(0.0));
    var node = walk_state[i].x;
    var k = walk_state[i].y;
    var it = 0u;
    while node != EMPTY && it < params.walk_budget {
        it += 1u;
        let n = nodes[node];
        if k == 0u && !hits(n, seg.origin, inv, seg.t0, seg.t1) {
            node = n.skip;
        } else if n.count == 0u {
            node = node + 1u;
        } else {
            let term = pair_radiance(seg, inv, pieces[n.first + k]);
            sum.l += term.l;
            sum.d += term.d;
            k = k + 1u;
            if k == n.count {
                k = 0u;
                node = n.skip;
            }
        }
    }
    // A walk the adapter ended before its budget (lavapipe's loop limit) lost crossings.
    return Walked(sum, vec2<u32>(node, k), node != EMPTY && it < params.walk_budget);
}

// A round of one segment's walk: its sum, where it stopped, and whether the adapter cut it.
struct Walked {
    sum: Term,
    state: vec2<u32>,
    cut: bool,
}

@compute @workgroup_size(64)
fn segment_main(@builtin(global_invocation_id) id: vec3<u32>) {
    if id.x >= chunk.count {
        return;
    }
    let i = chunk.first + id.x;
    if walk_state[i].x == EMPTY {
        return;
    }
    let seg = segments[i];
    let w = segment_radiance(seg, i);
    if w.cut && params.walk_budget != EMPTY {
        // In rounds: redo this round's part with the smaller budget the host then sets.
        atomicAdd(&walks_left[1], 1u);
    } else {
        // In one unbounded round a cut cannot be redone: mark the sums as wrong.
        let r = select(w.sum.l, vec4<f32>(LOOP_CUT), w.cut);
        seg_out[2u * i] += vec4<f32>(seg.beta * r.xyz, r.w);
        seg_out[2u * i + 1u] += vec4<f32>(seg.beta * w.sum.d.xyz, 0.0);
        walk_state[i] = w.state;
        if w.state.x != EMPTY {
            atomicAdd(&walks_left[0], 1u);
        }
    }
}

@compute @workgroup_size(64)
fn pixel_main(@builtin(global_invocation_id) id: vec3<u32>) {
    if id.x >= chunk.count {
        return;
    }
    let pixel = chunk.first + id.x;
    var l = vec4<f32>(0.0);
    var d = vec4<f32>(0.0);
    let w = params.raster_width;
    if w > 0u {
        let at = vec2<u32>(pixel % w, pixel / w);
        l = textureLoad(primary_sums, at, 0);
        d = textureLoad(primary_nested, at, 0);
    }
    for (var i = pixel_first[pixel]; i < pixel_first[pixel + 1u]; i++) {
        l += seg_out[2u * i];
        d += seg_out[2u * i + 1u];
    }
    accum[2u * pixel] += l;
    accum[2u * pixel + 1u] += d;
}

struct QuadOut {
    @builtin(position) pos: vec4<f32>,
    @location(0) @interpolate(flat) quad: u32,
}

@vertex
fn quad_vs(@builtin(vertex_index) v: u32, @builtin(instance_index) q: u32) -> QuadOut {
    // Two triangles, (0, 1, 2) and (2, 1, 3), over the strip-ordered corners.
    var strip = array<u32, 6>(0u, 1u, 2u, 2u, 1u, 3u);
    var out: QuadOut;
    out.pos = vec4<f32>(quads[q].corners[strip[v]], 0.0, 1.0);
    out.quad = q;
    return out;
}

// The pair's term into the first target, its nested difference into the second.
struct QuadSums {
    @location(0) l: vec4<f32>,
    @location(1) d: vec4<f32>,
}

@fragment
fn quad_fs(in: QuadOut) -> QuadSums {
    let px = vec2<u32>(in.pos.xy);
    let seg = primaries[px.y * params.raster_width + px.x];
    let r = pair_radiance(seg, safe_inv(seg.dir), quads[in.quad].piece);
    if r.l.w == 0.0 {
        discard;
    }
    return QuadSums(r.l, r.d);
}
