// Test kernels of freepath.wgsl (`gpu::freepath::GpuFreePaths`): batches of rays, each
// item one free path, one ratio estimate at one distance, or one ray's walk. Followed by
// freepath.wgsl and media.wgsl.

// Items [first, first + count) of this dispatch; `per_ray` items per ray (free paths,
// distances, or segment slots of a walk); `grid`: the grid a walk follows.
struct FpJob {
    first: u32,
    count: u32,
    per_ray: u32,
    grid: u32,
}

struct FpRay {
    origin: vec3<f32>,
    tmax: f32,
    dir: vec3<f32>,
    seed: u32,
}

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<uniform> job: FpJob;
@group(0) @binding(2) var<storage, read> grid_data: array<u32>;
@group(0) @binding(3) var<storage, read> octree_nodes: array<Node>;
@group(0) @binding(4) var<uniform> octrees: Octrees;
@group(0) @binding(5) var<storage, read> rays: array<FpRay>;
@group(0) @binding(6) var<storage, read> dists: array<f32>;
@group(0) @binding(7) var<storage, read_write> out: array<vec4<u32>>;

// Item i: free path i % per_ray of ray i / per_ray -> (t bits, hit, lookups, segments).
@compute @workgroup_size(64)
fn free_path_main(@builtin(global_invocation_id) id: vec3<u32>) {
    if id.x < job.count {
        let i = job.first + id.x;
        let r = rays[i / job.per_ray];
        let s = free_path(r.origin, r.dir, r.tmax, fp_key(r.seed, i % job.per_ray));
        out[i] = vec4<u32>(bitcast<u32>(s.t), select(0u, 1u, s.hit), s.lookups, s.steps);
    }
}

// Item i: ratio_tr_to at dists[i] on ray i / per_ray with the ray's seed
// -> (tr bits, lookups, segments, 0).
@compute @workgroup_size(64)
fn ratio_main(@builtin(global_invocation_id) id: vec3<u32>) {
    if id.x < job.count {
        let i = job.first + id.x;
        let r = rays[i / job.per_ray];
        let s = fp_track(r.origin, r.dir, dists[i], r.seed, FP_RATIO);
        out[i] = vec4<u32>(bitcast<u32>(s.tr), s.lookups, s.steps, 0u);
    }
}

// Item i: ray i's walk of grid `job.grid` over [0, tmax]: the segment count at
// out[i * (per_ray + 1)], then up to per_ray segments (s0, s1, majorant, minorant bits).
@compute @workgroup_size(64)
fn walk_main(@builtin(global_invocation_id) id: vec3<u32>) {
    if id.x < job.count {
        let i = job.first + id.x;
        let r = rays[i];
        let base = i * (job.per_ray + 1u);
        var w = walk_begin(job.grid, r.origin, r.dir, r.tmax);
        var n = 0u;
        var iters = 0u;
        loop {
            if w.done || n >= job.per_ray || iters >= FP_MAX_ITERS {
                break;
            }
            iters += 1u;
            if walk_step(&w) {
                out[base + 1u + n] = vec4<u32>(bitcast<u32>(w.s0), bitcast<u32>(w.s1), bitcast<u32>(w.maj), bitcast<u32>(w.mino));
                n += 1u;
            }
        }
        out[base] = vec4<u32>(n, 0u, 0u, 0u);
    }
}
