//! Runs the stages for each subcommand: progress bar, checkpoints, outputs, stats.
mod watch;
mod window;

use anyhow::{Context, Result};
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::{Duration, Instant};
pub use watch::{watch, WatchArgs};

use ppb::compare::{block_mean, compare as metrics, read_mask, DeviceDiff};
use ppb::film::Film;
use ppb::gpu::beams::GpuBeams;
use ppb::gpu::{DeviceKind, Gpu};
use ppb::majorant::{cache, Octree};
use ppb::output::{self, Image};
use ppb::progressive::{GpuStats, Progressive};
use ppb::render::{Renderer, Timings};
use ppb::scene::toml as scene_toml;
use ppb::transport::freepath::Mode;
use ppb::transport::transmittance::TrMode;
use ppb::transport::Counters;
use ppb::watch::octrees;

#[derive(Args)]
pub struct RenderArgs {
    /// Scene file (.toml).
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
    /// Random seed (overrides [render].seed); the image depends only on it, not on threads.
    #[arg(long)]
    pub seed: Option<u64>,
    /// Worker threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Image size override, e.g. 64x64 (for quick previews and tests).
    #[arg(long, value_parser = parse_size)]
    pub size: Option<(u32, u32)>,
    /// Light paths per pass (overrides [render].beams_per_pass).
    #[arg(long)]
    pub beams: Option<usize>,
    /// Rewrite the EXR/PNG every K passes.
    #[arg(long, value_name = "K")]
    pub checkpoint: Option<u32>,
    /// Write timings and counters as JSON.
    #[arg(long)]
    pub stats: Option<PathBuf>,
    /// PNG preview exposure in stops (overrides [render].exposure).
    #[arg(long)]
    pub exposure: Option<f32>,
    /// Grid free paths per camera segment per pass for the random and stratified estimators
    /// (overrides [render].tr_samples; 1..=16, default 4).
    #[arg(long, value_name = "M")]
    pub tr_samples: Option<usize>,
    /// Free-path sampler for light paths and camera transmittance: adaptive (majorant
    /// octree, the default) or woodcock (one global majorant, the paper's baseline).
    #[arg(long, value_enum)]
    pub free_path: Option<FreePathArg>,
    /// Camera-segment transmittance through grids: ratio (ratio tracking on the octree's
    /// local majorants, the default: lowest error per time in our measurements), stratified
    /// (the paper's estimator: free paths of --tr-block passes drawn at once, M strata) or
    /// random (M free paths per pass, the progressive deep shadow map).
    #[arg(long, value_enum)]
    pub transmittance: Option<TrArg>,
    /// Passes whose free paths the stratified estimator draws at once (N, <= 64, a
    /// multiple of --tr-samples). Memory: 4 N + 8 bytes per pixel (264 at N = 64).
    #[arg(long, value_name = "N")]
    pub tr_block: Option<usize>,
    /// Where baked octrees are cached (default: .ppb-cache/ beside the scene).
    #[arg(long)]
    pub cache_dir: Option<PathBuf>,
    /// Where the beam estimate runs: auto (a hardware GPU if wgpu finds one, else the CPU),
    /// gpu (any adapter, software Vulkan such as lavapipe included; an error if none) or
    /// cpu. On the GPU the estimate of pass i overlaps the CPU tracing pass i+1. One line
    /// names the adapter. WGPU_BACKEND=vulkan|metal|dx12|gl narrows the search.
    #[arg(long, value_enum, default_value = "auto")]
    pub device: DeviceArg,
    /// No progress bar.
    #[arg(short, long)]
    pub quiet: bool,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum DeviceArg {
    Auto,
    Gpu,
    Cpu,
}

impl DeviceArg {
    fn kind(self) -> DeviceKind {
        match self {
            DeviceArg::Auto => DeviceKind::Auto,
            DeviceArg::Gpu => DeviceKind::Gpu,
            DeviceArg::Cpu => DeviceKind::Cpu,
        }
    }
}

/// Opens the device for the beam estimate and says which in one line.
pub fn open_device(arg: DeviceArg, quiet: bool) -> Result<Option<Gpu>> {
    let gpu = ppb::gpu::open(arg.kind())?;
    if !quiet {
        match &gpu {
            Some(g) => eprintln!("beam estimate on the GPU: {}", g.describe()),
            None if arg == DeviceArg::Auto => {
                eprintln!("beam estimate on the CPU (no hardware GPU adapter found)")
            }
            None => eprintln!("beam estimate on the CPU"),
        }
    }
    Ok(gpu)
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum TrArg {
    Random,
    Stratified,
    Ratio,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum FreePathArg {
    Adaptive,
    Woodcock,
}

#[derive(Args)]
pub struct BuildArgs {
    /// Scene file (.toml).
    pub scene: PathBuf,
    /// Cache folder (default: .ppb-cache/ beside the scene).
    #[arg(long)]
    pub cache_dir: Option<PathBuf>,
    /// Only report whether each medium's cached octree is fresh; exit 1 if any is stale.
    #[arg(long)]
    pub check: bool,
}

fn cache_dir_for(scene: &Path, over: Option<&PathBuf>) -> PathBuf {
    over.cloned().unwrap_or_else(|| {
        scene
            .parent()
            .filter(|p| !p.as_os_str().is_empty())
            .unwrap_or(Path::new("."))
            .join(".ppb-cache")
    })
}

/// The grids' octrees: loaded from a valid cache, else built and stored. One line per
/// medium says which (unless quiet).
fn prepare_octrees(
    scene: &ppb::scene::Scene,
    depth: u32,
    dir: &Path,
    quiet: bool,
) -> Result<Vec<Octree>> {
    let mut trees = Vec::with_capacity(scene.grid_media.len());
    for (i, g) in scene.grid_media.iter().enumerate() {
        let (tree, origin) = octrees::load_or_build(dir, g, depth);
        if !quiet {
            eprintln!("{}", octrees::describe(i, g, &origin));
        }
        trees.push(tree);
    }
    Ok(trees)
}

pub fn build(args: BuildArgs) -> Result<ExitCode> {
    let file = scene_toml::load(&args.scene)?;
    let depth = file.settings.octree_depth;
    let dir = cache_dir_for(&args.scene, args.cache_dir.as_ref());
    if args.check {
        let mut stale = false;
        for (i, g) in file.scene.grid_media.iter().enumerate() {
            let (status, _) = cache::load(&dir, g, depth);
            let word = match &status {
                cache::Status::Fresh => "fresh".to_string(),
                cache::Status::Missing => "stale (no cache)".to_string(),
                cache::Status::Invalid(w) => format!("stale ({w})"),
            };
            stale |= status != cache::Status::Fresh;
            println!("medium {i} ({}): {word}", g.source);
        }
        return Ok(if stale {
            ExitCode::from(1)
        } else {
            ExitCode::SUCCESS
        });
    }
    prepare_octrees(&file.scene, depth, &dir, false)?;
    Ok(ExitCode::SUCCESS)
}

#[derive(Args)]
pub struct CompareArgs {
    /// Candidate EXR.
    pub a: PathBuf,
    /// Reference EXR.
    pub b: PathBuf,
    /// Exit with code 1 when rel_l1 is above this.
    #[arg(long)]
    pub max_rel_l1: Option<f64>,
    /// PNG mask: white pixels are left out of the metrics.
    #[arg(long)]
    pub mask: Option<PathBuf>,
    /// Also compare means over K x K pixel blocks (regional error, less sensitive to noise).
    #[arg(long, value_name = "K")]
    pub block: Option<usize>,
}

fn parse_size(s: &str) -> std::result::Result<(u32, u32), String> {
    let (w, h) = s
        .split_once('x')
        .ok_or("expected WIDTHxHEIGHT, e.g. 64x64")?;
    let w: u32 = w.parse().map_err(|_| format!("bad width in {s}"))?;
    let h: u32 = h.parse().map_err(|_| format!("bad height in {s}"))?;
    if w == 0 || h == 0 {
        return Err("size must be positive".into());
    }
    Ok((w, h))
}

#[derive(serde::Serialize)]
struct Stats {
    scene: String,
    passes: u32,
    width: u32,
    height: u32,
    beams_per_pass: usize,
    beam_r1: f32,
    photon_r1: f32,
    seconds: SecondsSplit,
    counters: Counters,
    /// "cpu" or the adapter.
    device: String,
    gpu: Option<GpuStats>,
}

/// Wall time split as the issue asks; fine-grained parts are thread-seconds divided by the
/// thread count, so they are comparable with the stage walls.
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

pub fn render(args: RenderArgs) -> Result<ExitCode> {
    if let Some(n) = args.threads {
        rayon::ThreadPoolBuilder::new()
            .num_threads(n.max(1))
            .build_global()
            .context("setting up the thread pool")?;
    }
    let start = Instant::now();
    let file = scene_toml::load(&args.scene)?;
    let mut settings = file.settings.clone();
    if let Some(p) = args.passes {
        settings.passes = p.max(1);
    }
    if let Some(s) = args.seed {
        settings.seed = s;
    }
    if let Some((w, h)) = args.size {
        settings.width = w;
        settings.height = h;
    }
    if let Some(b) = args.beams {
        settings.beams_per_pass = b.max(1);
    }
    if let Some(e) = args.exposure {
        settings.exposure = e;
    }
    if let Some(m) = args.tr_samples {
        if !(1..=ppb::transport::transmittance::MAX_TR_SAMPLES).contains(&m) {
            anyhow::bail!("--tr-samples: expected 1..=16, got {m}");
        }
        settings.tr_samples = m;
    }
    let out = args.output.clone().unwrap_or_else(|| {
        let stem = args.scene.file_stem().unwrap_or_default().to_string_lossy();
        PathBuf::from(format!("{stem}.exr"))
    });
    if let Some(dir) = out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    if let Some(f) = args.free_path {
        settings.free_path = match f {
            FreePathArg::Adaptive => Mode::Adaptive,
            FreePathArg::Woodcock => Mode::Woodcock,
        };
    }
    if let Some(t) = args.transmittance {
        settings.tr_mode = match t {
            TrArg::Random => TrMode::Random,
            TrArg::Stratified => TrMode::Stratified,
            TrArg::Ratio => TrMode::Ratio,
        };
    }
    if let Some(n) = args.tr_block {
        settings.tr_block = n;
    }
    let dir = cache_dir_for(&args.scene, args.cache_dir.as_ref());
    let trees = prepare_octrees(&file.scene, settings.octree_depth, &dir, args.quiet)?;
    let renderer = Renderer::with_octrees(&file.scene, settings.clone(), trees)?;
    let budget = args.time.map(Duration::from_secs_f64);
    let total_passes = if budget.is_some() {
        u32::MAX
    } else {
        settings.passes
    };
    let gpu = open_device(args.device, args.quiet)?;
    let device = gpu.as_ref().map_or("cpu".to_string(), |g| g.describe());
    let mut acc = Progressive::new(&renderer, gpu)?;
    let bar = progress_bar(args.quiet, budget, settings.passes);
    let render_start = Instant::now();
    for i in 1..=total_passes {
        acc.pass(&renderer, i)?;
        match budget {
            Some(b) => bar.set_position(render_start.elapsed().as_secs().min(b.as_secs())),
            None => bar.inc(1),
        }
        bar.set_message(format!("pass {i}"));
        if args.checkpoint.is_some_and(|k| k > 0 && i % k == 0) {
            let img = acc.image()?;
            let secs = render_start.elapsed().as_secs_f64();
            write_outputs(&out, &img, i, &settings, secs, &args.scene)?;
        }
        if budget.is_some_and(|b| render_start.elapsed() >= b) {
            break;
        }
    }
    bar.finish_and_clear();
    let img = acc.image()?;
    let seconds = render_start.elapsed().as_secs_f64();
    write_outputs(&out, &img, acc.passes(), &settings, seconds, &args.scene)?;
    if !args.quiet {
        eprintln!(
            "{}: {} passes in {:.1} s -> {}",
            args.scene.display(),
            acc.passes(),
            seconds,
            out.display()
        );
    }
    if let Some(path) = &args.stats {
        let threads = rayon::current_num_threads() as f64;
        let (counters, timings) = (acc.counters, acc.timings);
        let fp = counters.free_path_seconds / threads;
        let tr = counters.transmittance_seconds / threads;
        let total = start.elapsed().as_secs_f64();
        let split = SecondsSplit {
            total,
            light_tracing: timings.light_tracing - fp.min(timings.light_tracing),
            free_path_sampling: fp,
            camera_transmittance: tr,
            estimate: timings.build_maps + timings.camera_paths + timings.beam_estimate - tr,
            other: total - timings.total(),
            stages: timings,
        };
        let stats = Stats {
            scene: args.scene.display().to_string(),
            passes: acc.passes(),
            width: settings.width,
            height: settings.height,
            beams_per_pass: settings.beams_per_pass,
            beam_r1: renderer.beam_r1,
            photon_r1: renderer.photon_r1,
            seconds: split,
            counters,
            device,
            gpu: acc.on_gpu().then(|| acc.gpu_stats.clone()),
        };
        let json = serde_json::to_string_pretty(&stats)?;
        output::write_atomic(path, |tmp| {
            std::fs::write(tmp, &json).map_err(|e| ppb::error::Error::io(tmp, e))
        })?;
    }
    Ok(ExitCode::SUCCESS)
}

fn progress_bar(quiet: bool, budget: Option<Duration>, passes: u32) -> ProgressBar {
    if quiet {
        return ProgressBar::hidden();
    }
    let (len, template) = match budget {
        Some(b) => (
            b.as_secs().max(1),
            "{spinner} [{elapsed_precise}] {bar:40} {pos}/{len} s  {msg}",
        ),
        None => (
            passes as u64,
            "{spinner} [{elapsed_precise}] {bar:40} {pos}/{len} passes  {per_sec}  ETA {eta}",
        ),
    };
    let bar = ProgressBar::new(len);
    if let Ok(style) = ProgressStyle::with_template(template) {
        bar.set_style(style);
    }
    bar.enable_steady_tick(Duration::from_millis(250));
    bar
}

fn write_outputs(
    out: &Path,
    img: &Image,
    passes: u32,
    s: &ppb::settings::RenderSettings,
    seconds: f64,
    scene: &Path,
) -> Result<()> {
    write_outputs_meta(out, img, passes, s, seconds, scene, &[])
}

/// A film's mean image written by [`write_outputs_meta`] (`ppb watch`).
fn write_film(
    out: &Path,
    film: &Film,
    s: &ppb::settings::RenderSettings,
    seconds: f64,
    scene: &Path,
    extra: &[(String, String)],
) -> Result<()> {
    write_outputs_meta(
        out,
        &film.mean_image(),
        film.passes(),
        s,
        seconds,
        scene,
        extra,
    )
}

/// [`write_outputs`] with `extra` header attributes (e.g. `ppb watch`'s reload number).
fn write_outputs_meta(
    out: &Path,
    img: &Image,
    passes: u32,
    s: &ppb::settings::RenderSettings,
    seconds: f64,
    scene: &Path,
    extra: &[(String, String)],
) -> Result<()> {
    let meta = vec![
        ("ppb.scene".to_string(), scene.display().to_string()),
        ("ppb.passes".to_string(), passes.to_string()),
        ("ppb.seconds".to_string(), format!("{seconds:.3}")),
        (
            "ppb.beams_per_pass".to_string(),
            s.beams_per_pass.to_string(),
        ),
        ("ppb.alpha".to_string(), s.alpha.to_string()),
        ("ppb.seed".to_string(), s.seed.to_string()),
        (
            "ppb.beam_radius".to_string(),
            format!("{:?}", s.beam_radius),
        ),
        (
            "ppb.photon_radius".to_string(),
            format!("{:?}", s.photon_radius),
        ),
    ];
    let meta: Vec<(String, String)> = meta.into_iter().chain(extra.iter().cloned()).collect();
    output::write_exr(out, img, &meta)?;
    output::write_png(&out.with_extension("png"), img, s.exposure)?;
    Ok(())
}

pub fn compare(args: CompareArgs) -> Result<ExitCode> {
    let a = output::read_exr(&args.a)?;
    let b = output::read_exr(&args.b)?;
    let mask = match &args.mask {
        Some(p) => {
            let (w, h, m) = read_mask(p)?;
            if (w, h) != (b.width, b.height) {
                anyhow::bail!(
                    "{}: mask is {w}x{h}, images are {}x{}",
                    p.display(),
                    b.width,
                    b.height
                );
            }
            Some(m)
        }
        None => None,
    };
    let m = metrics(&a, &b, mask.as_deref())?;
    if let Some(k) = args.block.filter(|&k| k > 1) {
        let block_skip = mask.as_ref().map(|m| block_mask(m, b.width, k));
        let bm = metrics(
            &block_mean(&a, k),
            &block_mean(&b, k),
            block_skip.as_deref(),
        )?;
        println!("rel_l1 of {k}x{k} block means {:.6}", bm.rel_l1);
    }
    println!("rel_l1     {:.6}", m.rel_l1);
    println!("rel_rmse   {:.6}", m.rel_rmse);
    println!(
        "mean       {:.6} {:.6} {:.6}",
        m.mean[0], m.mean[1], m.mean[2]
    );
    println!(
        "mean_ref   {:.6} {:.6} {:.6}",
        m.mean_ref[0], m.mean_ref[1], m.mean_ref[2]
    );
    println!("pixels     {}", m.pixels);
    if let Some(max) = args.max_rel_l1 {
        if m.rel_l1 > max {
            println!("FAIL: rel_l1 {:.6} > {max}", m.rel_l1);
            return Ok(ExitCode::from(1));
        }
        println!("ok: rel_l1 {:.6} <= {max}", m.rel_l1);
    }
    Ok(ExitCode::SUCCESS)
}

/// A block is left out when any of its pixels is.
fn block_mask(mask: &[bool], width: usize, k: usize) -> Vec<bool> {
    let bw = width / k;
    let bh = mask.len() / width / k;
    let mut out = vec![false; bw * bh];
    for (i, &m) in mask.iter().enumerate() {
        let (x, y) = (i % width / k, i / width / k);
        if m && x < bw && y < bh {
            out[y * bw + x] = true;
        }
    }
    out
}

#[derive(Args)]
pub struct BenchArgs {
    /// Scene files (.toml).
    #[arg(required = true)]
    pub scenes: Vec<PathBuf>,
    /// Passes per scene.
    #[arg(long, default_value_t = 4)]
    pub passes: u32,
    /// Light paths per pass (default: the scene's).
    #[arg(long)]
    pub beams: Option<usize>,
    /// Image size override, e.g. 128x128.
    #[arg(long, value_parser = parse_size)]
    pub size: Option<(u32, u32)>,
}

impl BenchArgs {
    /// The scene's settings with this benchmark's overrides.
    fn settings(&self, file: &scene_toml::SceneFile) -> ppb::settings::RenderSettings {
        let mut s = file.settings.clone();
        if let Some(b) = self.beams {
            s.beams_per_pass = b.max(1);
        }
        if let Some((w, h)) = self.size {
            (s.width, s.height) = (w, h);
        }
        s
    }
}

/// A benchmark table's name for a scene: its folder's name.
fn scene_name(scene: &Path) -> String {
    scene.parent().and_then(|p| p.file_name()).map_or_else(
        || scene.display().to_string(),
        |n| n.to_string_lossy().into(),
    )
}

/// One benchmark run: free-path thread-seconds, wall seconds, counters.
struct BenchRun {
    fps: f64,
    total: f64,
    c: Counters,
}

fn bench_run(file: &scene_toml::SceneFile, args: &BenchArgs, mode: Mode) -> Result<BenchRun> {
    let mut settings = args.settings(file);
    settings.free_path = mode;
    // Same camera estimator for both, so the table isolates the free-path sampler.
    settings.tr_mode = TrMode::Random;
    let r = Renderer::new(&file.scene, settings)?;
    let start = Instant::now();
    let mut c = Counters::default();
    for i in 1..=args.passes.max(1) {
        c.add(&r.pass(i).counters);
    }
    let threads = rayon::current_num_threads() as f64;
    Ok(BenchRun {
        fps: (c.free_path_seconds + c.transmittance_seconds) / threads,
        total: start.elapsed().as_secs_f64(),
        c,
    })
}

#[derive(Args)]
pub struct BenchTableArgs {
    #[command(flatten)]
    pub bench: BenchArgs,
    /// Runs of each sampler, interleaved (Woodcock, adaptive, Woodcock, ...): the table shows
    /// each sampler's median run by free-path time and the range of the per-pair FPS ratio,
    /// which tames a noisy machine.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=99))]
    pub repeat: u32,
}

/// The run with the median free-path time (the upper one of an even count).
fn median_run(mut runs: Vec<BenchRun>) -> BenchRun {
    runs.sort_by(|a, b| a.fps.total_cmp(&b.fps));
    let mid = runs.len() / 2;
    runs.swap_remove(mid)
}

/// The paper's Table 1 on our scenes: free-path sampling (FPS) and total time with
/// Woodcock and adaptive sampling, their ratios, and density lookups per free path.
pub fn bench(table: BenchTableArgs) -> Result<ExitCode> {
    let args = &table.bench;
    println!(
        "{:<28} {:>9} {:>9} {:>7} {:>11} {:>9} {:>9} {:>7} {:>10} {:>10} {:>8}",
        "scene",
        "FPS wood",
        "FPS adap",
        "ratio",
        "range",
        "tot wood",
        "tot adap",
        "ratio",
        "lkp/fp W",
        "lkp/fp A",
        "ratio"
    );
    let mut rates = Vec::new();
    for scene in &args.scenes {
        let file = scene_toml::load(scene)?;
        let (mut ws, mut adaptive) = (Vec::new(), Vec::new());
        for _ in 0..table.repeat {
            ws.push(bench_run(&file, args, Mode::Woodcock)?);
            adaptive.push(bench_run(&file, args, Mode::Adaptive)?);
        }
        let pair_ratios = ws
            .iter()
            .zip(&adaptive)
            .map(|(w, a)| w.fps / a.fps.max(1e-9));
        let (lo, hi) = pair_ratios.fold((f64::MAX, f64::MIN), |(lo, hi), r| (lo.min(r), hi.max(r)));
        let (w, a) = (median_run(ws), median_run(adaptive));
        let per = |r: &BenchRun| r.c.density_lookups as f64 / r.c.free_paths.max(1) as f64;
        let name = scene_name(scene);
        println!(
            "{:<28} {:>9.2} {:>9.2} {:>7.2} {:>11} {:>9.2} {:>9.2} {:>7.2} {:>10.2} {:>10.2} {:>8.2}",
            name,
            w.fps,
            a.fps,
            w.fps / a.fps.max(1e-9),
            format!("{lo:.2}-{hi:.2}"),
            w.total,
            a.total,
            w.total / a.total.max(1e-9),
            per(&w),
            per(&a),
            per(&w) / per(&a).max(1e-9)
        );
        rates.push((scene.clone(), w, a));
    }
    println!("(seconds, median of {} runs per sampler; FPS = free-path sampling incl. camera transmittance, thread-seconds / threads; range = FPS ratio over the interleaved pairs; lkp/fp = density lookups per free path)", table.repeat);
    println!(
        "\n{:<28} {:>9} {:>14} {:>14} {:>12} {:>14}",
        "scene", "sampler", "free paths/s", "lookups/s", "leaves/fp", "no-lookup/fp"
    );
    for (scene, w, a) in &rates {
        for (name, r) in [("woodcock", w), ("adaptive", a)] {
            let secs = (r.c.free_path_seconds + r.c.transmittance_seconds).max(1e-9);
            println!(
                "{:<28} {:>9} {:>14.0} {:>14.0} {:>12.2} {:>14.2}",
                scene_name(scene),
                name,
                r.c.free_paths as f64 / secs,
                r.c.density_lookups as f64 / secs,
                r.c.octree_steps as f64 / r.c.free_paths.max(1) as f64,
                r.c.minorant_accepts as f64 / r.c.free_paths.max(1) as f64
            );
        }
    }
    println!("(per thread-second; leaves/fp = octree leaves entered per free path; no-lookup/fp = collisions found real below a leaf's minorant, per free path)");
    Ok(ExitCode::SUCCESS)
}

#[derive(Args)]
pub struct BenchTrArgs {
    /// Scenes, each optionally with its reference EXR: SCENE.toml[=REFERENCE.exr]. Without
    /// one, the reference is a ppb render (adaptive + ratio) with 16x the longest run's passes.
    #[arg(required = true)]
    pub scenes: Vec<String>,
    /// Pass counts at which the error is measured.
    #[arg(long, value_delimiter = ',', default_value = "4,8,16,32,64")]
    pub passes: Vec<u32>,
    /// Render size; the reference is averaged over blocks to match (must divide it).
    #[arg(long, value_parser = parse_size, default_value = "128x128")]
    pub size: (u32, u32),
    /// Light paths per pass (default: the scene's).
    #[arg(long)]
    pub beams: Option<usize>,
    /// Write every measurement as CSV (scene,config,passes,seconds,rel_l1,rel_l1_media)
    /// for tools/plot_tr.py.
    #[arg(long)]
    pub csv: Option<PathBuf>,
    /// The second error column covers the pixels whose centre ray crosses at least this
    /// optical depth of media before the first surface (the paper measured its error in a
    /// region of the smoke).
    #[arg(long, default_value_t = 0.1)]
    pub media_depth: f32,
}

/// The five configurations of the paper's Figs. 11 and 12.
const TR_CONFIGS: [(&str, Mode, TrMode); 5] = [
    ("woodcock+random (PPB)", Mode::Woodcock, TrMode::Random),
    ("woodcock+stratified", Mode::Woodcock, TrMode::Stratified),
    ("adaptive+random", Mode::Adaptive, TrMode::Random),
    ("adaptive+stratified", Mode::Adaptive, TrMode::Stratified),
    ("adaptive+ratio", Mode::Adaptive, TrMode::Ratio),
];

/// Renders `max` passes and returns (passes, seconds, image) at each checkpoint.
fn render_checkpoints(
    file: &scene_toml::SceneFile,
    settings: &ppb::settings::RenderSettings,
    octrees: &[Octree],
    checkpoints: &[u32],
) -> Result<Vec<(u32, f64, Image)>> {
    let r = Renderer::with_octrees(&file.scene, settings.clone(), octrees.to_vec())?;
    let mut film = Film::new(settings.width, settings.height);
    let mut out = Vec::new();
    let start = Instant::now();
    let max = checkpoints.iter().copied().max().unwrap_or(1);
    for i in 1..=max {
        film.add_pass(&r.pass(i).image);
        if checkpoints.contains(&i) {
            out.push((i, start.elapsed().as_secs_f64(), film.mean_image()));
        }
    }
    Ok(out)
}

/// Error at wall time `t` by log-log interpolation of (seconds, rel_l1) points,
/// extrapolating with the last two points' slope.
fn error_at_time(points: &[(f64, f64)], t: f64) -> f64 {
    let n = points.len();
    if n == 1 {
        return points[0].1;
    }
    let i = points.windows(2).position(|w| t <= w[1].0).unwrap_or(n - 2);
    let (a, b) = (points[i], points[i + 1]);
    let slope = (b.1.ln() - a.1.ln()) / (b.0.ln() - a.0.ln());
    (a.1.ln() + slope * (t.ln() - a.0.ln())).exp()
}

pub fn bench_tr(args: BenchTrArgs) -> Result<ExitCode> {
    let mut csv = String::from("scene,config,passes,seconds,rel_l1,rel_l1_media\n");
    let mut checkpoints = args.passes.clone();
    checkpoints.sort_unstable();
    checkpoints.dedup();
    let longest = *checkpoints.last().unwrap_or(&1);
    for spec in &args.scenes {
        let (scene, reference) = match spec.split_once('=') {
            Some((s, r)) => (PathBuf::from(s), Some(PathBuf::from(r))),
            None => (PathBuf::from(spec), None),
        };
        let file = scene_toml::load(&scene)?;
        let mut base = file.settings.clone();
        // One bake per scene: the octrees do not depend on the render settings varied here.
        let octrees: Vec<Octree> = file
            .scene
            .grid_media
            .iter()
            .map(|g| Octree::build(g, base.octree_depth))
            .collect();
        let full = Renderer::with_octrees(&file.scene, base.clone(), octrees.clone())?;
        // Keep the full-resolution radii so the kernels blur the same world distance.
        base.beam_radius = ppb::settings::Radius::Fixed(full.beam_r1);
        base.photon_radius = ppb::settings::Radius::Fixed(full.photon_r1);
        (base.width, base.height) = args.size;
        if let Some(b) = args.beams {
            base.beams_per_pass = b.max(1);
        }
        let (reference, ref_note) = match reference {
            Some(p) => {
                let img = output::read_exr(&p)?;
                let k = img.width / base.width as usize;
                if k == 0
                    || img.width != k * base.width as usize
                    || img.height != k * base.height as usize
                {
                    anyhow::bail!(
                        "{}: {}x{} is not a multiple of {}x{}",
                        p.display(),
                        img.width,
                        img.height,
                        base.width,
                        base.height
                    );
                }
                (
                    block_mean(&img, k),
                    format!("{} ({k}x{k} block means)", p.display()),
                )
            }
            None => {
                let mut s = base.clone();
                s.free_path = Mode::Adaptive;
                s.tr_mode = TrMode::Ratio;
                s.seed = base.seed + 1000;
                let passes = 16 * longest;
                eprintln!(
                    "{}: rendering a reference with {passes} passes",
                    scene.display()
                );
                let img = render_checkpoints(&file, &s, &octrees, &[passes])?
                    .remove(0)
                    .2;
                (
                    img,
                    format!("ppb adaptive+ratio, {passes} passes, other seed"),
                )
            }
        };
        // Pixels outside the media region are skipped by the second metric.
        let outside: Vec<bool> =
            Renderer::with_octrees(&file.scene, base.clone(), octrees.clone())?
                .camera_optical_depths()
                .iter()
                .map(|&tau| tau < args.media_depth)
                .collect();
        let in_media = outside.iter().filter(|&&o| !o).count();
        println!(
            "\n{} at {}x{}; reference: {ref_note}; media region: {in_media} pixels with optical depth >= {}",
            scene.display(),
            base.width,
            base.height,
            args.media_depth
        );
        println!(
            "{:<24} {:>7} {:>9} {:>9} {:>12}",
            "config", "passes", "seconds", "rel_l1", "rel_l1 media"
        );
        let mut curves = Vec::new();
        for (name, mode, tr) in TR_CONFIGS {
            let mut s = base.clone();
            s.free_path = mode;
            s.tr_mode = tr;
            let mut curve = Vec::new();
            for (passes, secs, img) in render_checkpoints(&file, &s, &octrees, &checkpoints)? {
                let e = metrics(&img, &reference, None)?.rel_l1;
                let em = metrics(&img, &reference, Some(&outside))?.rel_l1;
                println!("{name:<24} {passes:>7} {secs:>9.2} {e:>9.4} {em:>12.4}");
                csv.push_str(&format!(
                    "{},{name},{passes},{secs:.4},{e:.6},{em:.6}\n",
                    scene.display()
                ));
                curve.push((secs, e, em));
            }
            curves.push((name, curve));
        }
        let budget = curves[0].1.last().map_or(1.0, |p| p.0);
        let at = |curve: &[(f64, f64, f64)], media: bool| {
            let pts: Vec<(f64, f64)> = curve
                .iter()
                .map(|p| (p.0, if media { p.2 } else { p.1 }))
                .collect();
            error_at_time(&pts, budget)
        };
        let (base_err, base_media) = (at(&curves[0].1, false), at(&curves[0].1, true));
        println!("equal time ({budget:.1} s, the PPB baseline's {longest} passes):");
        for (name, curve) in &curves {
            let (e, em) = (at(curve, false), at(curve, true));
            println!(
                "  {name:<24} rel_l1 {e:.4} ({:.2}x lower than PPB), media region {em:.4} ({:.2}x)",
                base_err / e,
                base_media / em
            );
        }
    }
    if let Some(p) = &args.csv {
        output::write_atomic(p, |tmp| {
            std::fs::write(tmp, &csv).map_err(|e| ppb::error::Error::io(tmp, e))
        })?;
    }
    Ok(ExitCode::SUCCESS)
}

/// Prints one loaded grid: bounds, voxel size, counts, value range and memory.
fn print_grid(g: &ppb::media::grid::Grid) {
    let m = g.index_to_world.matrix3;
    let voxel = glam::DVec3::new(m.x_axis.length(), m.y_axis.length(), m.z_axis.length());
    println!(
        "  voxel size   {:.6} {:.6} {:.6}",
        voxel.x, voxel.y, voxel.z
    );
    if let Some((lo, hi)) = g.active_bbox() {
        let wlo = g.index_to_world.transform_point3(lo.as_dvec3());
        let whi = g.index_to_world.transform_point3(hi.as_dvec3());
        println!("  index bbox   {lo} .. {hi} (inclusive)");
        println!("  world bbox   {wlo:.4} .. {whi:.4} (voxel centres)");
    }
    let active = g.active_voxels();
    println!(
        "  active       {active} voxels, {} leaves, {} tiles",
        g.leaf_count(),
        g.tiles().len()
    );
    if let Some((lo, hi, mean)) = g.active_stats() {
        println!("  values       min {lo} max {hi} mean {mean:.6} (active voxels)");
    }
    let bytes = g.memory_bytes();
    println!(
        "  memory       {:.2} MiB, {:.2} bytes per active voxel",
        bytes as f64 / (1 << 20) as f64,
        bytes as f64 / active.max(1) as f64
    );
}

fn info_grid_file(path: &Path) -> Result<ExitCode> {
    let file = ppb::scene::grids::GridFile::open(path)?;
    println!("file         {}", path.display());
    for g in file.grids()? {
        println!("grid \"{}\": {}", g.name, g.kind);
        if g.loadable {
            print_grid(&file.load(&g.name)?);
        }
    }
    Ok(ExitCode::SUCCESS)
}

pub fn info(scene: &Path) -> Result<ExitCode> {
    if ppb::scene::Format::detect(scene).is_some_and(ppb::scene::Format::is_grid) {
        return info_grid_file(scene);
    }
    let file = scene_toml::load(scene)?;
    let s = &file.scene;
    println!("scene      {}", scene.display());
    println!(
        "image      {}x{}, {} passes, {} light paths per pass",
        file.settings.width,
        file.settings.height,
        file.settings.passes,
        file.settings.beams_per_pass
    );
    println!(
        "camera     origin {:?} target {:?} vfov {}",
        s.camera.origin, s.camera.target, s.camera.vfov_deg
    );
    for m in &s.materials {
        println!("material   {}: {:?}", m.name, m.material);
    }
    for m in &s.meshes {
        println!(
            "mesh       {}: {} triangles, material {}",
            m.name,
            m.triangles.len(),
            s.materials.get(m.material).map_or("?", |x| x.name.as_str())
        );
    }
    for l in &s.lights {
        println!("light      {l:?}");
    }
    for m in &s.media {
        println!(
            "medium     homogeneous {:?}..{:?} sigma_t {} albedo {:?} g {}",
            m.bounds[0], m.bounds[1], m.sigma_t, m.albedo, m.phase.g
        );
    }
    for g in &s.grid_media {
        println!(
            "medium       grid {}: bounds {:?}..{:?}, density_scale {}, majorant {} 1/m, albedo {:?} g {}",
            g.source, g.bounds[0], g.bounds[1], g.density_scale, g.majorant(), g.albedo, g.phase.g
        );
        print_grid(&g.grid);
    }
    for p in &file.sources[1..] {
        println!("source     {}", p.display());
    }
    for n in &file.notes {
        println!("usd        {n}");
    }
    Ok(ExitCode::SUCCESS)
}

#[derive(Args)]
pub struct BenchGpuArgs {
    #[command(flatten)]
    pub bench: BenchArgs,
    /// Device to measure against the CPU: gpu (any adapter, the default here) or auto
    /// (hardware adapters only).
    #[arg(long, value_enum, default_value = "gpu")]
    pub device: DeviceArg,
}

/// Times the beam estimate of the same traced passes on the CPU and on the GPU.
pub fn bench_gpu(args: BenchGpuArgs) -> Result<ExitCode> {
    println!(
        "{:<22} {:>9} {:>8} {:>10} {:>10} {:>8} {:>12} {:>12} {:>12} {:>9} {:>8}",
        "scene",
        "size",
        "beams",
        "CPU ms/ps",
        "GPU ms/ps",
        "CPU/GPU",
        "pairs/pass",
        "pairs/s CPU",
        "pairs/s GPU",
        "rel diff",
        "px>1e-3"
    );
    let mut adapter = String::new();
    for scene in &args.bench.scenes {
        let file = scene_toml::load(scene)?;
        let s = args.bench.settings(&file);
        let r = Renderer::new(&file.scene, s.clone())?;
        let Some(gpu) = open_device(args.device, true)? else {
            anyhow::bail!("no GPU adapter to measure (try --device gpu)");
        };
        adapter = gpu.describe();
        let pixels = s.width * s.height;
        let mut est = GpuBeams::new(gpu, r.media(), r.camera().origin(), pixels)?;
        let (mut cpu_s, mut gpu_s, mut pairs) = (0.0, 0.0, 0u64);
        let mut diff = DeviceDiff::default();
        for i in 1..=args.bench.passes {
            let t = r.trace(i, true);
            let start = Instant::now();
            let (cpu, evals) = r.beam_image(&t);
            cpu_s += start.elapsed().as_secs_f64();
            pairs += evals;
            est.clear()?;
            let start = Instant::now();
            est.submit(&t, r.media())?;
            let timing = est.wait()?.context("the pass was submitted")?;
            gpu_s += (timing.done - start).as_secs_f64();
            diff.add(&cpu, &est.read()?.0);
        }
        let n = args.bench.passes.max(1) as f64;
        let name = scene_name(scene);
        println!(
            "{:<22} {:>9} {:>8} {:>10.1} {:>10.1} {:>8.2} {:>12.0} {:>12.3e} {:>12.3e} {:>9.1e} {:>8}",
            name,
            format!("{}x{}", s.width, s.height),
            s.beams_per_pass,
            1e3 * cpu_s / n,
            1e3 * gpu_s / n,
            cpu_s / gpu_s.max(1e-12),
            pairs as f64 / n,
            pairs as f64 / cpu_s.max(1e-12),
            pairs as f64 / gpu_s.max(1e-12),
            diff.rel_l1(),
            diff.off_pixels
        );
    }
    println!(
        "(GPU: {adapter}; times per pass of the beam estimate alone on the same traced passes, \
         GPU including segment/BVH upload; pairs = beam-segment crossings within the radius; \
         rel diff = sum|GPU - CPU| / sum CPU over all passes; px>1e-3 = pixels (all passes) \
         differing by more than 1e-3 relative; CPU threads: {})",
        rayon::current_num_threads()
    );
    Ok(ExitCode::SUCCESS)
}
