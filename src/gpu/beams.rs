//! The beam estimate of eq. 2 on the GPU: a compute kernel with one invocation per camera
//! segment (primary and after specular bounces) walks the pass's beam BVH; a second one,
//! per pixel, adds its segments' results in order to a float32 accumulator that stays on
//! the GPU until a checkpoint reads it back. (A single per-pixel kernel looping over its
//! segments' traversals was miscompiled by Mesa's lavapipe and llvmpipe alike: it lost
//! crossings when a pixel had several segments, though each segment alone was right.)
//!
//! Why one BVH gather kernel rather than the original PPB's rasterized beam quads for
//! primary rays: one kernel serves every camera segment (primary and after glass) with the
//! same code as the CPU's BVH query, per-pixel sums are deterministic (no blending order),
//! and it needs no float32-blendable render target (wgpu's GL backend has none). What we
//! measured (`ppb bench-gpu`, README): on lavapipe, the only adapter here, this kernel is
//! 30-50x slower than the CPU splat (lavapipe runs the divergent traversal on SIMD lanes of
//! the same two cores), which is why `--device auto` skips software adapters. Rasterized
//! quads were not built, and no hardware GPU was available to compare the two on.
//!
//! Pipelining: [`GpuBeams::submit`] uploads a pass and returns at once; the caller traces
//! the next pass on the CPU while the GPU works, and the next `submit` (or a checkpoint)
//! waits for the previous one and reports how long it waited.
use std::thread::JoinHandle;
use std::time::{Duration, Instant};
use wgpu::util::DeviceExt;

use super::layout::{media_params, Chunk, Params, SegmentUpload};
use super::Gpu;
use crate::error::{Error, Result};
use crate::estimate::Estimator;
use crate::film::Film;
use crate::media::Media;
use crate::pass::{TracedPass, Tracer};
use glam::Vec3;

/// The kernel's source: its own file and the shared media code.
pub const SHADER: &str = concat!(
    include_str!("../../shaders/beam_estimate.wgsl"),
    include_str!("../../shaders/media.wgsl")
);

/// Segments or pixels per dispatch: long single dispatches can lose the device.
pub const CHUNK: u32 = 65536;
const WORKGROUP: u32 = 64;

/// When the GPU ran one pass's estimate, and how long the CPU waited for it.
#[derive(Clone, Copy, Debug)]
pub struct GpuTiming {
    pub submitted: Instant,
    pub done: Instant,
    pub waited: Duration,
    pub upload_seconds: f64,
}

/// How the GPU estimate overlapped the CPU's tracing of the next pass.
#[derive(serde::Serialize, Default, Clone, Debug)]
pub struct GpuStats {
    pub adapter: String,
    pub passes: u32,
    /// Sum over passes of submission to completion of the estimate.
    pub estimate_seconds: f64,
    /// The part of that during which the CPU was tracing the next pass.
    pub overlap_seconds: f64,
    /// Time the CPU sat waiting for the GPU.
    pub wait_seconds: f64,
    /// Building and uploading segments and the beam BVH.
    pub upload_seconds: f64,
    /// Beam-segment crossings within the radius, counted by the GPU (as of the last
    /// read-back).
    pub beam_evaluations: u64,
}

impl GpuStats {
    /// Adds one finished pass; `tracing` is the CPU's tracing interval that ran meanwhile.
    fn record(&mut self, t: Option<GpuTiming>, tracing: Option<(Instant, Instant)>) {
        let Some(t) = t else { return };
        self.passes += 1;
        self.estimate_seconds += (t.done - t.submitted).as_secs_f64();
        self.wait_seconds += t.waited.as_secs_f64();
        self.upload_seconds += t.upload_seconds;
        if let Some((a, b)) = tracing {
            let (lo, hi) = (a.max(t.submitted), b.min(t.done));
            if hi > lo {
                self.overlap_seconds += (hi - lo).as_secs_f64();
            }
        }
    }
}

struct InFlight {
    submitted: Instant,
    upload_seconds: f64,
    poller: JoinHandle<Instant>,
}

/// A storage buffer that grows to fit.
struct Grow {
    label: &'static str,
    buf: wgpu::Buffer,
}

impl Grow {
    fn new(dev: &wgpu::Device, label: &'static str) -> Self {
        Grow {
            label,
            buf: storage(dev, label, 256),
        }
    }

    fn write(&mut self, gpu: &Gpu, data: &[u8]) -> Result<()> {
        self.reserve(gpu, data.len() as u64)?;
        if !data.is_empty() {
            gpu.queue.write_buffer(&self.buf, 0, data);
        }
        Ok(())
    }

    /// Makes room for `bytes` (contents undefined).
    fn reserve(&mut self, gpu: &Gpu, bytes: u64) -> Result<()> {
        let need = bytes.max(16);
        if need > gpu.limits.max_storage_buffer_binding_size {
            return Err(Error::Gpu(format!(
                "{} needs {need} bytes, over the adapter's storage binding limit of {} \
                 (use a smaller image or --device cpu)",
                self.label, gpu.limits.max_storage_buffer_binding_size
            )));
        }
        if need > self.buf.size() {
            self.buf = storage(&gpu.device, self.label, need.next_power_of_two());
        }
        Ok(())
    }
}

fn storage(dev: &wgpu::Device, label: &str, size: u64) -> wgpu::Buffer {
    dev.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size,
        usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    })
}

pub struct GpuBeams {
    gpu: Gpu,
    per_segment: wgpu::ComputePipeline,
    per_pixel: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
    params: Params,
    params_buf: wgpu::Buffer,
    chunk_buf: wgpu::Buffer,
    chunk_stride: u64,
    grid_buf: wgpu::Buffer,
    accum: wgpu::Buffer,
    segments: Grow,
    pixel_first: Grow,
    seg_out: Grow,
    tr_steps: Grow,
    nodes: Grow,
    pieces: Grow,
    origin: Vec3,
    pixels: u32,
    in_flight: Option<InFlight>,
    stats: GpuStats,
}

impl GpuBeams {
    /// Compiles the kernel and uploads the media (fixed for a render).
    pub fn new(gpu: Gpu, media: &Media, origin: Vec3, pixels: u32) -> Result<Self> {
        let dev = &gpu.device;
        let scope = dev.push_error_scope(wgpu::ErrorFilter::Validation);
        let module = dev.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("beam_estimate.wgsl"),
            source: wgpu::ShaderSource::Wgsl(SHADER.into()),
        });
        let layout = bind_group_layout(dev);
        let pipeline_layout = dev.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("beam estimate"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let pipeline = |entry: &str| {
            dev.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(entry),
                layout: Some(&pipeline_layout),
                module: &module,
                entry_point: Some(entry),
                compilation_options: Default::default(),
                cache: None,
            })
        };
        let (per_segment, per_pixel) = (pipeline("segment_main"), pipeline("pixel_main"));
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(Error::Gpu(format!("beam_estimate.wgsl: {e}")));
        }
        let (params, grid_words) = media_params(media)?;
        let grid_bytes: &[u8] = if grid_words.is_empty() {
            &[0; 16]
        } else {
            bytemuck::cast_slice(&grid_words)
        };
        if grid_bytes.len() as u64 > gpu.limits.max_storage_buffer_binding_size {
            return Err(Error::Gpu(format!(
                "the density grids need {} bytes, over the adapter's storage binding limit \
                 of {} (use --device cpu)",
                grid_bytes.len(),
                gpu.limits.max_storage_buffer_binding_size
            )));
        }
        let grid_buf = dev.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("grid data"),
            contents: grid_bytes,
            usage: wgpu::BufferUsages::STORAGE,
        });
        let params_buf = dev.create_buffer(&wgpu::BufferDescriptor {
            label: Some("params"),
            size: std::mem::size_of::<Params>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let chunk_stride = (gpu.limits.min_uniform_buffer_offset_alignment as u64)
            .max(std::mem::size_of::<Chunk>() as u64);
        let chunk_buf = uniform_chunks(dev, 2 * chunk_stride);
        let accum = dev.create_buffer(&wgpu::BufferDescriptor {
            label: Some("accum"),
            size: pixels as u64 * 16,
            usage: wgpu::BufferUsages::STORAGE
                | wgpu::BufferUsages::COPY_SRC
                | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let adapter = gpu.describe();
        Ok(GpuBeams {
            segments: Grow::new(dev, "segments"),
            pixel_first: Grow::new(dev, "pixel ranges"),
            seg_out: Grow::new(dev, "segment results"),
            tr_steps: Grow::new(dev, "transmittance steps"),
            nodes: Grow::new(dev, "beam BVH"),
            pieces: Grow::new(dev, "beam pieces"),
            gpu,
            per_segment,
            per_pixel,
            layout,
            params,
            params_buf,
            chunk_buf,
            chunk_stride,
            grid_buf,
            accum,
            origin,
            pixels,
            in_flight: None,
            stats: GpuStats {
                adapter,
                ..Default::default()
            },
        })
    }

    pub fn gpu(&self) -> &Gpu {
        &self.gpu
    }

    /// Uploads pass `t` and dispatches its estimate into the accumulator; returns the
    /// previous pass's timing (after waiting for it) if one was in flight.
    pub fn submit(&mut self, t: &TracedPass, media: &Media) -> Result<Option<GpuTiming>> {
        let prev = self.wait()?;
        let start = Instant::now();
        let map = match &t.beam_map {
            Some(m) if !t.beams.is_empty() && !media.is_empty() => m,
            _ => return Ok(prev),
        };
        let nodes = map.nodes();
        let segs = SegmentUpload::build(self.origin, &t.camera, media);
        if segs.pixel_first.len() != self.pixels as usize + 1 {
            return Err(Error::Gpu("pass size differs from the estimator's".into()));
        }
        self.params.radius = t.beam_radius;
        self.gpu
            .queue
            .write_buffer(&self.params_buf, 0, bytemuck::bytes_of(&self.params));
        self.segments
            .write(&self.gpu, bytemuck::cast_slice(&segs.segments))?;
        self.pixel_first
            .write(&self.gpu, bytemuck::cast_slice(&segs.pixel_first))?;
        self.tr_steps
            .write(&self.gpu, bytemuck::cast_slice(&segs.tr_steps))?;
        self.nodes.write(&self.gpu, bytemuck::cast_slice(&nodes))?;
        self.pieces
            .write(&self.gpu, bytemuck::cast_slice(map.pieces()))?;
        let n_segs = segs.segments.len() as u32;
        self.seg_out.reserve(&self.gpu, n_segs as u64 * 16)?;
        let seg_chunks = chunks(n_segs);
        let pixel_chunks = chunks(self.pixels);
        let table: Vec<u8> = seg_chunks
            .iter()
            .chain(&pixel_chunks)
            .flat_map(|c| {
                let mut b = bytemuck::bytes_of(c).to_vec();
                b.resize(self.chunk_stride as usize, 0);
                b
            })
            .collect();
        if table.len() as u64 > self.chunk_buf.size() {
            let size = (table.len() as u64).next_power_of_two();
            self.chunk_buf = uniform_chunks(&self.gpu.device, size);
        }
        self.gpu.queue.write_buffer(&self.chunk_buf, 0, &table);
        let bind = self.bind_group();
        let mut enc = self
            .gpu
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: None });
        let passes = seg_chunks
            .iter()
            .map(|c| (&self.per_segment, c))
            .chain(pixel_chunks.iter().map(|c| (&self.per_pixel, c)));
        for (k, (pipeline, c)) in passes.enumerate() {
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor::default());
            pass.set_pipeline(pipeline);
            pass.set_bind_group(0, &bind, &[(k as u64 * self.chunk_stride) as u32]);
            pass.dispatch_workgroups(c.count.div_ceil(WORKGROUP), 1, 1);
        }
        let index = self.gpu.queue.submit([enc.finish()]);
        let submitted = Instant::now();
        let device = self.gpu.device.clone();
        let poller = std::thread::spawn(move || {
            let _ = device.poll(wgpu::PollType::Wait {
                submission_index: Some(index),
                timeout: None,
            });
            Instant::now()
        });
        self.in_flight = Some(InFlight {
            submitted,
            upload_seconds: (submitted - start).as_secs_f64(),
            poller,
        });
        self.check()?;
        Ok(prev)
    }

    /// Waits for the pass in flight, if any.
    pub fn wait(&mut self) -> Result<Option<GpuTiming>> {
        let Some(f) = self.in_flight.take() else {
            return Ok(None);
        };
        let t0 = Instant::now();
        let done = f
            .poller
            .join()
            .map_err(|_| Error::Gpu("the GPU poll thread panicked".into()))?;
        let waited = t0.elapsed();
        self.check()?;
        Ok(Some(GpuTiming {
            submitted: f.submitted,
            done,
            waited,
            upload_seconds: f.upload_seconds,
        }))
    }

    /// The accumulated beam radiance per pixel (sum over the submitted passes), after
    /// waiting for the pass in flight.
    pub fn read(&mut self) -> Result<(Vec<[f32; 4]>, Option<GpuTiming>)> {
        let timing = self.wait()?;
        let size = self.pixels as u64 * 16;
        let staging = self.gpu.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("readback"),
            size,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut enc = self
            .gpu
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: None });
        enc.copy_buffer_to_buffer(&self.accum, 0, &staging, 0, size);
        self.gpu.queue.submit([enc.finish()]);
        let slice = staging.slice(..);
        let (tx, rx) = std::sync::mpsc::channel();
        slice.map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        self.gpu
            .device
            .poll(wgpu::PollType::wait_indefinitely())
            .map_err(|e| Error::Gpu(format!("waiting for the readback: {e}")))?;
        rx.recv()
            .map_err(|_| Error::Gpu("readback never completed".into()))?
            .map_err(|e| Error::Gpu(format!("mapping the accumulator: {e}")))?;
        let view = slice
            .get_mapped_range()
            .map_err(|e| Error::Gpu(format!("reading the accumulator: {e}")))?;
        let data = bytemuck::cast_slice::<u8, [f32; 4]>(&view).to_vec();
        drop(view);
        staging.unmap();
        self.check()?;
        Ok((data, timing))
    }

    /// Zeroes the accumulator (a new render, or a test that wants one pass).
    pub fn clear(&mut self) -> Result<()> {
        self.wait()?;
        let mut enc = self
            .gpu
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: None });
        enc.clear_buffer(&self.accum, 0, None);
        self.gpu.queue.submit([enc.finish()]);
        self.check()
    }

    fn check(&self) -> Result<()> {
        match self.gpu.take_error() {
            Some(e) => Err(Error::Gpu(e)),
            None => Ok(()),
        }
    }

    fn bind_group(&self) -> wgpu::BindGroup {
        fn whole(b: &wgpu::Buffer) -> wgpu::BindingResource<'_> {
            b.as_entire_binding()
        }
        let chunk = wgpu::BindingResource::Buffer(wgpu::BufferBinding {
            buffer: &self.chunk_buf,
            offset: 0,
            size: wgpu::BufferSize::new(std::mem::size_of::<Chunk>() as u64),
        });
        let resources = [
            whole(&self.params_buf),
            chunk,
            whole(&self.segments.buf),
            whole(&self.pixel_first.buf),
            whole(&self.tr_steps.buf),
            whole(&self.nodes.buf),
            whole(&self.pieces.buf),
            whole(&self.grid_buf),
            whole(&self.accum),
            whole(&self.seg_out.buf),
        ];
        let entries: Vec<wgpu::BindGroupEntry> = resources
            .into_iter()
            .enumerate()
            .map(|(i, resource)| wgpu::BindGroupEntry {
                binding: i as u32,
                resource,
            })
            .collect();
        self.gpu
            .device
            .create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("beam estimate"),
                layout: &self.layout,
                entries: &entries,
            })
    }
}

impl Estimator for GpuBeams {
    fn describe(&self) -> String {
        self.gpu.describe()
    }

    fn needs_beam_map(&self) -> bool {
        true
    }

    fn estimate(
        &mut self,
        tracer: &Tracer,
        t: &TracedPass,
        _film: &mut Film,
        traced: (Instant, Instant),
    ) -> Result<u64> {
        let prev = self.submit(t, tracer.media())?;
        self.stats.record(prev, Some(traced));
        Ok(0)
    }

    fn held(&mut self) -> Result<Option<Vec<[f32; 4]>>> {
        let (acc, timing) = self.read()?;
        self.stats.record(timing, None);
        self.stats.beam_evaluations = acc.iter().map(|a| a[3] as f64).sum::<f64>() as u64;
        Ok(Some(acc))
    }

    fn clear(&mut self) -> Result<()> {
        GpuBeams::clear(self)
    }

    fn gpu_stats(&self) -> Option<GpuStats> {
        Some(self.stats.clone())
    }
}

/// `count` items in dispatches of at most [`CHUNK`].
fn chunks(count: u32) -> Vec<Chunk> {
    (0..count.div_ceil(CHUNK))
        .map(|k| Chunk {
            first: k * CHUNK,
            count: CHUNK.min(count - k * CHUNK),
            _pad: [0; 2],
        })
        .collect()
}

fn uniform_chunks(dev: &wgpu::Device, size: u64) -> wgpu::Buffer {
    dev.create_buffer(&wgpu::BufferDescriptor {
        label: Some("chunks"),
        size,
        usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    })
}

/// Bindings 0-9 of `beam_estimate.wgsl`; the chunk uniform (1) takes a dynamic offset.
fn bind_group_layout(dev: &wgpu::Device) -> wgpu::BindGroupLayout {
    let entry =
        |binding: u32, ty: wgpu::BufferBindingType, dynamic: bool| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Buffer {
                ty,
                has_dynamic_offset: dynamic,
                min_binding_size: None,
            },
            count: None,
        };
    let read = wgpu::BufferBindingType::Storage { read_only: true };
    let entries = [
        entry(0, wgpu::BufferBindingType::Uniform, false),
        entry(1, wgpu::BufferBindingType::Uniform, true),
        entry(2, read, false),
        entry(3, read, false),
        entry(4, read, false),
        entry(5, read, false),
        entry(6, read, false),
        entry(7, read, false),
        entry(
            8,
            wgpu::BufferBindingType::Storage { read_only: false },
            false,
        ),
        entry(
            9,
            wgpu::BufferBindingType::Storage { read_only: false },
            false,
        ),
    ];
    dev.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
        label: Some("beam estimate"),
        entries: &entries,
    })
}
