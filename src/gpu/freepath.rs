//! Free-path sampling on the GPU (`shaders/freepath.wgsl`): the octree walk, delta and
//! ratio tracking in WGSL, so a kernel can estimate camera-segment transmittance itself
//! instead of receiving per-pass transmittance steps. The media ([`media_params`]) and
//! every grid's octree nodes ([`octree_upload`]) are uploaded once. [`GpuFreePaths`] runs
//! test kernels (`shaders/freepath_test.wgsl`) on batches of rays, so the WGSL sampler can
//! be checked against the CPU's (`transport::freepath::FreePath`).
use bytemuck::{Pod, Zeroable};
use wgpu::util::DeviceExt;

use super::buffers::{
    buffer_entry, read_back, storage_init, uniform_stride, uniform_table, CHUNK, READ, READ_WRITE,
    UNIFORM,
};
use super::layout::{media_params, mode_word, octree_upload, Octrees};
use super::{compute_pipelines, Gpu};
use crate::error::{Error, Result};
use crate::majorant::Mode;
use crate::media::Media;

/// The functions a kernel appends to use free-path sampling (after its own source; it
/// also appends `media.wgsl`).
pub const FREEPATH_WGSL: &str = include_str!("../../shaders/freepath.wgsl");

/// The test kernels' source: their file, the free-path functions and the media code.
pub const SHADER: &str = concat!(
    include_str!("../../shaders/freepath_test.wgsl"),
    include_str!("../../shaders/freepath.wgsl"),
    include_str!("../../shaders/media.wgsl")
);

const WORKGROUP: u32 = 64;

/// One test ray: [0, tmax] along `dir` from `origin`, its realizations keyed by `seed`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
pub struct FpRay {
    pub origin: [f32; 3],
    pub tmax: f32,
    pub dir: [f32; 3],
    pub seed: u32,
}

/// The items of one dispatch and what they share; `FpJob` in `freepath_test.wgsl`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
pub struct FpJob {
    pub first: u32,
    pub count: u32,
    pub per_ray: u32,
    pub grid: u32,
}

/// One GPU free path: the distance to the collision (None: the ray got through), with
/// its density lookups and majorant segments.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GpuFreePath {
    pub t: Option<f32>,
    pub lookups: u32,
    pub segments: u32,
}

/// One ratio-tracking estimate and its density lookups.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GpuRatio {
    pub tr: f32,
    pub lookups: u32,
}

/// A majorant segment of a walk: [t0, t1] with the leaf's bounds.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GpuSegment {
    pub t0: f32,
    pub t1: f32,
    pub majorant: f32,
    pub minorant: f32,
}

/// The free-path test kernels with the media and octrees uploaded.
pub struct GpuFreePaths {
    gpu: Gpu,
    free_path: wgpu::ComputePipeline,
    ratio: wgpu::ComputePipeline,
    walk: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
    octrees: Octrees,
    params_buf: wgpu::Buffer,
    grid_buf: wgpu::Buffer,
    nodes_buf: wgpu::Buffer,
    octrees_buf: wgpu::Buffer,
    job_stride: u64,
}

impl GpuFreePaths {
    /// Compiles the kernels and uploads the media and octrees (once).
    pub fn new(gpu: Gpu, media: &Media) -> Result<Self> {
        let dev = &gpu.device;
        let scope = dev.push_error_scope(wgpu::ErrorFilter::Validation);
        let layout = bind_group_layout(dev);
        let entries = ["free_path_main", "ratio_main", "walk_main"];
        let (_, pipelines) =
            compute_pipelines(dev, "freepath_test.wgsl", SHADER, &layout, &entries);
        let [free_path, ratio, walk]: [wgpu::ComputePipeline; 3] = pipelines
            .try_into()
            .map_err(|_| Error::Gpu("three pipelines".into()))?;
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(Error::Gpu(format!("freepath_test.wgsl: {e}")));
        }
        let (params, grid_words) = media_params(media)?;
        let (octrees, nodes) = octree_upload(media)?;
        let grid_bytes: &[u8] = if grid_words.is_empty() {
            &[0; 16]
        } else {
            bytemuck::cast_slice(&grid_words)
        };
        let grid_buf = storage_init(&gpu, "grid data", grid_bytes)?;
        let nodes_buf = storage_init(&gpu, "octree nodes", bytemuck::cast_slice(&nodes))?;
        let uniform = |label: &str, contents: &[u8]| {
            dev.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents,
                usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            })
        };
        let params_buf = uniform("params", bytemuck::bytes_of(&params));
        let octrees_buf = uniform("octrees", bytemuck::bytes_of(&octrees));
        let job_stride = uniform_stride::<FpJob>(&gpu);
        let g = GpuFreePaths {
            gpu,
            free_path,
            ratio,
            walk,
            layout,
            octrees,
            params_buf,
            grid_buf,
            nodes_buf,
            octrees_buf,
            job_stride,
        };
        g.check()?;
        Ok(g)
    }

    /// `k` free paths through the grids per ray (delta tracking, `FreePath::sample_grids`),
    /// ray after ray; path j of a ray is keyed by (ray seed, j).
    pub fn free_paths(&mut self, rays: &[FpRay], k: u32, mode: Mode) -> Result<Vec<GpuFreePath>> {
        let items = items(rays.len(), k)?;
        let out = self.run(Kernel::FreePath, rays, &[0.0], items, k, 0, mode)?;
        Ok(out
            .iter()
            .map(|w| GpuFreePath {
                t: (w[1] != 0).then_some(f32::from_bits(w[0])),
                lookups: w[2],
                segments: w[3],
            })
            .collect())
    }

    /// `ratio_tr_to` of each ray at each of `dists[ray * m .. (ray + 1) * m]` (m =
    /// dists.len() / rays.len()), with the ray's seed: one realization per ray.
    pub fn ratio_tr(&mut self, rays: &[FpRay], dists: &[f32], mode: Mode) -> Result<Vec<GpuRatio>> {
        if rays.is_empty() || !dists.len().is_multiple_of(rays.len()) {
            return Err(Error::Other(
                "ratio_tr: the distances must be a whole number per ray".into(),
            ));
        }
        let m = (dists.len() / rays.len()) as u32;
        let items = items(rays.len(), m)?;
        let out = self.run(Kernel::Ratio, rays, dists, items, m, 0, mode)?;
        Ok(out
            .iter()
            .map(|w| GpuRatio {
                tr: f32::from_bits(w[0]),
                lookups: w[1],
            })
            .collect())
    }

    /// The majorant segments of grid `grid` along each ray over [0, tmax], at most `max`
    /// per ray (`Heterogeneous::majorants`).
    pub fn walk(
        &mut self,
        rays: &[FpRay],
        grid: u32,
        max: u32,
        mode: Mode,
    ) -> Result<Vec<Vec<GpuSegment>>> {
        let n = u32::try_from(rays.len()).map_err(|_| Error::Other("too many rays".into()))?;
        let out = self.run(Kernel::Walk, rays, &[0.0], n, max, grid, mode)?;
        Ok(out
            .chunks(max as usize + 1)
            .map(|c| {
                let count = (c[0][0] as usize).min(max as usize);
                c[1..=count]
                    .iter()
                    .map(|w| GpuSegment {
                        t0: f32::from_bits(w[0]),
                        t1: f32::from_bits(w[1]),
                        majorant: f32::from_bits(w[2]),
                        minorant: f32::from_bits(w[3]),
                    })
                    .collect()
            })
            .collect())
    }

    /// Runs `kernel` on `items` items (chunks of [`CHUNK`]) and reads back its output.
    #[allow(clippy::too_many_arguments)]
    fn run(
        &mut self,
        kernel: Kernel,
        rays: &[FpRay],
        dists: &[f32],
        items: u32,
        per_ray: u32,
        grid: u32,
        mode: Mode,
    ) -> Result<Vec<[u32; 4]>> {
        if rays.is_empty() || per_ray == 0 {
            return Ok(Vec::new());
        }
        let dev = &self.gpu.device;
        self.octrees.mode = mode_word(mode);
        self.gpu
            .queue
            .write_buffer(&self.octrees_buf, 0, bytemuck::bytes_of(&self.octrees));
        let rays_buf = storage_init(&self.gpu, "rays", bytemuck::cast_slice(rays))?;
        let dists_buf = storage_init(&self.gpu, "distances", bytemuck::cast_slice(dists))?;
        let slots = match kernel {
            Kernel::Walk => items as u64 * (per_ray as u64 + 1),
            _ => items as u64,
        };
        let size = slots * 16;
        if size > self.gpu.limits.max_storage_buffer_binding_size {
            return Err(Error::Gpu(format!(
                "free-path output needs {size} bytes, over the storage binding limit"
            )));
        }
        let out_buf = dev.create_buffer(&wgpu::BufferDescriptor {
            label: Some("free-path output"),
            size,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let jobs: Vec<FpJob> = (0..items.div_ceil(CHUNK))
            .map(|k| FpJob {
                first: k * CHUNK,
                count: CHUNK.min(items - k * CHUNK),
                per_ray,
                grid,
            })
            .collect();
        let table = uniform_table(&jobs, self.job_stride);
        let job_buf = dev.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("jobs"),
            contents: &table,
            usage: wgpu::BufferUsages::UNIFORM,
        });
        let job = wgpu::BindingResource::Buffer(wgpu::BufferBinding {
            buffer: &job_buf,
            offset: 0,
            size: wgpu::BufferSize::new(std::mem::size_of::<FpJob>() as u64),
        });
        let resources = [
            self.params_buf.as_entire_binding(),
            job,
            self.grid_buf.as_entire_binding(),
            self.nodes_buf.as_entire_binding(),
            self.octrees_buf.as_entire_binding(),
            rays_buf.as_entire_binding(),
            dists_buf.as_entire_binding(),
            out_buf.as_entire_binding(),
        ];
        let entries: Vec<wgpu::BindGroupEntry> = resources
            .into_iter()
            .enumerate()
            .map(|(i, resource)| wgpu::BindGroupEntry {
                binding: i as u32,
                resource,
            })
            .collect();
        let bind = dev.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("free paths"),
            layout: &self.layout,
            entries: &entries,
        });
        let pipeline = match kernel {
            Kernel::FreePath => &self.free_path,
            Kernel::Ratio => &self.ratio,
            Kernel::Walk => &self.walk,
        };
        let mut enc = dev.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: None });
        for (k, j) in jobs.iter().enumerate() {
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor::default());
            pass.set_pipeline(pipeline);
            pass.set_bind_group(0, &bind, &[(k as u64 * self.job_stride) as u32]);
            pass.dispatch_workgroups(j.count.div_ceil(WORKGROUP), 1, 1);
        }
        let data = read_back(&self.gpu, enc, &out_buf, size, "the free paths")?;
        self.check()?;
        Ok(data)
    }

    fn check(&self) -> Result<()> {
        match self.gpu.take_error() {
            Some(e) => Err(Error::Gpu(e)),
            None => Ok(()),
        }
    }
}

#[derive(Clone, Copy)]
enum Kernel {
    FreePath,
    Ratio,
    Walk,
}

fn items(rays: usize, per_ray: u32) -> Result<u32> {
    u32::try_from(rays as u64 * per_ray as u64)
        .map_err(|_| Error::Other("too many free-path items for one batch".into()))
}

/// Bindings 0-7 of `freepath_test.wgsl`; the job uniform (1) takes a dynamic offset.
fn bind_group_layout(dev: &wgpu::Device) -> wgpu::BindGroupLayout {
    let entry =
        |binding, ty, dynamic| buffer_entry(binding, wgpu::ShaderStages::COMPUTE, ty, dynamic);
    let entries = [
        entry(0, UNIFORM, false),
        entry(1, UNIFORM, true),
        entry(2, READ, false),
        entry(3, READ, false),
        entry(4, UNIFORM, false),
        entry(5, READ, false),
        entry(6, READ, false),
        entry(7, READ_WRITE, false),
    ];
    dev.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
        label: Some("free paths"),
        entries: &entries,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gpu::layout::Params;
    use crate::gpu::validated;
    use crate::majorant::Node;
    use std::mem::{offset_of, size_of};

    /// The free-path shader (test kernels + freepath.wgsl + media.wgsl) parses and
    /// validates, and its shared structs have the Rust `Pod` types' sizes and offsets.
    #[test]
    fn freepath_shader_validates_and_layouts_match() {
        let check = validated(SHADER);
        check(
            "Node",
            size_of::<Node>(),
            &[
                ("majorant", offset_of!(Node, majorant)),
                ("max", offset_of!(Node, max)),
                ("minorant", offset_of!(Node, minorant)),
                ("first_child", offset_of!(Node, first_child)),
                ("depth", offset_of!(Node, depth)),
            ],
        );
        check(
            "Octrees",
            size_of::<Octrees>(),
            &[
                ("roots", offset_of!(Octrees, roots)),
                ("majorants", offset_of!(Octrees, majorants)),
                ("mode", offset_of!(Octrees, mode)),
            ],
        );
        check(
            "FpRay",
            size_of::<FpRay>(),
            &[
                ("tmax", offset_of!(FpRay, tmax)),
                ("dir", offset_of!(FpRay, dir)),
                ("seed", offset_of!(FpRay, seed)),
            ],
        );
        check(
            "FpJob",
            size_of::<FpJob>(),
            &[
                ("count", offset_of!(FpJob, count)),
                ("per_ray", offset_of!(FpJob, per_ray)),
                ("grid", offset_of!(FpJob, grid)),
            ],
        );
        check("Params", size_of::<Params>(), &[]);
        assert_eq!(size_of::<Node>(), 48);
        // The library alone is what other kernels append.
        assert!(SHADER.contains(FREEPATH_WGSL));
    }

    /// The shader's roulette threshold is the CPU's.
    #[test]
    fn roulette_threshold_matches_the_cpu() {
        let line = format!(
            "const ROULETTE_BELOW: f32 = {:?};",
            crate::transport::freepath::ROULETTE_BELOW
        );
        assert!(FREEPATH_WGSL.contains(&line), "{line}");
    }
}
