//! The beam estimate of eq. 2 on the GPU: a compute kernel with one invocation per camera
//! segment (primary and after specular bounces) walks the pass's beam BVH; a second one,
//! per pixel, adds its segments' results in order to a float32 accumulator that stays on
//! the GPU until a checkpoint reads it back. (A single per-pixel kernel looping over its
//! segments' traversals was miscompiled by Mesa's lavapipe and llvmpipe alike: it lost
//! crossings when a pixel had several segments, though each segment alone was right.)
//!
//! Primary segments can instead be rasterised ([`PrimaryPath::Raster`], the original
//! PPB's beam quads): every beam becomes a film rectangle, the one the CPU splat's band
//! lies in (`estimate::splat`), and a fragment per covered pixel evaluates the same term
//! for that pixel's primary segment into an additively blended float32 target. Blending
//! follows primitive order, so sums are in beam order as on the CPU. It needs
//! float32-blendable targets (wgpu's GL backend has none), so the gather stays for those
//! adapters and for segments after specular bounces.
//!
//! The camera transmittance is the CPU's estimate, uploaded as steps, or ratio tracking on
//! the GPU ([`CameraTr::Track`], `shaders/freepath.wgsl`) over the octrees uploaded once.
//!
//! Pipelining: [`GpuBeams::submit`] uploads a pass and returns at once; the caller traces
//! the next pass on the CPU while the GPU works, and the next `submit` (or a checkpoint)
//! waits for the previous one and reports how long it waited.
mod options;
mod raster;
mod stats;

pub use options::{CameraTr, GpuOptions, PrimaryPath};
pub use stats::{GpuStats, GpuTiming};

use raster::{sums_texture, Raster};

use std::thread::JoinHandle;
use std::time::Instant;
use wgpu::util::DeviceExt;

use super::buffers::{
    bind_group, buffer_entry, read_back, storage_init, uniform_stride, uniform_table, Grow, CHUNK,
    READ, READ_WRITE, UNIFORM,
};
use super::layout::{
    kernel_word, media_params, mode_word, octree_upload, BeamQuad, Chunk, Params, SegmentUpload,
};
use super::{compute_pipelines, Gpu};
use crate::error::{Error, Result};
use crate::estimate::beams::{MapNeed, Walker};
use crate::estimate::Estimator;
use crate::estimate::{TracedPass, View};
use crate::film::{Film, Held};
use crate::majorant::Mode;
use crate::media::Media;
use crate::sampling::mix64;
use crate::transport::camera::Pinhole;

/// The kernel's source: its own file and the shared media code.
pub const SHADER: &str = concat!(
    include_str!("../../../shaders/beam_estimate.wgsl"),
    include_str!("../../../shaders/freepath.wgsl"),
    include_str!("../../../shaders/media.wgsl")
);

const WORKGROUP: u32 = 64;
/// A segment's result and a pixel's accumulator: the estimate's RGB and count, then the
/// nested difference's RGB and a pad (two vec4).
const PIXEL_SUM_BYTES: u64 = 32;
/// BVH walk iterations per segment per round on software adapters, which end an
/// invocation's loops after 65,535 iterations in all, its crossings' own loops included:
/// walks were cut at 4,600-4,800 iterations where crossings were dense.
pub const SOFTWARE_WALK_BUDGET: u32 = 1024;
/// The budget below which a walk the adapter still cuts is an error.
const MIN_WALK_BUDGET: u32 = 8;

struct InFlight {
    /// How its primaries were estimated, and its beams (the trial's unit of work).
    path: PrimaryPath,
    beams: usize,
    submitted: Instant,
    upload_seconds: f64,
    poller: JoinHandle<Instant>,
}

pub struct GpuBeams {
    gpu: Gpu,
    camera: Pinhole,
    /// How primaries are estimated now (raster or gather) ...
    path: PrimaryPath,
    /// ... and, for auto, GPU seconds per beam of the trial's raster and gather passes,
    /// until both are known and the faster is kept.
    trial: Option<[Option<f64>; 2]>,
    /// What rasterising needs, where it is possible and asked for.
    raster: Option<Raster>,
    /// The rasterised primary sums `pixel_main` adds, the estimate's and the nested
    /// difference's (1x1 textures it never reads when primaries are gathered).
    primary_sums: [wgpu::TextureView; 2],
    per_segment: wgpu::ComputePipeline,
    per_pixel: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
    params: Params,
    params_buf: wgpu::Buffer,
    chunk_buf: wgpu::Buffer,
    chunk_stride: u64,
    grid_buf: wgpu::Buffer,
    octree_nodes: wgpu::Buffer,
    octrees: wgpu::Buffer,
    seed: u64,
    /// The walk budget each pass starts from (`Params::walk_budget`).
    walk_budget: u32,
    /// Beam sums of the even and of the odd passes (the film's half-films).
    accum: [wgpu::Buffer; 2],
    /// Whether the pass submitted last is odd (`PassPlan::odd`): the accumulator it adds to.
    odd: bool,
    /// Passes estimated into the accumulators since they were cleared.
    passes: u32,
    segments: Grow,
    pixel_first: Grow,
    seg_out: Grow,
    walk_state: Grow,
    /// How many walks a dispatch round left unfinished (one u32).
    unfinished: wgpu::Buffer,
    tr_steps: Grow,
    nodes: Grow,
    pieces: Grow,
    pixels: u32,
    in_flight: Option<InFlight>,
    stats: GpuStats,
}

impl GpuBeams {
    /// Compiles the kernels and uploads the media and their octrees (fixed for a render)
    /// for images of `camera`, estimating as `opts` says.
    pub fn new(gpu: Gpu, media: &Media, camera: &Pinhole, opts: GpuOptions) -> Result<Self> {
        let (width, height) = (camera.width(), camera.height());
        let pixels = width * height;
        let primary = opts.primary.resolve(&gpu, width, height)?;
        let dev = &gpu.device;
        let scope = dev.push_error_scope(wgpu::ErrorFilter::Validation);
        let layout = bind_group_layout(dev);
        let entries = ["segment_main", "pixel_main"];
        let (module, pipelines) =
            compute_pipelines(dev, "beam_estimate.wgsl", SHADER, &layout, &entries);
        let [per_segment, per_pixel]: [wgpu::ComputePipeline; 2] = pipelines
            .try_into()
            .map_err(|_| Error::Gpu("two pipelines".into()))?;
        let raster = (primary != PrimaryPath::Gather).then(|| Raster::new(dev, &module, camera));
        let primary_sums = match &raster {
            Some(r) => r.targets.clone(),
            None => [0, 1].map(|_| sums_texture(dev, 1, 1, false)),
        };
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(Error::Gpu(format!("beam_estimate.wgsl: {e}")));
        }
        let (mut params, grid_words) = media_params(media)?;
        params.track_tr = u32::from(opts.camera_tr == CameraTr::Track);
        let software = gpu.info.device_type == wgpu::DeviceType::Cpu;
        params.walk_budget = opts.walk_budget.unwrap_or(if software {
            SOFTWARE_WALK_BUDGET
        } else {
            u32::MAX
        });
        let grid_buf = storage_init(&gpu, "the density grids", bytemuck::cast_slice(&grid_words))?;
        let (octree_nodes, octrees) = octree_buffers(&gpu, media, opts.free_path)?;
        let params_buf = dev.create_buffer(&wgpu::BufferDescriptor {
            label: Some("params"),
            size: std::mem::size_of::<Params>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let chunk_stride = uniform_stride::<Chunk>(&gpu);
        let chunk_buf = uniform_chunks(dev, 2 * chunk_stride);
        let accum = ["even", "odd"].map(|k| {
            let label = format!("{k} passes' sums");
            read_write(dev, &label, pixels as u64 * PIXEL_SUM_BYTES)
        });
        let adapter = gpu.describe();
        Ok(GpuBeams {
            segments: Grow::new(dev, "segments"),
            pixel_first: Grow::new(dev, "pixel ranges"),
            seg_out: Grow::new(dev, "segment results"),
            walk_state: Grow::new(dev, "walk states"),
            unfinished: read_write(dev, "walks left", 16),
            tr_steps: Grow::new(dev, "transmittance steps"),
            nodes: Grow::new(dev, "beam BVH"),
            pieces: Grow::new(dev, "beam pieces"),
            gpu,
            camera: *camera,
            path: if primary == PrimaryPath::Auto {
                PrimaryPath::Raster
            } else {
                primary
            },
            trial: (primary == PrimaryPath::Auto).then_some([None; 2]),
            raster,
            primary_sums,
            per_segment,
            per_pixel,
            layout,
            params,
            params_buf,
            chunk_buf,
            chunk_stride,
            grid_buf,
            octree_nodes,
            octrees,
            seed: opts.seed,
            walk_budget: params.walk_budget,
            accum,
            odd: false,
            passes: 0,
            pixels,
            in_flight: None,
            stats: GpuStats {
                adapter,
                primary: Some(primary),
                camera_tr: Some(opts.camera_tr),
                ..Default::default()
            },
        })
    }

    pub fn gpu(&self) -> &Gpu {
        &self.gpu
    }

    /// How primary segments are estimated: [`PrimaryPath::Auto`] while auto's trial runs.
    pub fn primary(&self) -> PrimaryPath {
        match self.trial {
            Some(_) => PrimaryPath::Auto,
            None => self.path,
        }
    }

    /// The way the next pass's primaries go: auto's trial rasterises its first pass and
    /// gathers its second; once both are timed it keeps the faster per beam.
    fn next_path(&mut self) -> PrimaryPath {
        if let Some([Some(raster), Some(gather)]) = self.trial {
            self.trial = None;
            self.path = if raster <= gather {
                PrimaryPath::Raster
            } else {
                PrimaryPath::Gather
            };
            self.stats.primary = Some(self.path);
        } else if let Some([Some(_), None]) = self.trial {
            self.path = PrimaryPath::Gather;
        }
        self.path
    }

    /// How this estimate overlapped tracing, and its counts so far.
    pub fn stats(&self) -> &GpuStats {
        &self.stats
    }

    /// Uploads pass `t` and dispatches its estimate under `view`'s media and kernel into
    /// the accumulator; returns the previous pass's timing (after waiting for it) if one
    /// was in flight.
    pub fn submit(&mut self, view: View, t: &TracedPass) -> Result<Option<GpuTiming>> {
        let media = view.media;
        let prev = self.wait()?;
        self.passes += 1;
        let start = Instant::now();
        let path = self.next_path();
        let raster = path == PrimaryPath::Raster;
        if t.beams.is_empty() || media.is_empty() || (!raster && t.beam_map.is_none()) {
            return Ok(prev);
        }
        self.params.kernel = kernel_word(view.kernel);
        let (n_segs, quads) = self.upload(t, media, raster)?;
        self.odd = t.odd;
        let seg_chunks = chunks(n_segs);
        let pixel_chunks = chunks(self.pixels);
        self.write_chunk_table(&seg_chunks, &pixel_chunks);
        let bind = self.bind_group();
        let mut enc = self.encoder();
        if let Some(r) = self.raster.as_ref().filter(|_| raster) {
            self.draw_quads(r, &mut enc, quads);
        }
        enc.clear_buffer(&self.seg_out.buf, 0, None);
        enc.clear_buffer(&self.walk_state.buf, 0, None);
        let (mut enc, first_round) = self.walk_segments(enc, &bind, &seg_chunks)?;
        let first = seg_chunks.len();
        self.dispatch(&mut enc, &bind, &self.per_pixel, &pixel_chunks, first);
        let index = self.gpu.queue.submit([enc.finish()]);
        // Rounds run before the last submission: the estimate starts with the first.
        let submitted = first_round.unwrap_or_else(Instant::now);
        self.in_flight = Some(InFlight {
            path,
            beams: t.beams.len(),
            submitted,
            upload_seconds: (submitted - start).as_secs_f64(),
            poller: poll_in_background(self.gpu.device.clone(), index),
        });
        self.check()?;
        Ok(prev)
    }

    /// Uploads what pass `t`'s estimate reads (parameters, segments, transmittance steps,
    /// the beam BVH, quads when `raster`) and counts the bytes; returns the number of
    /// segments and of quads.
    fn upload(&mut self, t: &TracedPass, media: &Media, raster: bool) -> Result<(u32, u32)> {
        let (nodes, pieces) = match &t.beam_map {
            Some(map) => {
                let nodes = map.nodes().ok_or_else(|| {
                    Error::Gpu("the pass's beam map was built for the CPU's walk".into())
                })?;
                (nodes, map.pieces())
            }
            None => (Vec::new(), &[][..]),
        };
        let origin = self.camera.origin();
        let steps = self.params.track_tr == 0;
        let segs = SegmentUpload::build(origin, &t.camera, media, raster, steps);
        if segs.pixel_first.len() != self.pixels as usize + 1 {
            return Err(Error::Gpu("pass size differs from the estimator's".into()));
        }
        self.params.radius = t.beam_radius;
        self.params.raster_width = if raster { self.camera.width() } else { 0 };
        self.params.pass_seed = mix64(self.seed ^ mix64(u64::from(t.index))) as u32;
        self.gpu
            .queue
            .write_buffer(&self.params_buf, 0, bytemuck::bytes_of(&self.params));
        let gpu = &self.gpu;
        self.segments
            .write(gpu, bytemuck::cast_slice(&segs.segments))?;
        self.pixel_first
            .write(gpu, bytemuck::cast_slice(&segs.pixel_first))?;
        self.tr_steps
            .write(gpu, bytemuck::cast_slice(&segs.tr_steps))?;
        self.nodes.write(gpu, bytemuck::cast_slice(&nodes))?;
        self.pieces.write(gpu, bytemuck::cast_slice(pieces))?;
        let quads = if raster {
            self.write_quads(t, &segs)?
        } else {
            0
        };
        let tr_bytes = std::mem::size_of_val(&segs.tr_steps[..]) as u64;
        self.stats.tr_step_bytes += tr_bytes;
        self.stats.upload_bytes += tr_bytes
            + (std::mem::size_of_val(&segs.segments[..])
                + std::mem::size_of_val(&segs.pixel_first[..])
                + std::mem::size_of_val(&segs.primaries[..])
                + std::mem::size_of_val(&nodes[..])
                + std::mem::size_of_val(pieces)
                + quads as usize * std::mem::size_of::<BeamQuad>()) as u64;
        let n_segs = segs.segments.len() as u32;
        self.seg_out
            .reserve(&self.gpu, n_segs as u64 * PIXEL_SUM_BYTES)?;
        self.walk_state.reserve(&self.gpu, n_segs as u64 * 8)?;
        Ok((n_segs, quads))
    }

    /// Writes the chunk table: the segment kernel's chunks, then the pixel kernel's.
    fn write_chunk_table(&mut self, seg_chunks: &[Chunk], pixel_chunks: &[Chunk]) {
        let table = uniform_table(seg_chunks.iter().chain(pixel_chunks), self.chunk_stride);
        if table.len() as u64 > self.chunk_buf.size() {
            let size = (table.len() as u64).next_power_of_two();
            self.chunk_buf = uniform_chunks(&self.gpu.device, size);
        }
        self.gpu.queue.write_buffer(&self.chunk_buf, 0, &table);
    }

    fn encoder(&self) -> wgpu::CommandEncoder {
        self.gpu
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: None })
    }

    /// Records the segment kernel's BVH walks. On hardware that is one dispatch into
    /// `enc`. On a software adapter the walks run in rounds of `walk_budget` iterations:
    /// each round is submitted and read back, and rounds go on while walks remain, with
    /// half the budget after a round in which the adapter cut some. Returns the encoder to
    /// record the rest into and when the first round was submitted.
    fn walk_segments(
        &mut self,
        mut enc: wgpu::CommandEncoder,
        bind: &wgpu::BindGroup,
        seg_chunks: &[Chunk],
    ) -> Result<(wgpu::CommandEncoder, Option<Instant>)> {
        let rounds = self.params.walk_budget != u32::MAX && !seg_chunks.is_empty();
        let mut budget = self.params.walk_budget;
        let mut first_round: Option<Instant> = None;
        loop {
            enc.clear_buffer(&self.unfinished, 0, None);
            self.dispatch(&mut enc, bind, &self.per_segment, seg_chunks, 0);
            if !rounds {
                break;
            }
            first_round.get_or_insert_with(Instant::now);
            let left: Vec<u32> = read_back(&self.gpu, enc, &self.unfinished, 8, "walks left")?;
            enc = self.encoder();
            if left[1] > 0 {
                budget /= 2;
                if budget < MIN_WALK_BUDGET {
                    return Err(self.loop_cut());
                }
                self.params.walk_budget = budget;
                let bytes = bytemuck::bytes_of(&self.params);
                self.gpu.queue.write_buffer(&self.params_buf, 0, bytes);
            } else if left[0] == 0 {
                break;
            }
        }
        self.params.walk_budget = self.walk_budget;
        Ok((enc, first_round))
    }

    /// Dispatches `pipeline` over `chunks`, whose entries in the chunk table start at
    /// `first`.
    fn dispatch(
        &self,
        enc: &mut wgpu::CommandEncoder,
        bind: &wgpu::BindGroup,
        pipeline: &wgpu::ComputePipeline,
        chunks: &[Chunk],
        first: usize,
    ) {
        for (k, c) in chunks.iter().enumerate() {
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor::default());
            pass.set_pipeline(pipeline);
            let offset = ((first + k) as u64 * self.chunk_stride) as u32;
            pass.set_bind_group(0, bind, &[offset]);
            pass.dispatch_workgroups(c.count.div_ceil(WORKGROUP), 1, 1);
        }
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
        if let Some(trial) = &mut self.trial {
            let k = usize::from(f.path == PrimaryPath::Gather);
            let per_beam = (done - f.submitted).as_secs_f64() / f.beams.max(1) as f64;
            trial[k].get_or_insert(per_beam);
        }
        Ok(Some(GpuTiming {
            submitted: f.submitted,
            done,
            waited,
            upload_seconds: f.upload_seconds,
        }))
    }

    /// The accumulated beam radiance per pixel (sum over the submitted passes; RGB and
    /// the evaluation count), after waiting for the pass in flight.
    pub fn read(&mut self) -> Result<(Vec<[f32; 4]>, Option<GpuTiming>)> {
        let (held, timing) = self.read_halves()?;
        let [even, odd] = held.halves;
        let sum = even
            .iter()
            .zip(&odd)
            .map(|(a, b)| [0, 1, 2, 3].map(|c| a[c] + b[c]))
            .collect();
        Ok((sum, timing))
    }

    /// The accumulated sums of the even and of the odd passes, with the nested
    /// difference's, after waiting for the pass in flight.
    pub fn read_halves(&mut self) -> Result<(Held, Option<GpuTiming>)> {
        let timing = self.wait()?;
        let size = self.pixels as u64 * PIXEL_SUM_BYTES;
        let mut halves: [Vec<[f32; 8]>; 2] = [Vec::new(), Vec::new()];
        for (half, buf) in halves.iter_mut().zip(&self.accum) {
            let enc = self.encoder();
            *half = read_back(&self.gpu, enc, buf, size, "the accumulator")?;
            // A cut walk marks the estimate (never negative) with LOOP_CUT.
            if half.iter().any(|p| p[..4].iter().any(|&v| v < 0.0)) {
                return Err(self.loop_cut());
            }
        }
        self.check()?;
        let passes = self.passes;
        Ok((Held { halves, passes }, timing))
    }

    /// The error for sums the adapter's loop limit made wrong.
    fn loop_cut(&self) -> Error {
        let (w, h) = (self.camera.width(), self.camera.height());
        let could_raster = PrimaryPath::Raster.resolve(&self.gpu, w, h).is_ok();
        let raster = match self.path {
            PrimaryPath::Gather if could_raster => "--gpu-primary raster, ",
            _ => "",
        };
        Error::Gpu(format!(
            "{} ended a shader loop before its work was done (Mesa's lavapipe and llvmpipe \
             stop loops after 65,535 iterations), so some beam sums are wrong; use \
             {raster}fewer light paths per pass or --device cpu",
            self.gpu.describe()
        ))
    }

    /// Zeroes the accumulator (a new render, or a test that wants one pass).
    pub fn clear(&mut self) -> Result<()> {
        self.wait()?;
        let mut enc = self
            .gpu
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: None });
        for buf in &self.accum {
            enc.clear_buffer(buf, 0, None);
        }
        self.gpu.queue.submit([enc.finish()]);
        self.passes = 0;
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
            whole(&self.accum[usize::from(self.odd)]),
            whole(&self.seg_out.buf),
            wgpu::BindingResource::TextureView(&self.primary_sums[0]),
        ];
        let entries: Vec<(u32, wgpu::BindingResource)> = resources
            .into_iter()
            .enumerate()
            .map(|(i, r)| (i as u32, r))
            .chain([
                (13, whole(&self.octree_nodes)),
                (14, whole(&self.octrees)),
                (15, whole(&self.walk_state.buf)),
                (16, whole(&self.unfinished)),
                (
                    17,
                    wgpu::BindingResource::TextureView(&self.primary_sums[1]),
                ),
            ])
            .collect();
        bind_group(&self.gpu.device, &self.layout, &entries)
    }
}

impl Estimator for GpuBeams {
    fn describe(&self) -> String {
        self.gpu.describe()
    }

    /// Gathered segments walk the beam BVH; rasterised primaries do not (auto's trial
    /// keeps it until the choice is made), but segments after specular surfaces do.
    fn beam_map(&self) -> MapNeed {
        MapNeed {
            walker: Walker::Gpu,
            every_pass: self.path == PrimaryPath::Gather || self.trial.is_some(),
        }
    }

    fn estimate(
        &mut self,
        view: View,
        t: &TracedPass,
        _film: &mut Film,
        traced: (Instant, Instant),
    ) -> Result<u64> {
        let prev = self.submit(view, t)?;
        self.stats.record(prev, Some(traced));
        Ok(0)
    }

    fn held(&mut self) -> Result<Option<Held>> {
        let (acc, timing) = self.read_halves()?;
        self.stats.record(timing, None);
        let evals = acc
            .halves
            .iter()
            .flatten()
            .map(|a| a[3] as f64)
            .sum::<f64>();
        self.stats.beam_evaluations = evals as u64;
        Ok(Some(acc))
    }

    fn clear(&mut self) -> Result<()> {
        GpuBeams::clear(self)
    }
}

/// The majorant octrees' nodes (a storage buffer) and their table (a uniform), for the
/// free-path mode `mode`.
fn octree_buffers(gpu: &Gpu, media: &Media, mode: Mode) -> Result<(wgpu::Buffer, wgpu::Buffer)> {
    let (mut block, nodes) = octree_upload(media)?;
    block.mode = mode_word(mode);
    let nodes = storage_init(gpu, "the majorant octrees", bytemuck::cast_slice(&nodes))?;
    let table = gpu
        .device
        .create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("octrees"),
            contents: bytemuck::bytes_of(&block),
            usage: wgpu::BufferUsages::UNIFORM,
        });
    Ok((nodes, table))
}

/// A storage buffer the kernels write and the host clears and reads back.
fn read_write(dev: &wgpu::Device, label: &str, size: u64) -> wgpu::Buffer {
    dev.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size,
        usage: wgpu::BufferUsages::STORAGE
            | wgpu::BufferUsages::COPY_SRC
            | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    })
}

/// A thread that waits for submission `index` and returns when it finished.
fn poll_in_background(device: wgpu::Device, index: wgpu::SubmissionIndex) -> JoinHandle<Instant> {
    std::thread::spawn(move || {
        let _ = device.poll(wgpu::PollType::Wait {
            submission_index: Some(index),
            timeout: None,
        });
        Instant::now()
    })
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

/// Bindings 0-10 and 13-17 of `beam_estimate.wgsl` for the kernels; the chunk uniform
/// (1) takes a dynamic offset.
fn bind_group_layout(dev: &wgpu::Device) -> wgpu::BindGroupLayout {
    let entry =
        |binding, ty, dynamic| buffer_entry(binding, wgpu::ShaderStages::COMPUTE, ty, dynamic);
    let entries = [
        entry(0, UNIFORM, false),
        entry(1, UNIFORM, true),
        entry(2, READ, false),
        entry(3, READ, false),
        entry(4, READ, false),
        entry(5, READ, false),
        entry(6, READ, false),
        entry(7, READ, false),
        entry(8, READ_WRITE, false),
        entry(9, READ_WRITE, false),
        entry(13, READ, false),
        entry(14, UNIFORM, false),
        entry(15, READ_WRITE, false),
        entry(16, READ_WRITE, false),
    ];
    let sums = |binding| wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Texture {
            sample_type: wgpu::TextureSampleType::Float { filterable: false },
            view_dimension: wgpu::TextureViewDimension::D2,
            multisampled: false,
        },
        count: None,
    };
    let entries: Vec<_> = entries.into_iter().chain([sums(10), sums(17)]).collect();
    dev.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
        label: Some("beam estimate"),
        entries: &entries,
    })
}
