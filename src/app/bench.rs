//! `ppb bench`: the paper's Table 1 (Woodcock against adaptive free-path sampling), and
//! what every benchmark shares (`BenchArgs`, one octree bake per scene for all its runs).
//! Each run is a session; `bench_tr`, `bench_gpu` and `bench_size` are the other
//! benchmarks.
use anyhow::Result;
use clap::Args;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

use ppb::error::Result as PpbResult;
use ppb::majorant::Mode;
use ppb::media::octrees::{self, OctreeStore};
use ppb::media::Media;
use ppb::pass::Tracer;
use ppb::scene::toml::SceneFile;
use ppb::session::{Flow, Session};
use ppb::settings::TrMode;
use ppb::settings::{Method, RenderSettings};
use ppb::transport::Counters;

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
pub(super) fn bake_once(file: &SceneFile, depth: u32) -> PpbResult<Media> {
    let scene = &file.scene;
    OctreeStore::new().media(
        &scene.media,
        &scene.grid_media,
        depth,
        None,
        |i, g, origin| eprintln!("{} (once, for all runs)", octrees::describe(i, g, origin)),
    )
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
        let media = bake_once(&file, settings.octree_depth)?;
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
