//! The benchmarks: `ppb bench` (the paper's Table 1), `ppb bench-tr` (its Figs. 11 and 12)
//! and `ppb bench-gpu` (the beam estimate on both devices). Each run is a session; the
//! octrees of a scene are baked once and shared by all its runs.
use anyhow::Result;
use clap::Args;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::{Arc, Mutex};
use std::time::Instant;

use ppb::compare::{block_mean, compare as metrics, DeviceDiff};
use ppb::error::Result as PpbResult;
use ppb::estimate::Estimator;
use ppb::film::Film;
use ppb::gpu::beams::{CameraTr, GpuBeams, GpuOptions, PrimaryPath};
use ppb::gpu::DeviceKind;
use ppb::media::Media;
use ppb::output::{self, Image};
use ppb::pass::{TracedPass, Tracer};
use ppb::scene::toml::SceneFile;
use ppb::session::{Flow, Session};
use ppb::settings::{Method, RenderSettings};
use ppb::transport::freepath::Mode;
use ppb::transport::transmittance::TrMode;
use ppb::transport::Counters;
use ppb::watch::octrees;

use super::{parse_size, scene_name, LightPaths, Overrides};

#[derive(Args)]
pub struct BenchArgs {
    /// Scene files (.toml).
    #[arg(required = true)]
    pub scenes: Vec<PathBuf>,
    /// Passes per scene.
    #[arg(long, default_value_t = 4)]
    pub passes: u32,
    #[command(flatten)]
    pub paths: LightPaths,
    /// Image size override, e.g. 128x128.
    #[arg(long, value_parser = parse_size)]
    pub size: Option<(u32, u32)>,
    /// Method of the runs: ppb (the default), the paper's pure method, reproduces its
    /// Table 1; hybrid measures the renderer's default.
    #[arg(long, value_enum, default_value = "ppb")]
    pub method: Method,
    /// The frame to load, for scenes whose paths hold the frame token (`#`), e.g. a VDB
    /// sequence.
    #[arg(long)]
    pub frame: Option<u32>,
}

impl BenchArgs {
    /// A scene of this benchmark, at `--frame` when given.
    pub(super) fn load(&self, scene: &std::path::Path) -> Result<SceneFile> {
        super::load_frame(scene, self.frame)
    }

    /// The scene's settings with this benchmark's overrides.
    pub(super) fn settings(&self, file: &SceneFile) -> Result<RenderSettings> {
        Overrides {
            size: self.size,
            paths: self.paths.clone(),
            method: Some(self.method),
            ..Default::default()
        }
        .apply(&file.settings)
    }
}

/// The scene's media with every grid's octree baked once, in memory, for all of a
/// benchmark's runs; one line per grid says so.
fn bake_once(file: &SceneFile, depth: u32) -> Media {
    octrees::bake(&file.scene, depth, |i, g, origin| {
        eprintln!("{} (once, for all runs)", octrees::describe(i, g, origin))
    })
}

/// One benchmark run: free-path thread-seconds, wall seconds, counters.
pub(super) struct BenchRun {
    pub(super) fps: f64,
    pub(super) total: f64,
    pub(super) c: Counters,
}

pub(super) fn bench_run(
    file: &SceneFile,
    settings: &RenderSettings,
    media: &Media,
    passes: u32,
    mode: Mode,
) -> Result<BenchRun> {
    let mut s = settings.clone();
    s.free_path = mode;
    // Same camera estimator for both, so the table isolates the free-path sampler.
    s.tr_mode = TrMode::Random;
    let mut session = Session::cpu(Tracer::with_media(&file.scene, s, media.clone())?);
    let start = Instant::now();
    session.run(1..=passes.max(1), |_, _| {
        Ok::<_, anyhow::Error>(Flow::Continue)
    })?;
    let c = session.counters;
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
pub(super) fn median_run(mut runs: Vec<BenchRun>) -> BenchRun {
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
        let file = args.load(scene)?;
        let settings = args.settings(&file)?;
        let media = bake_once(&file, settings.octree_depth);
        let (mut ws, mut adaptive) = (Vec::new(), Vec::new());
        for _ in 0..table.repeat {
            let run = |mode| bench_run(&file, &settings, &media, args.passes, mode);
            ws.push(run(Mode::Woodcock)?);
            adaptive.push(run(Mode::Adaptive)?);
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
    #[command(flatten)]
    pub paths: LightPaths,
    /// Write every measurement as CSV (scene,config,passes,seconds,rel_l1,rel_l1_media)
    /// for tools/plot_tr.py.
    #[arg(long)]
    pub csv: Option<PathBuf>,
    /// The second error column covers the pixels whose centre ray crosses at least this
    /// optical depth of media before the first surface (the paper measured its error in a
    /// region of the smoke).
    #[arg(long, default_value_t = 0.1)]
    pub media_depth: f32,
    /// Method of the runs: ppb (the default), the paper's pure method, reproduces its
    /// Figs. 11 and 12; hybrid measures the renderer's default.
    #[arg(long, value_enum, default_value = "ppb")]
    pub method: Method,
}

/// The five configurations of the paper's Figs. 11 and 12.
const TR_CONFIGS: [(&str, Mode, TrMode); 5] = [
    ("woodcock+random (PPB)", Mode::Woodcock, TrMode::Random),
    ("woodcock+stratified", Mode::Woodcock, TrMode::Stratified),
    ("adaptive+random", Mode::Adaptive, TrMode::Random),
    ("adaptive+stratified", Mode::Adaptive, TrMode::Stratified),
    ("adaptive+ratio", Mode::Adaptive, TrMode::Ratio),
];

/// Renders up to the last checkpoint and returns (passes, seconds, image) at each.
fn render_checkpoints(
    file: &SceneFile,
    settings: &RenderSettings,
    media: &Media,
    checkpoints: &[u32],
) -> Result<Vec<(u32, f64, Image)>> {
    let tracer = Tracer::with_media(&file.scene, settings.clone(), media.clone())?;
    let mut session = Session::cpu(tracer);
    let mut out = Vec::new();
    let start = Instant::now();
    let max = checkpoints.iter().copied().max().unwrap_or(1);
    session.run(1..=max, |s, done| {
        if checkpoints.contains(&done.plan.index) {
            let secs = start.elapsed().as_secs_f64();
            out.push((done.plan.index, secs, s.image()?));
        }
        Ok::<_, anyhow::Error>(Flow::Continue)
    })?;
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

/// The reference at the benchmark's size: `path`'s block means, or (without one) a ppb
/// adaptive+ratio render of 16x the longest run's passes with another seed; and a note.
fn reference_image(
    path: Option<PathBuf>,
    file: &SceneFile,
    base: &RenderSettings,
    media: &Media,
    longest: u32,
) -> Result<(Image, String)> {
    Ok(match path {
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
                file.path.display()
            );
            let img = render_checkpoints(file, &s, media, &[passes])?.remove(0).2;
            (
                img,
                format!("ppb adaptive+ratio, {passes} passes, other seed"),
            )
        }
    })
}

/// A configuration's (seconds, rel_l1, rel_l1 in the media region) at each checkpoint.
type Curve = Vec<(f64, f64, f64)>;

/// Prints each configuration's error at the PPB baseline's wall time.
fn print_equal_time(curves: &[(&str, Curve)], longest: u32) {
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
    for (name, curve) in curves {
        let (e, em) = (at(curve, false), at(curve, true));
        println!(
            "  {name:<24} rel_l1 {e:.4} ({:.2}x lower than PPB), media region {em:.4} ({:.2}x)",
            base_err / e,
            base_media / em
        );
    }
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
        let file = super::load_scene(&scene)?;
        let mut base = file.settings.clone();
        // One bake per scene: the octrees do not depend on the render settings varied here.
        let media = bake_once(&file, base.octree_depth);
        let full = Tracer::with_media(&file.scene, base.clone(), media.clone())?;
        // Keep the full-resolution radii so the kernels blur the same world distance.
        base.beam_radius = ppb::settings::Radius::Fixed(full.beam_r1);
        base.photon_radius = ppb::settings::Radius::Fixed(full.photon_r1);
        base.smooth_photon_radius = ppb::settings::Radius::Fixed(full.smooth_photon_r1);
        let over = Overrides {
            size: Some(args.size),
            paths: args.paths.clone(),
            method: Some(args.method),
            ..Default::default()
        };
        base = over.apply(&base)?;
        let (reference, ref_note) = reference_image(reference, &file, &base, &media, longest)?;
        // Pixels outside the media region are skipped by the second metric.
        let outside: Vec<bool> = Tracer::with_media(&file.scene, base.clone(), media.clone())?
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
            for (passes, secs, img) in render_checkpoints(&file, &s, &media, &checkpoints)? {
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
        print_equal_time(&curves, longest);
    }
    if let Some(p) = &args.csv {
        output::write_atomic(p, |tmp| {
            std::fs::write(tmp, &csv).map_err(|e| ppb::error::Error::io(tmp, e))
        })?;
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
    pub device: DeviceKind,
}

/// What `bench-gpu` measures over a session's passes.
#[derive(Default)]
struct DeviceRace {
    cpu_seconds: f64,
    gpu_seconds: f64,
    pairs: u64,
    diff: DeviceDiff,
    /// Why this way stopped (a software adapter's loop limit, say); the others go on.
    failed: Option<String>,
}

/// An estimator that runs every pass's beam estimate on the CPU (into the film) and, on
/// their own, on the GPU once per way of estimating primary segments, timing each and
/// comparing their images with the CPU's.
struct Race {
    gpus: Vec<GpuBeams>,
    out: Arc<Mutex<Vec<DeviceRace>>>,
}

impl Estimator for Race {
    fn describe(&self) -> String {
        self.gpus
            .first()
            .map_or_else(|| "cpu".into(), |g| g.describe())
    }

    fn needs_beam_map(&self) -> bool {
        true
    }

    fn estimate(
        &mut self,
        tracer: &Tracer,
        t: &TracedPass,
        film: &mut Film,
        _traced: (Instant, Instant),
    ) -> PpbResult<u64> {
        let start = Instant::now();
        let (cpu, evals) = tracer.beam_image(t);
        let cpu_seconds = start.elapsed().as_secs_f64();
        film.add(&cpu);
        for (k, gpu) in self.gpus.iter_mut().enumerate() {
            if self.out.lock().unwrap_or_else(|e| e.into_inner())[k]
                .failed
                .is_some()
            {
                continue;
            }
            let run = |gpu: &mut GpuBeams| -> PpbResult<(f64, Vec<[f32; 4]>)> {
                gpu.clear()?;
                let start = Instant::now();
                gpu.submit(t, tracer.media())?;
                let done = gpu.wait()?.map_or_else(Instant::now, |t| t.done);
                Ok(((done - start).as_secs_f64(), gpu.read()?.0))
            };
            let result = run(gpu);
            let mut out = self.out.lock().unwrap_or_else(|e| e.into_inner());
            let o = &mut out[k];
            match result {
                Ok((gpu_seconds, acc)) => {
                    o.cpu_seconds += cpu_seconds;
                    o.gpu_seconds += gpu_seconds;
                    o.pairs += evals;
                    o.diff.add(&cpu, &acc);
                }
                Err(e) => o.failed = Some(e.to_string()),
            }
        }
        Ok(evals)
    }

    fn held(&mut self) -> PpbResult<Option<Vec<[f32; 4]>>> {
        Ok(None)
    }

    fn clear(&mut self) -> PpbResult<()> {
        Ok(())
    }
}

/// Times the beam estimate of the same traced passes on the CPU and on the GPU.
pub fn bench_gpu(args: BenchGpuArgs) -> Result<ExitCode> {
    println!(
        "{:<22} {:<7} {:>9} {:>8} {:>10} {:>10} {:>8} {:>12} {:>12} {:>12} {:>9} {:>8}",
        "scene",
        "primary",
        "size",
        "paths",
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
        let file = args.bench.load(scene)?;
        let s = args.bench.settings(&file)?;
        let tracer = Tracer::new(&file.scene, s.clone())?;
        let Some(gpu) = super::open_device(args.device, true)? else {
            anyhow::bail!("no GPU adapter to measure (try --device gpu)");
        };
        adapter = gpu.describe();
        let mut paths = vec![PrimaryPath::Gather];
        if PrimaryPath::Auto.resolve(&gpu, s.width, s.height)? != PrimaryPath::Gather {
            paths.insert(0, PrimaryPath::Raster);
        }
        let gpus = paths
            .iter()
            .map(|&p| {
                let opts = GpuOptions::new(p, CameraTr::Steps, &tracer.settings);
                GpuBeams::new(gpu.clone(), tracer.media(), tracer.camera(), opts)
            })
            .collect::<PpbResult<Vec<_>>>()?;
        let out = Arc::new(Mutex::new(
            paths.iter().map(|_| DeviceRace::default()).collect(),
        ));
        let race = Race {
            gpus,
            out: out.clone(),
        };
        let mut session = Session::new(tracer, Box::new(race));
        session.run(1..=args.bench.passes, |_, _| {
            Ok::<_, anyhow::Error>(Flow::Continue)
        })?;
        let races = out.lock().unwrap_or_else(|e| e.into_inner());
        for (path, r) in paths.iter().zip(races.iter()) {
            if let Some(why) = &r.failed {
                println!(
                    "{:<22} {:<7} failed: {why}",
                    scene_name(scene),
                    format!("{path:?}").to_lowercase()
                );
                continue;
            }
            let n = args.bench.passes.max(1) as f64;
            println!(
            "{:<22} {:<7} {:>9} {:>8} {:>10.1} {:>10.1} {:>8.2} {:>12.0} {:>12.3e} {:>12.3e} {:>9.1e} {:>8}",
            scene_name(scene),
            format!("{path:?}").to_lowercase(),
            format!("{}x{}", s.width, s.height),
            s.light_paths,
            1e3 * r.cpu_seconds / n,
            1e3 * r.gpu_seconds / n,
            r.cpu_seconds / r.gpu_seconds.max(1e-12),
            r.pairs as f64 / n,
            r.pairs as f64 / r.cpu_seconds.max(1e-12),
            r.pairs as f64 / r.gpu_seconds.max(1e-12),
            r.diff.rel_l1(),
            r.diff.off_pixels
        );
        }
    }
    println!(
        "(GPU: {adapter}; times per pass of the beam estimate alone on the same traced passes, \
         GPU including segment/BVH upload; primary: how the GPU estimated primary segments \
         (raster: beam quads, where the adapter can blend float32 targets; gather: BVH queries); pairs = beam-segment crossings within the radius; \
         rel diff = sum|GPU - CPU| / sum CPU over all passes; px>1e-3 = pixels (all passes) \
         differing by more than 1e-3 relative; CPU threads: {})",
        rayon::current_num_threads()
    );
    Ok(ExitCode::SUCCESS)
}
