// The media shared by the GPU kernels: homogeneous boxes and density grids as uploaded by
// `src/gpu/layout.rs` (`media_params`), their extinction and in-scattering, mirroring
// `media::Media` and `media::grid::Grid`. WGSL has no includes: each kernel's Rust side
// appends this file to its source (`concat!`), and the kernel declares the globals read
// here, `params: Params` (uniform) and `grid_data: array<u32>` (storage).

const MAX_BOXES: u32 = 16u;
const MAX_GRIDS: u32 = 8u;
const EMPTY: u32 = 0xffffffffu;
const TILE_SLOT: u32 = 0x80000000u;
const PI: f32 = 3.14159265358979;
// What a result becomes when a loop was ended before its work was done (Mesa's gallivm
// ends an invocation's loops after 65,535 iterations in all): a negative radiance, which no
// true estimate has, so the readback can refuse the sums instead of returning wrong ones.
const LOOP_CUT: f32 = -1e30;

struct MediumBox {
    min: vec3<f32>,
    sigma_t: f32,
    max: vec3<f32>,
    g: f32,
    albedo: vec3<f32>,
    _pad: f32,
}

struct GridMeta {
    row0: vec4<f32>,
    row1: vec4<f32>,
    row2: vec4<f32>,
    bmin: vec3<f32>,
    density_scale: f32,
    bmax: vec3<f32>,
    g: f32,
    albedo: vec3<f32>,
    background: f32,
    table_min: vec3<i32>,
    leaf_base: u32,
    table_dim: vec3<i32>,
    table_base: u32,
    tile_base: u32,
    tile_count: u32,
    _pad0: u32,
    _pad1: u32,
}

struct Params {
    radius: f32,
    box_count: u32,
    grid_count: u32,
    // The image width when primary segments are rasterised, 0 when they are gathered.
    raster_width: u32,
    // This pass's key for camera transmittance tracked on the GPU, and whether it is
    // (else the kernels read the CPU's estimate as steps).
    pass_seed: u32,
    track_tr: u32,
    // BVH walk iterations per segment per dispatch round.
    walk_budget: u32,
    // The beam kernel: 0 eq. 2's line, 1 the tube.
    kernel: u32,
    boxes: array<MediumBox, MAX_BOXES>,
    grids: array<GridMeta, MAX_GRIDS>,
}

fn hg(g: f32, cos_theta: f32) -> f32 {
    let denom = 1.0 + g * g - 2.0 * g * cos_theta;
    return (1.0 - g * g) / (4.0 * PI * denom * sqrt(max(denom, 1e-12)));
}

fn inside(p: vec3<f32>, lo: vec3<f32>, hi: vec3<f32>) -> bool {
    return all(p >= lo) && all(p <= hi);
}

// The 1/d rule of `core::Ray::inv_d`: a component under MIN_DIR in magnitude becomes MIN_DIR.
fn safe_inv(d: vec3<f32>) -> vec3<f32> {
    return 1.0 / select(d, vec3<f32>(1e-30), abs(d) < vec3<f32>(1e-30));
}

// (near, far) of the ray (o, inv = safe_inv(d)) in the box [lo, hi], clipped to [t0, t1]:
// `core::slab`, the one slab test (empty when near >= far).
fn slab(o: vec3<f32>, inv: vec3<f32>, lo: vec3<f32>, hi: vec3<f32>, t0: f32, t1: f32) -> vec2<f32> {
    let a = (lo - o) * inv;
    let b = (hi - o) * inv;
    let near = max(max(max(min(a.x, b.x), min(a.y, b.y)), min(a.z, b.z)), t0);
    let far = min(min(min(max(a.x, b.x), max(a.y, b.y)), max(a.z, b.z)), t1);
    return vec2<f32>(near, far);
}

// Length of [t0, t1] inside the box (0 when they miss), as `core::ray_box`.
fn box_overlap(o: vec3<f32>, inv: vec3<f32>, lo: vec3<f32>, hi: vec3<f32>, t0: f32, t1: f32) -> f32 {
    let s = slab(o, inv, lo, hi, t0, t1);
    return select(0.0, s.y - s.x, s.x < s.y);
}

fn voxel(gi: u32, ijk: vec3<i32>) -> f32 {
    let m = params.grids[gi];
    let key = ijk >> vec3<u32>(3u);
    let d = key - m.table_min;
    var slot = EMPTY;
    if all(d >= vec3<i32>(0)) && all(d < m.table_dim) {
        slot = grid_data[m.table_base + u32((d.x * m.table_dim.y + d.y) * m.table_dim.z + d.z)];
    }
    var v = m.background;
    if slot != EMPTY && (slot & TILE_SLOT) != 0u {
        // A slot a tile covers whole, as `Grid::value`.
        v = bitcast<f32>(grid_data[m.tile_base + 7u * (slot & ~TILE_SLOT) + 6u]);
    } else if slot != EMPTY {
        let l = ijk & vec3<i32>(7);
        v = bitcast<f32>(grid_data[m.leaf_base + slot * 512u + u32((l.x * 8 + l.y) * 8 + l.z)]);
    } else {
        // The first tile containing the voxel, as `Grid::value`.
        var found = false;
        for (var k = 0u; k < m.tile_count; k++) {
            let t = m.tile_base + 7u * k;
            let lo = vec3<i32>(bitcast<i32>(grid_data[t]), bitcast<i32>(grid_data[t + 1u]), bitcast<i32>(grid_data[t + 2u]));
            let hi = vec3<i32>(bitcast<i32>(grid_data[t + 3u]), bitcast<i32>(grid_data[t + 4u]), bitcast<i32>(grid_data[t + 5u]));
            if !found && all(ijk >= lo) && all(ijk <= hi) {
                v = bitcast<f32>(grid_data[t + 6u]);
                found = true;
            }
        }
    }
    return v;
}

// Extinction of grid `gi` at world point p: trilinear between voxel centres.
fn grid_sigma_t(gi: u32, p: vec3<f32>) -> f32 {
    let m = params.grids[gi];
    var sigma = 0.0;
    if inside(p, m.bmin, m.bmax) {
        let p4 = vec4<f32>(p, 1.0);
        let q = vec3<f32>(dot(m.row0, p4), dot(m.row1, p4), dot(m.row2, p4));
        let f = floor(q);
        let t = q - f;
        let i = vec3<i32>(f);
        let x00 = mix(voxel(gi, i), voxel(gi, i + vec3<i32>(1, 0, 0)), t.x);
        let x10 = mix(voxel(gi, i + vec3<i32>(0, 1, 0)), voxel(gi, i + vec3<i32>(1, 1, 0)), t.x);
        let x01 = mix(voxel(gi, i + vec3<i32>(0, 0, 1)), voxel(gi, i + vec3<i32>(1, 0, 1)), t.x);
        let x11 = mix(voxel(gi, i + vec3<i32>(0, 1, 1)), voxel(gi, i + vec3<i32>(1, 1, 1)), t.x);
        let v = mix(mix(x00, x10, t.y), mix(x01, x11, t.y), t.z);
        sigma = m.density_scale * max(v, 0.0);
    }
    return sigma;
}

// sum_i sigma_s,i(x) f_i(cos): the media's in-scattering at x, as `Media::in_scatter`.
fn in_scatter(x: vec3<f32>, cos_theta: f32) -> vec3<f32> {
    var l = vec3<f32>(0.0);
    for (var i = 0u; i < params.box_count; i++) {
        let b = params.boxes[i];
        if inside(x, b.min, b.max) {
            l += b.albedo * (b.sigma_t * hg(b.g, cos_theta));
        }
    }
    for (var i = 0u; i < params.grid_count; i++) {
        let s = grid_sigma_t(i, x);
        if s > 0.0 {
            l += params.grids[i].albedo * (s * hg(params.grids[i].g, cos_theta));
        }
    }
    return l;
}
