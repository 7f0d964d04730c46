//! `ppb render`: sessions to a pass count or a time budget, for one frame or a frame
//! list, whole or as one farm task (a pass range written to a part file), with
//! checkpoints, progress for a terminal or a farm manager, and stats.
use anyhow::{Context, Result};
use clap::Args;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::{Duration, Instant};

use ppb::farm::part::content_hash;
use ppb::farm::{FrameList, Part, PartHeader, PassRange, Tasks};
use ppb::gpu::beams::GpuStats;
use ppb::gpu::Gpu;
use ppb::output::{self, ExrMeta};
use ppb::pass::{Timings, Tracer};
use ppb::scene::toml::{self as scene_toml, SceneFile};
use ppb::session::{Flow, Session};
use ppb::settings::{Method, RenderSettings};
use ppb::transport::Counters;

use super::progress::{Interrupt, Progress, ProgressKind};
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
    seconds: SecondsSplit,
    counters: Counters,
    /// "cpu" or the adapter.
    device: String,
    gpu: Option<GpuStats>,
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
    let token = ppb::farm::frames::has_token(&out.to_string_lossy());
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

/// `p` with its frame token replaced.
pub fn at_frame(p: &Path, frame: Option<u32>) -> PathBuf {
    match frame {
        Some(f) => PathBuf::from(ppb::farm::with_frame(&p.to_string_lossy(), f)),
        None => p.to_path_buf(),
    }
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

/// The settings that change pixels, for a part file's check.
fn pixel_settings(s: &RenderSettings) -> String {
    format!(
        "{:?}",
        RenderSettings {
            passes: 0,
            exposure: 0.0,
            ..s.clone()
        }
    )
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
    let budget = args.time.map(Duration::from_secs_f64);
    let total: u64 = jobs.iter().map(|j| j.passes.len() as u64).sum();
    let progress = Progress::new(kind, budget.map(|b| (b, jobs.len() as u32)), total);
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
    let out = frame_output(&args.scene, args.output.as_ref(), job.frame)?;
    let quiet = args.quiet;
    let dir = super::cache_dir_for(&args.scene, args.machine.cache_dir.as_ref());
    let mut header = job
        .part
        .then(|| part_header(args, job, &file, &settings, passes))
        .transpose()?;
    let part = job
        .part
        .then(|| part_path(&out, args.shard.part_dir.as_ref(), job.passes));
    if let Some(d) = part.as_ref().and_then(|p| p.parent()) {
        std::fs::create_dir_all(d).with_context(|| format!("creating {}", d.display()))?;
        ppb::output::sweep_temps(d, ppb::output::STALE_TEMP);
    }
    let resumed = match (&part, &mut header) {
        (Some(path), Some(h)) => existing_part(path, h, quiet),
        _ => None,
    };
    if let (Some(h), Some(p)) = (&header, &resumed) {
        if p.header.complete() {
            if !quiet {
                eprintln!(
                    "{}: passes {} already done, skipped",
                    p.path.display(),
                    h.range
                );
            }
            progress.skip(job.passes.len() as u64);
            return Ok(Ended::Done);
        }
    }
    let media = super::cached_media(&file, settings.octree_depth, &dir, quiet)?;
    let tracer = Tracer::with_media(&file.scene, settings.clone(), media)?;
    let camera = *tracer.camera();
    let scene_hash = match &header {
        Some(h) => h.scene_hash.clone(),
        None => content_hash(&file.sources)?,
    };
    let mut session = Session::open(tracer, gpu, args.machine.gpu_primary, args.machine.gpu_tr)?;
    let (from, earlier_seconds) = match resumed {
        Some(p) => {
            if !quiet {
                eprintln!(
                    "{}: resuming after passes {}",
                    p.path.display(),
                    p.header.finished()
                );
            }
            progress.skip(p.header.done as u64);
            let f = p.header.finished().end;
            session.resume(p.film).map_err(failed)?;
            (f, p.header.seconds)
        }
        None => (job.passes.start, 0.0),
    };
    let exr = |passes: u32, seconds: f64| -> ExrMeta {
        let mut m = OutputMeta {
            scene: &args.scene,
            settings: &settings,
            passes,
            seconds,
            extra: &[],
        }
        .exr();
        m.set("ppb/pass_range", format!("0..{passes}"));
        m.set("ppb/scene_hash", scene_hash.clone());
        if let Some(f) = job.frame {
            m.set("ppb/frame", f.to_string());
            m.frames_per_second = Some(args.fps);
        }
        m.world_to_camera = Some(camera.world_to_camera().to_cols_array());
        m.world_to_ndc = Some(camera.world_to_ndc().to_cols_array());
        m
    };
    let budget = args.time.map(Duration::from_secs_f64);
    let last = if budget.is_some() {
        u32::MAX
    } else {
        job.passes.end
    };
    let render_start = Instant::now();
    let seconds = |at: Instant| earlier_seconds + at.duration_since(render_start).as_secs_f64();
    let save = |s: &mut Session, h: &mut Option<PartHeader>| -> Result<()> {
        let secs = seconds(Instant::now());
        match (h, &part) {
            (Some(h), Some(path)) => {
                let film = s.film()?;
                h.done = film.passes();
                h.seconds = secs;
                h.exr = exr(h.passes, 0.0);
                Part::write(path, h, &film)?;
            }
            _ => {
                let img = s.image()?;
                let meta = exr(s.passes(), secs);
                super::write_image(&out, &img, &meta, settings.exposure)?;
            }
        }
        Ok(())
    };
    let mut stopped = None;
    session
        .run(from + 1..=last, |s, done| {
            let i = done.plan.index;
            progress.pass(job.frame, i, render_start.elapsed());
            if args.checkpoint.is_some_and(|k| k > 0 && i % k == 0) {
                save(s, &mut header)?;
            }
            stopped = interrupt.signalled();
            Ok::<_, anyhow::Error>(match budget {
                _ if stopped.is_some() => Flow::Stop,
                Some(b) if render_start.elapsed() >= b => Flow::Stop,
                _ => Flow::Continue,
            })
        })
        .map_err(failed)?;
    save(&mut session, &mut header).map_err(failed)?;
    let written = part.as_ref().unwrap_or(&out);
    if !quiet {
        eprintln!(
            "{}: {} passes in {:.1} s -> {}",
            args.scene.display(),
            session.passes(),
            seconds(Instant::now()),
            written.display()
        );
    }
    if let Some(path) = &args.stats {
        let path = at_frame(path, job.frame);
        write_stats(&path, args, &session, start).map_err(failed)?;
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
        settings: pixel_settings(settings),
        width: settings.width,
        height: settings.height,
        seed: settings.seed,
        frame: job.frame,
        passes,
        range: job.passes,
        done: 0,
        seconds: 0.0,
        exposure: settings.exposure,
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
        Ok(p) => {
            let o = &p.header;
            let same = (&o.version, &o.scene_hash, &o.settings, o.width, o.height)
                == (&h.version, &h.scene_hash, &h.settings, h.width, h.height)
                && (o.seed, o.frame, o.passes, o.range) == (h.seed, h.frame, h.passes, h.range);
            if same {
                return Some(p);
            }
            "it belongs to another scene, settings or range".to_string()
        }
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
fn write_stats(path: &Path, args: &RenderArgs, session: &Session, start: Instant) -> Result<()> {
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
        seconds: SecondsSplit::new(
            start.elapsed().as_secs_f64(),
            &session.counters,
            session.timings,
        ),
        counters: session.counters,
        device: session.device(),
        gpu: session.gpu_stats(),
    };
    let json = serde_json::to_string_pretty(&stats)?;
    output::write_atomic(path, |tmp| {
        std::fs::write(tmp, &json).map_err(|e| ppb::error::Error::io(tmp, e))
    })?;
    Ok(())
}
