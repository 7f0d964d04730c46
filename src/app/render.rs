//! `ppb render`: one session to a pass count or a time budget, with checkpoints and stats.
use anyhow::Result;
use clap::Args;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::{Duration, Instant};

use ppb::gpu::beams::GpuStats;
use ppb::output;
use ppb::pass::{Timings, Tracer};
use ppb::session::{Flow, Session};
use ppb::settings::Method;
use ppb::transport::Counters;

use super::{Machine, OutputMeta, Overrides};

#[derive(Args)]
pub struct RenderArgs {
    /// Scene file (.toml, or a USD stage with an optional .ppb.toml sidecar).
    pub scene: PathBuf,
    /// Output EXR; a PNG preview is written beside it. Default: <scene stem>.exr in the
    /// current folder.
    #[arg(short, long)]
    pub output: Option<PathBuf>,
    /// Number of passes (overrides [render].passes).
    #[arg(long)]
    pub passes: Option<u32>,
    /// Stop after this many seconds instead of a pass count (the pass in flight finishes).
    #[arg(long)]
    pub time: Option<f64>,
    #[command(flatten)]
    pub over: Overrides,
    #[command(flatten)]
    pub machine: Machine,
    /// Rewrite the EXR/PNG every K passes.
    #[arg(long, value_name = "K")]
    pub checkpoint: Option<u32>,
    /// Write timings and counters as JSON.
    #[arg(long)]
    pub stats: Option<PathBuf>,
    /// No progress bar.
    #[arg(short, long)]
    pub quiet: bool,
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

pub fn render(args: RenderArgs) -> Result<ExitCode> {
    super::set_threads(args.machine.threads)?;
    let start = Instant::now();
    let file = super::load_scene(&args.scene)?;
    let mut settings = args.over.apply(&file.settings)?;
    if let Some(p) = args.passes {
        settings.passes = p.max(1);
    }
    let out = super::output_path(&args.scene, args.output.as_ref())?;
    let dir = super::cache_dir_for(&args.scene, args.machine.cache_dir.as_ref());
    let media = super::cached_media(&file, settings.octree_depth, &dir, args.quiet)?;
    let tracer = Tracer::with_media(&file.scene, settings.clone(), media)?;
    let gpu = super::open_device(args.machine.device, args.quiet)?;
    let mut session = Session::open(tracer, gpu)?;
    let budget = args.time.map(Duration::from_secs_f64);
    let last = if budget.is_some() {
        u32::MAX
    } else {
        settings.passes
    };
    let bar = super::progress_bar(args.quiet, budget, settings.passes);
    let render_start = Instant::now();
    let meta = |passes, seconds| OutputMeta {
        scene: &args.scene,
        settings: &settings,
        passes,
        seconds,
        extra: &[],
    };
    session.run(1..=last, |s, done| {
        let i = done.plan.index;
        match budget {
            Some(b) => bar.set_position(render_start.elapsed().as_secs().min(b.as_secs())),
            None => bar.inc(1),
        }
        bar.set_message(format!("pass {i}"));
        if args.checkpoint.is_some_and(|k| k > 0 && i % k == 0) {
            let img = s.image()?;
            let secs = render_start.elapsed().as_secs_f64();
            super::write_outputs(&out, &img, &meta(i, secs))?;
        }
        Ok::<_, anyhow::Error>(match budget {
            Some(b) if render_start.elapsed() >= b => Flow::Stop,
            _ => Flow::Continue,
        })
    })?;
    bar.finish_and_clear();
    let img = session.image()?;
    let seconds = render_start.elapsed().as_secs_f64();
    super::write_outputs(&out, &img, &meta(session.passes(), seconds))?;
    if !args.quiet {
        eprintln!(
            "{}: {} passes in {:.1} s -> {}",
            args.scene.display(),
            session.passes(),
            seconds,
            out.display()
        );
    }
    if let Some(path) = &args.stats {
        write_stats(path, &args, &session, start)?;
    }
    Ok(ExitCode::SUCCESS)
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
