//! `ppb render`: sessions to a pass count or a time budget, for one frame or a frame
//! list, whole or as one farm task (a pass range written to a part file), with
//! checkpoints, progress for a terminal or a farm manager, and stats.
use anyhow::{Context, Result};
use clap::Args;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::{Duration, Instant};

use ppb::core::frames::{at_frame, FrameList};
use ppb::estimate::Timings;
use ppb::farm::part::content_hash;
use ppb::farm::{Part, PartHeader, PassRange, Tasks};
use ppb::film::error::{Bandwidth, ErrorEstimate, Metric, MIN_HALF_PASSES};
use ppb::film::Film;
use ppb::gpu::beams::GpuStats;
use ppb::gpu::Gpu;
use ppb::output::{Channel, ExrMeta};
use ppb::pass::Tracer;
use ppb::scene::toml::{self as scene_toml, SceneFile};
use ppb::session::{Flow, Session};
use ppb::settings::{BeamKernel, Method, RenderSettings};
use ppb::transport::camera::Pinhole;
use ppb::transport::Counters;

use super::progress::{Goal, Interrupt, PassNote, Progress, ProgressKind};
use super::{failed, Machine, OutputMeta, Overrides};

#[derive(Args)]
pub struct RenderArgs {
    /// Scene file (.toml, or a USD stage with an optional .ppb.toml sidecar). With
    /// --frames, a run of # in it (and in the paths it names) is the frame number.
    pub scene: PathBuf,
    /// Output EXR; a PNG preview is written beside it. A run of # is the frame number,
    /// zero-padded (out/shot.####.exr). Default: <scene stem>.exr, or
    /// <scene stem>.####.exr with --frames, in the current folder.
    #[arg(short, long)]
    pub output: Option<PathBuf>,
    /// Number of passes per frame (overrides [render].passes).
    #[arg(long)]
    pub passes: Option<u32>,
    /// Stop after this many seconds per frame instead of a pass count (the pass in flight
    /// finishes). Not with a pass range or a task.
    #[arg(long)]
    pub time: Option<f64>,
    /// Stop each frame when its estimated error (rel_l1 from the converged image over the
    /// pixels that do not see a light directly, see --target-on) falls below E, e.g. 0.01. The estimate is the noise of the mean of the
    /// passes, from the spread between its odd and even passes, with the beams' kernel bias,
    /// from their estimates at half the radius (the surface photons' bias is not in it). A
    /// frame never stops on it before 4 passes. --passes or --time, when given,
    /// still stop the frame first (with a warning); without them the frame runs until the
    /// target. Not with a pass range or a task.
    #[arg(long, value_name = "E")]
    pub target_error: Option<f64>,
    /// What --target-error measures: pixel (rel_l1 over pixels) or blocks (rel_l1 of 4x4
    /// block means: the blotches that show before noise).
    #[arg(long, value_enum, default_value = "pixel", requires = "target_error")]
    pub target_on: TargetOn,
    /// Add the per-pixel error estimate to the EXR as channels error.R, error.G, error.B
    /// (expected absolute error in radiance units, averaged over 3x3 pixels); and, where
    /// the beams' kernels were nested, bias.R, bias.G, bias.B (the signed bias estimate of
    /// the image at the fixed bandwidth, beams' and surface photons' kernels: negative
    /// where a kernel blurs a peak away), lambda (the adaptive kernel's weight on r/2)
    /// and, with --bandwidth adaptive, narrowing.R, narrowing.G, narrowing.B (what the
    /// adaptive kernel added: the fixed image is the written one minus it).
    #[arg(long)]
    pub error_layer: bool,
    /// Frames to render, e.g. 1-240,300. The frame token (a run of #) in the scene's path,
    /// in the paths it names (grid files, meshes, imports) and in the output becomes the
    /// frame number, so a VDB sequence renders as an animation. Every frame's files are
    /// checked before any work starts.
    #[arg(long, value_name = "LIST")]
    pub frames: Option<String>,
    /// Frames per second, recorded in the EXR header (framesPerSecond).
    #[arg(long, default_value_t = 24.0)]
    pub fps: f64,
    #[command(flatten)]
    pub shard: ShardArgs,
    #[command(flatten)]
    pub over: Overrides,
    #[command(flatten)]
    pub machine: Machine,
    /// Rewrite the EXR/PNG (or a task's part file) every K passes.
    #[arg(long, value_name = "K")]
    pub checkpoint: Option<u32>,
    /// Write timings and counters of the last frame as JSON.
    #[arg(long)]
    pub stats: Option<PathBuf>,
    /// Progress: bar (a terminal), alf (ALF_PROGRESS n% lines, as Tractor and Deadline
    /// read from prman and husk), openjd (openjd_progress: lines), json (one object per
    /// pass: frame, pass, fraction, elapsed and ETA seconds), or none.
    #[arg(long, value_enum, default_value = "bar")]
    pub progress: ProgressKind,
    /// No progress and no status lines (same as --progress none).
    #[arg(short, long)]
    pub quiet: bool,
}

/// The rel_l1 a `--target-error` applies to.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum TargetOn {
    Pixel,
    Blocks,
}

impl From<TargetOn> for Metric {
    fn from(t: TargetOn) -> Metric {
        match t {
            TargetOn::Pixel => Metric::Pixel,
            TargetOn::Blocks => Metric::Block,
        }
    }
}

/// A share of the work: `--pass-range`, or task K of `--passes-per-task`. A task writes
/// a part file (sums and checks, no image) for `ppb merge`.
#[derive(Args, Clone, Debug, Default)]
pub struct ShardArgs {
    /// Render only these passes of every frame, counted from 0, half-open: 256..512 is
    /// the 257th to the 512th pass, so 0..256 and 256..512 tile.
    #[arg(long, value_name = "A..B", conflicts_with_all = ["task_index", "task_index_env"])]
    pub pass_range: Option<String>,
    /// Render task K of the render's tasks (frame-major, each frame's passes cut into
    /// ranges of --passes-per-task); `ppb plan` lists them.
    #[arg(long, value_name = "K", requires = "passes_per_task")]
    pub task_index: Option<u32>,
    /// Read the task index from this environment variable: SLURM_ARRAY_TASK_ID (Slurm job
    /// arrays), JOB_COMPLETION_INDEX (Kubernetes Indexed Jobs), CUE_IFRAME (OpenCue).
    #[arg(
        long,
        value_name = "VAR",
        conflicts_with = "task_index",
        requires = "passes_per_task"
    )]
    pub task_index_env: Option<String>,
    /// Passes per task.
    #[arg(long, value_name = "P")]
    pub passes_per_task: Option<u32>,
    /// Folder of the part files (default: beside the output). A part is named after the
    /// output and its range: shot.0012.passes-0-64.ppbpart.
    #[arg(long, value_name = "DIR")]
    pub part_dir: Option<PathBuf>,
}

#[derive(serde::Serialize)]
struct Stats {
    scene: String,
    passes: u32,
    width: u32,
    height: u32,
    method: Method,
    light_paths: usize,
    beam_r1: f32,
    photon_r1: f32,
    smooth_photon_r1: f32,
    seconds: SecondsSplit,
    counters: Counters,
    /// "cpu" or the adapter.
    device: String,
    /// The instruction set of the CPU's wide loops (`core::simd`): "scalar", "avx2" or
    /// "avx512".
    simd: &'static str,
    /// The beam kernel the estimate ran: "line" (eq. 2) or "tube" (`--beam-kernel auto`
    /// resolved).
    beam_kernel: BeamKernel,
    gpu: Option<GpuStats>,
    /// The image's expected rel_l1 from its converged mean (its noise), per pixel and on
    /// 4x4 block means; null before each half-film holds 2 passes.
    estimated_rel_l1: Option<ErrorEstimate>,
}

/// Wall time split by stage; fine-grained parts are thread-seconds divided by the thread
/// count, so they are comparable with the stage walls.
#[derive(serde::Serialize)]
struct SecondsSplit {
    total: f64,
    light_tracing: f64,
    free_path_sampling: f64,
    camera_transmittance: f64,
    estimate: f64,
    other: f64,
    stages: Timings,
}

impl SecondsSplit {
    fn new(total: f64, counters: &Counters, timings: Timings) -> Self {
        let threads = rayon::current_num_threads() as f64;
        let fp = counters.free_path_seconds / threads;
        let tr = counters.transmittance_seconds / threads;
        SecondsSplit {
            total,
            light_tracing: timings.light_tracing - fp.min(timings.light_tracing),
            free_path_sampling: fp,
            camera_transmittance: tr,
            estimate: timings.build_maps + timings.camera_paths + timings.beam_estimate - tr,
            other: total - timings.total(),
            stages: timings,
        }
    }
}

/// One frame's share of the work.
#[derive(Clone, Copy, Debug)]
struct Job {
    frame: Option<u32>,
    passes: PassRange,
    /// A task's share: written to a part file, not an image.
    part: bool,
}

/// How a job ended.
enum Ended {
    Done,
    /// By a signal: the exit code (130 or 143).
    Interrupted(u8),
}

/// The frames of the command line (empty: a still).
pub fn frame_list(frames: Option<&str>) -> Result<Vec<u32>> {
    Ok(match frames {
        Some(s) => FrameList::parse(s)?.frames().to_vec(),
        None => Vec::new(),
    })
}

/// The output path of `frame`: the token replaced, the folder created.
pub fn frame_output(scene: &Path, over: Option<&PathBuf>, frame: Option<u32>) -> Result<PathBuf> {
    let pattern = over.cloned().unwrap_or_else(|| {
        let stem = scene.file_stem().unwrap_or_default().to_string_lossy();
        let stem = stem.replace('#', "");
        let stem = stem.trim_end_matches(['.', '_']);
        PathBuf::from(match frame {
            Some(_) => format!("{stem}.####.exr"),
            None => format!("{stem}.exr"),
        })
    });
    super::output_path(scene, Some(&at_frame(&pattern, frame)))
}

/// An output with the frame token needs frames to fill it, and several frames need the
/// token, or each frame's image would land in one file.
fn check_output_token(output: Option<&Path>, frames: &[u32]) -> Result<()> {
    let Some(out) = output else { return Ok(()) };
    let token = ppb::core::frames::has_token(&out.to_string_lossy());
    if token && frames.is_empty() {
        anyhow::bail!(
            "{}: -o holds the frame token `#` but no --frames were given (add --frames, or \
             remove the #)",
            out.display()
        );
    }
    if !token && frames.len() > 1 {
        anyhow::bail!(
            "{}: --frames renders {} frames, but -o has no frame token to tell them apart \
             (e.g. -o out/shot.####.exr)",
            out.display(),
            frames.len()
        );
    }
    Ok(())
}

/// The part file of `range` of the frame whose output is `out`.
pub fn part_path(out: &Path, dir: Option<&PathBuf>, range: PassRange) -> PathBuf {
    let stem = out.file_stem().unwrap_or_default().to_string_lossy();
    let name = format!("{stem}.passes-{}-{}.ppbpart", range.start, range.end);
    match dir {
        Some(d) => d.join(name),
        None => out.with_file_name(name),
    }
}

/// The jobs the flags ask for, over `frames` (empty: a still) of `passes` passes.
fn jobs(args: &RenderArgs, frames: &[u32], passes: u32) -> Result<Vec<Job>> {
    let sh = &args.shard;
    let index =
        match (&sh.task_index, &sh.task_index_env) {
            (Some(k), _) => Some(*k),
            (None, Some(var)) => {
                let v = std::env::var(var)
                    .with_context(|| format!("--task-index-env: {var} is not set"))?;
                Some(v.trim().parse().with_context(|| {
                    format!("--task-index-env: {var}={v:?} is not a task index")
                })?)
            }
            (None, None) => None,
        };
    let each_frame = |passes: PassRange, part: bool| -> Vec<Job> {
        let frames: Vec<Option<u32>> = match frames {
            [] => vec![None],
            f => f.iter().map(|&f| Some(f)).collect(),
        };
        frames
            .into_iter()
            .map(|frame| Job {
                frame,
                passes,
                part,
            })
            .collect()
    };
    if (index.is_some() || sh.pass_range.is_some()) && args.time.is_some() {
        anyhow::bail!("--time renders whole frames: it cannot be used with a pass range or a task");
    }
    if (index.is_some() || sh.pass_range.is_some()) && args.target_error.is_some() {
        anyhow::bail!(
            "--target-error renders whole frames: it cannot be used with a pass range or a task \
             (a task's passes are fixed so that parts merge)"
        );
    }
    if let Some(k) = index {
        let per = sh.passes_per_task.unwrap_or(passes);
        let t = Tasks::new(frames, passes, per)?.task(k)?;
        return Ok(vec![Job {
            frame: t.frame,
            passes: t.passes,
            part: true,
        }]);
    }
    if let Some(r) = &sh.pass_range {
        let r = PassRange::parse(r)?;
        if r.end > passes {
            anyhow::bail!("--pass-range {r} goes past the frame's {passes} passes (--passes)");
        }
        return Ok(each_frame(r, true));
    }
    if sh.passes_per_task.is_some() {
        anyhow::bail!("--passes-per-task needs --task-index or --task-index-env");
    }
    Ok(each_frame(
        PassRange {
            start: 0,
            end: passes,
        },
        false,
    ))
}

pub fn render(args: RenderArgs) -> Result<ExitCode> {
    super::set_threads(args.machine.threads)?;
    if let Some(e) = args
        .target_error
        .filter(|e| !(e.is_finite() && *e > 0.0 && *e < 1.0))
    {
        anyhow::bail!("--target-error {e}: expected a rel_l1 between 0 and 1, e.g. 0.01");
    }
    let start = Instant::now();
    let frames = frame_list(args.frames.as_deref())?;
    check_output_token(args.output.as_deref(), &frames)?;
    if !frames.is_empty() {
        scene_toml::check_frames(&args.scene, &frames)?;
    }
    let first = super::load_frame(&args.scene, frames.first().copied())?;
    let passes = args.passes.unwrap_or(first.settings.passes).max(1);
    let jobs = jobs(&args, &frames, passes)?;
    let kind = if args.quiet {
        ProgressKind::None
    } else {
        args.progress
    };
    let gpu = super::open_device(args.machine.device, args.quiet)?;
    let interrupt = Interrupt::install()?;
    let goal = if args.time.is_some() || args.target_error.is_some() {
        Goal::Frames(jobs.len() as u32)
    } else {
        Goal::Passes(jobs.iter().map(|j| j.passes.len() as u64).sum())
    };
    let progress = Progress::new(kind, goal);
    let mut first = Some(first);
    for job in &jobs {
        let file = match first
            .take()
            .filter(|_| job.frame == frames.first().copied())
        {
            Some(f) => f,
            None => super::load_frame(&args.scene, job.frame)?,
        };
        let ended = render_job(
            &args,
            job,
            file,
            passes,
            gpu.clone(),
            &progress,
            &interrupt,
            start,
        )?;
        if let Ended::Interrupted(code) = ended {
            progress.finish();
            return Ok(ExitCode::from(code));
        }
        progress.frame_done();
    }
    progress.finish();
    Ok(ExitCode::SUCCESS)
}

/// Where a job's passes go: the frame's image, or a task's part file.
struct Target {
    out: PathBuf,
    /// The task's part file and its header, for a task.
    part: Option<(PathBuf, PartHeader)>,
}

impl Target {
    /// The image `out`, or for a task its part file (its folder made, the temp files killed
    /// writers left there swept).
    fn new(
        args: &RenderArgs,
        job: &Job,
        file: &SceneFile,
        settings: &RenderSettings,
    ) -> Result<Self> {
        let out = frame_output(&args.scene, args.output.as_ref(), job.frame)?;
        if !job.part {
            return Ok(Target { out, part: None });
        }
        let header = part_header(args, job, file, settings, settings.passes)?;
        let path = part_path(&out, args.shard.part_dir.as_ref(), job.passes);
        if let Some(d) = path.parent() {
            std::fs::create_dir_all(d).with_context(|| format!("creating {}", d.display()))?;
            ppb::core::fs::sweep_temps(d, ppb::core::fs::STALE_TEMP);
        }
        Ok(Target {
            out,
            part: Some((path, header)),
        })
    }

    /// The file the job writes.
    fn written(&self) -> &Path {
        self.part.as_ref().map_or(&self.out, |(p, _)| p)
    }
}

/// Renders one job: loads its caches and session, resumes or skips a task whose part
/// file exists, runs its passes and writes the part or the image.
#[allow(clippy::too_many_arguments)]
fn render_job(
    args: &RenderArgs,
    job: &Job,
    file: SceneFile,
    passes: u32,
    gpu: Option<Gpu>,
    progress: &Progress,
    interrupt: &Interrupt,
    start: Instant,
) -> Result<Ended> {
    if let Some(code) = interrupt.signalled() {
        return Ok(Ended::Interrupted(code));
    }
    let mut settings = args.over.apply(&file.settings)?;
    settings.passes = passes;
    let mut target = Target::new(args, job, &file, &settings)?;
    let resumed = match &target.part {
        Some((path, h)) => existing_part(path, h, args.quiet),
        None => None,
    };
    if let Some(p) = resumed.as_ref().filter(|p| p.header.complete()) {
        if !args.quiet {
            let path = p.path.display();
            eprintln!("{path}: passes {} already done, skipped", job.passes);
        }
        progress.skip(job.passes.len() as u64);
        return Ok(Ended::Done);
    }
    let (mut session, meta) = open_session(args, job, &file, &settings, gpu, &target)?;
    let (from, earlier) = match resumed {
        Some(p) => resume(&mut session, p, progress, args.quiet)?,
        None => (job.passes.start, 0.0),
    };
    let run = Run {
        args,
        job,
        progress,
        interrupt,
        meta: &meta,
        earlier,
        start: Instant::now(),
    };
    let stopped = run.passes(&mut session, from, &mut target)?;
    let estimate = session.error_estimate().map_err(failed)?;
    run.report(&session, &target, stopped, estimate, start)
}

/// The session of a job (octrees from the cache) and what its EXR headers say.
fn open_session<'a>(
    args: &'a RenderArgs,
    job: &Job,
    file: &SceneFile,
    settings: &'a RenderSettings,
    gpu: Option<Gpu>,
    target: &Target,
) -> Result<(Session, FrameMeta<'a>)> {
    let dir = super::cache_dir_for(&args.scene, args.machine.cache_dir.as_ref());
    let media = super::cached_media(file, settings.octree_depth, &dir, args.quiet)?;
    let tracer = Tracer::with_media(&file.scene, settings.clone(), media)?;
    let meta = FrameMeta {
        args,
        settings,
        kernel: tracer.view().kernel,
        camera: *tracer.camera(),
        frame: job.frame,
        scene_hash: match &target.part {
            Some((_, h)) => h.scene_hash.clone(),
            None => content_hash(&file.sources)?,
        },
    };
    let (primary, tr) = (args.machine.gpu_primary, args.machine.gpu_tr);
    Ok((Session::open(tracer, gpu, primary, tr)?, meta))
}

/// A job's passes as they run: what stops them and what checkpoints write.
struct Run<'a> {
    args: &'a RenderArgs,
    job: &'a Job,
    progress: &'a Progress,
    interrupt: &'a Interrupt,
    meta: &'a FrameMeta<'a>,
    /// Render seconds of the task's earlier runs.
    earlier: f64,
    start: Instant,
}

impl Run<'_> {
    /// Render seconds so far, earlier runs of the task included.
    fn seconds(&self) -> f64 {
        self.earlier + self.start.elapsed().as_secs_f64()
    }

    /// Runs passes after `from` until the job's last, the time budget, the error target
    /// or a signal, with checkpoints, then writes the result; returns the signal's exit
    /// code if one came.
    fn passes(&self, session: &mut Session, from: u32, target: &mut Target) -> Result<Option<u8>> {
        let budget = self.args.time.map(Duration::from_secs_f64);
        let mut goal = self
            .args
            .target_error
            .map(|e| ErrorGoal::new(e, self.args.target_on));
        // A target without --passes runs until it is met (or --time runs out).
        let open = budget.is_some() || (goal.is_some() && self.args.passes.is_none());
        let last = if open { u32::MAX } else { self.job.passes.end };
        let mut stopped = None;
        session
            .run(from + 1..=last, |s, done| {
                let i = done.plan.index;
                let elapsed = self.start.elapsed();
                let met = match &mut goal {
                    Some(g) => g.met(s, elapsed)?,
                    None => false,
                };
                let note = PassNote {
                    in_frame: self.in_frame(i, elapsed, open, goal.as_ref()),
                    error: goal.as_ref().and_then(ErrorGoal::status),
                };
                self.progress.pass(self.job.frame, i, note);
                if self.args.checkpoint.is_some_and(|k| k > 0 && i % k == 0) {
                    save(s, target, self.meta, self.seconds())?;
                }
                stopped = self.interrupt.signalled();
                Ok::<_, anyhow::Error>(match budget {
                    _ if stopped.is_some() || met => Flow::Stop,
                    Some(b) if elapsed >= b => Flow::Stop,
                    _ => Flow::Continue,
                })
            })
            .map_err(failed)?;
        save(session, target, self.meta, self.seconds()).map_err(failed)?;
        // The last pass may have come before the estimate was due: judge the final image.
        if let Some(g) = goal.as_mut().filter(|g| !g.reached) {
            g.cost = Duration::ZERO;
            g.met(session, self.start.elapsed()).map_err(failed)?;
        }
        if let Some(g) = goal.filter(|g| !g.reached && stopped.is_none() && !self.args.quiet) {
            let why = if budget.is_some() {
                "--time"
            } else {
                "--passes"
            };
            let now = g
                .status()
                .map_or("not estimated yet".into(), |(e, _)| format!("{e:.4}"));
            eprintln!(
                "warning: {}: {why} ran out before --target-error {} (estimated rel_l1 {now})",
                self.args.scene.display(),
                g.target
            );
        }
        Ok(stopped)
    }

    /// How far into the frame pass `i` ends, `elapsed` into it: the furthest of the time
    /// budget's share, the pass count's (unless the frame is `open`-ended) and the error
    /// target's.
    fn in_frame(&self, i: u32, elapsed: Duration, open: bool, goal: Option<&ErrorGoal>) -> f64 {
        let time = self.args.time.map_or(0.0, |b| elapsed.as_secs_f64() / b);
        let passes = if open {
            0.0
        } else {
            f64::from(i - self.job.passes.start) / f64::from(self.job.passes.len().max(1))
        };
        time.max(passes).max(goal.map_or(0.0, ErrorGoal::fraction))
    }

    /// The job's last lines and its stats file; how it ended.
    fn report(
        &self,
        session: &Session,
        target: &Target,
        stopped: Option<u8>,
        estimate: Option<ErrorEstimate>,
        start: Instant,
    ) -> Result<Ended> {
        let written = target.written();
        if !self.args.quiet {
            let error = estimate.map_or_else(String::new, |e| {
                let bias = e.bias.map_or_else(String::new, |b| {
                    format!("; kernel bias {:.4}, {:.4}", b.pixel, b.block)
                });
                format!(
                    ", estimated error {:.4} ({:.4} on 4x4 blocks{bias})",
                    e.pixel, e.block
                )
            });
            eprintln!(
                "{}: {} passes in {:.1} s{error} -> {}",
                self.args.scene.display(),
                session.passes(),
                self.seconds(),
                written.display()
            );
        }
        if let Some(path) = &self.args.stats {
            let path = at_frame(path, self.job.frame);
            write_stats(&path, self.args, session, estimate, start).map_err(failed)?;
        }
        Ok(match stopped {
            Some(code) => {
                eprintln!(
                    "interrupted: {} passes kept in {}",
                    session.passes(),
                    written.display()
                );
                Ended::Interrupted(code)
            }
            None => Ended::Done,
        })
    }
}

/// Passes each half-film holds before an error target can stop a frame: the estimate's
/// own minimum. (It was 8 while a pixel on a light's rim was a coin toss each pass: the
/// halves saw such rare contributions in one half or neither and read half the error.
/// With the light's pixels sampled 4x4 and left out, glass-caustic's estimate after 4
/// passes matched two seeds' measured noise; docs/error-estimate.md.)
const MIN_TARGET_HALF_PASSES: u32 = MIN_HALF_PASSES;

/// `--target-error`: the estimate, computed after a pass when one is due.
struct ErrorGoal {
    target: f64,
    metric: Metric,
    last: Option<ErrorEstimate>,
    /// Render time at the last estimate, and how long it took.
    at: Duration,
    cost: Duration,
    reached: bool,
}

impl ErrorGoal {
    fn new(target: f64, on: TargetOn) -> Self {
        ErrorGoal {
            target,
            metric: on.into(),
            last: None,
            at: Duration::ZERO,
            cost: Duration::ZERO,
            reached: false,
        }
    }

    /// Whether the target is met after the pass that ended `elapsed` into the frame. The
    /// estimate (a sweep over the film, after a read-back on the GPU) waits until the
    /// passes since the last one took 20 times what it cost, so it adds at most 5 %.
    fn met(&mut self, s: &mut Session, elapsed: Duration) -> ppb::error::Result<bool> {
        if elapsed.saturating_sub(self.at) < self.cost * 20 {
            return Ok(false);
        }
        let start = std::time::Instant::now();
        self.last = s.error_estimate()?;
        self.cost = start.elapsed();
        self.at = elapsed;
        self.reached = self.last.is_some_and(|e| {
            e.passes >= 2 * MIN_TARGET_HALF_PASSES && e.on(self.metric) < self.target
        });
        Ok(self.reached)
    }

    /// The last estimate and the target.
    fn status(&self) -> Option<(f64, f64)> {
        self.last.map(|e| (e.on(self.metric), self.target))
    }

    /// How far to the target: noise falls about as 1 / sqrt(passes), so the passes still
    /// needed are (error / target)^2 times those done.
    fn fraction(&self) -> f64 {
        self.status().map_or(0.0, |(e, t)| (t / e).powi(2).min(1.0))
    }
}

/// Continues a task's partial part file `p` in `session`; returns the last pass it holds
/// and the seconds spent on it so far.
fn resume(session: &mut Session, p: Part, progress: &Progress, quiet: bool) -> Result<(u32, f64)> {
    if !quiet {
        eprintln!(
            "{}: resuming after passes {}",
            p.path.display(),
            p.header.finished()
        );
    }
    progress.skip(p.header.done as u64);
    let from = p.header.finished().end;
    let seconds = p.header.seconds;
    session.resume(p.film).map_err(failed)?;
    Ok((from, seconds))
}

/// What the EXR header of a frame says besides the pixels.
struct FrameMeta<'a> {
    args: &'a RenderArgs,
    settings: &'a RenderSettings,
    kernel: BeamKernel,
    camera: Pinhole,
    frame: Option<u32>,
    scene_hash: String,
}

impl FrameMeta<'_> {
    fn exr(&self, passes: u32, seconds: f64) -> ExrMeta {
        let mut m = OutputMeta {
            scene: &self.args.scene,
            settings: self.settings,
            kernel: self.kernel,
            passes,
            seconds,
            extra: &[],
        }
        .exr();
        m.set("ppb/pass_range", format!("0..{passes}"));
        m.set("ppb/scene_hash", self.scene_hash.clone());
        if let Some(f) = self.frame {
            m.set("ppb/frame", f.to_string());
            m.frames_per_second = Some(self.args.fps);
        }
        m.world_to_camera = Some(self.camera.world_to_camera().to_cols_array());
        m.world_to_ndc = Some(self.camera.world_to_ndc().to_cols_array());
        m
    }
}

/// Writes what `s` has so far: the task's part file (its header updated), or the image
/// and its preview. `seconds`: render time including earlier runs of the task.
fn save(s: &mut Session, t: &mut Target, meta: &FrameMeta, seconds: f64) -> Result<()> {
    match &mut t.part {
        Some((path, h)) => {
            let film = s.film()?;
            h.done = film.passes();
            h.odd_done = film.odd_passes();
            h.nested_done = film.counts().nested;
            h.lights = film.lights().to_vec();
            h.seconds = seconds;
            h.exr = meta.exr(h.passes, 0.0);
            Part::write(path, h, &film)?;
        }
        None => {
            let img = s.image()?;
            let mut exr = meta.exr(s.passes(), seconds);
            let film = s.film()?;
            super::set_error_estimate(&mut exr, &film, meta.settings.bandwidth);
            let layer = if meta.args.error_layer {
                error_channels(&film, meta.settings.bandwidth)
            } else {
                Vec::new()
            };
            super::write_image_with(&t.out, &img, &exr, &layer, meta.settings.exposure)?;
        }
    }
    Ok(())
}

/// The error layer's EXR channels (`--error-layer`): error.RGB, and bias.RGB, lambda and
/// (adaptive bandwidth) narrowing.RGB where the film has nested sums; none before the
/// error can be estimated.
fn error_channels(film: &Film, bandwidth: Bandwidth) -> Vec<Channel<'static>> {
    let rgb = |names: [&'static str; 3], map: &[[f32; 3]]| {
        names
            .into_iter()
            .enumerate()
            .map(|(c, name)| (name, map.iter().map(|p| p[c]).collect()))
            .collect::<Vec<Channel<'static>>>()
    };
    let mut out = film
        .error_map(bandwidth)
        .map_or_else(Vec::new, |m| rgb(["error.R", "error.G", "error.B"], &m));
    let f32s =
        |m: Vec<[f64; 3]>| -> Vec<[f32; 3]> { m.iter().map(|p| p.map(|c| c as f32)).collect() };
    if let (Some(bias), Some(lambda)) = (film.bias_map(), film.lambda_map(bandwidth)) {
        out.extend(rgb(["bias.R", "bias.G", "bias.B"], &f32s(bias)));
        out.push(("lambda", lambda));
    }
    if bandwidth == Bandwidth::Adaptive {
        if let Some(n) = film.narrowing_map(bandwidth) {
            out.extend(rgb(["narrowing.R", "narrowing.G", "narrowing.B"], &f32s(n)));
        }
    }
    out
}

/// The header of a task's part file, before any pass.
fn part_header(
    args: &RenderArgs,
    job: &Job,
    file: &SceneFile,
    settings: &RenderSettings,
    passes: u32,
) -> Result<PartHeader> {
    Ok(PartHeader {
        version: env!("CARGO_PKG_VERSION").to_string(),
        scene_hash: content_hash(&file.sources)?,
        settings: settings.pixel_key(),
        width: settings.width,
        height: settings.height,
        seed: settings.seed,
        frame: job.frame,
        passes,
        range: job.passes,
        done: 0,
        odd_done: 0,
        nested_done: 0,
        seconds: 0.0,
        exposure: settings.exposure,
        bandwidth: settings.bandwidth,
        lights: Vec::new(),
        exr: ExrMeta::default(),
        scene: args.scene.display().to_string(),
    })
}

/// A part file already at `path` that this task can use: complete (nothing to do) or
/// partial (continue after its passes). A damaged or foreign one is reported and
/// rendered again.
fn existing_part(path: &Path, h: &PartHeader, quiet: bool) -> Option<Part> {
    if !path.exists() {
        return None;
    }
    let why = match Part::read(path) {
        Err(e) => e.to_string(),
        Ok(p) => match h.differs(&p.header) {
            None if p.header.range == h.range => return Some(p),
            None => format!("it holds passes {}, this task {}", p.header.range, h.range),
            Some((field, ..)) => format!("it belongs to another render: its {field} differs"),
        },
    };
    if !quiet {
        eprintln!(
            "warning: {}: not reused ({why}); rendering its passes again",
            path.display()
        );
    }
    None
}

/// The stats JSON: passes, radii, the wall time split by stage, counters and the device.
fn write_stats(
    path: &Path,
    args: &RenderArgs,
    session: &Session,
    estimated_rel_l1: Option<ErrorEstimate>,
    start: Instant,
) -> Result<()> {
    let t = session.tracer();
    let settings = &t.settings;
    let stats = Stats {
        scene: args.scene.display().to_string(),
        passes: session.passes(),
        width: settings.width,
        height: settings.height,
        method: settings.method,
        light_paths: settings.light_paths,
        beam_r1: t.beam_r1,
        photon_r1: t.photon_r1,
        smooth_photon_r1: t.smooth_photon_r1,
        seconds: SecondsSplit::new(
            start.elapsed().as_secs_f64(),
            &session.counters,
            session.timings,
        ),
        counters: session.counters,
        device: session.device(),
        simd: ppb::core::simd::isa().name(),
        beam_kernel: t.view().kernel,
        gpu: session.gpu_stats(),
        estimated_rel_l1,
    };
    let json = serde_json::to_string_pretty(&stats)?;
    ppb::core::fs::write_atomic(path, |tmp| {
        std::fs::write(tmp, &json).map_err(|e| ppb::error::Error::io(tmp, e))
    })?;
    Ok(())
}
