//! `ppb bench-size`: the cost of free-path sampling against grid size. The scene's noise
//! media are rebuilt at each resolution (the same cloud, finer voxels), their octrees baked
//! once, and Woodcock and adaptive sampling run interleaved as in `ppb bench`.
use anyhow::{Context, Result};
use clap::Args;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

use ppb::majorant::Mode;
use ppb::media::Media;
use ppb::scene::toml::{self as scene_toml, SceneFile};

use super::bench::{bench_run, median_run, BenchArgs, BenchRun};
use super::scene_name;

#[derive(Args)]
pub struct BenchSizeArgs {
    #[command(flatten)]
    pub bench: BenchArgs,
    /// Voxels along the longest axis of every noise medium, one table row each.
    #[arg(long, value_delimiter = ',', default_value = "64,128,256,512,1024")]
    pub resolutions: Vec<u32>,
    /// Runs of each sampler per row, interleaved; the row shows the median runs.
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u32).range(1..=99))]
    pub repeat: u32,
}

/// `scene` with every `type = "noise"` medium at `resolution`; an error if it has none.
fn at_resolution(scene: &PathBuf, resolution: u32) -> Result<SceneFile> {
    let text = std::fs::read_to_string(scene)
        .with_context(|| format!("{}: cannot read", scene.display()))?;
    let mut doc: toml::Table =
        toml::from_str(&text).with_context(|| format!("{}: not TOML", scene.display()))?;
    let mut found = false;
    if let Some(toml::Value::Array(media)) = doc.get_mut("medium") {
        for m in media.iter_mut().filter_map(|m| m.as_table_mut()) {
            if m.get("type").and_then(|t| t.as_str()) == Some("noise") {
                m.insert("resolution".into(), toml::Value::Integer(resolution.into()));
                found = true;
            }
        }
    }
    if !found {
        anyhow::bail!(
            "{}: medium: expected at least one `type = \"noise\"` medium to resize",
            scene.display()
        );
    }
    Ok(scene_toml::parse(scene, &toml::to_string(&doc)?)?)
}

/// Peak resident memory since the last [`reset_peak`] (Linux), in bytes.
fn peak_rss() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

/// Restarts the peak-memory count (Linux's clear_refs; ignored where unsupported).
fn reset_peak() {
    let _ = std::fs::write("/proc/self/clear_refs", "5");
}

pub fn bench_size(args: BenchSizeArgs) -> Result<ExitCode> {
    let b = &args.bench;
    if b.scenes.len() != 1 {
        anyhow::bail!("bench-size takes one scene (its noise media are resized)");
    }
    let scene = &b.scenes[0];
    println!(
        "{}: {} passes, {} runs per sampler",
        scene_name(scene),
        b.passes,
        args.repeat
    );
    println!(
        "{:>5} {:>9} {:>8} {:>7} {:>6} {:>8} {:>8} {:>8} {:>6} {:>11} {:>7} {:>7} {:>6} {:>8} {:>8} {:>8}",
        "res",
        "active",
        "grid MiB",
        "load s",
        "depth",
        "leaves",
        "build s",
        "FPS W",
        "FPS A",
        "ratio",
        "lkp W",
        "lkp A",
        "ratio",
        "pass W",
        "pass A",
        "peak MiB"
    );
    for &res in &args.resolutions {
        reset_peak();
        let start = Instant::now();
        let file = at_resolution(scene, res)?;
        let load = start.elapsed().as_secs_f64();
        let settings = b.settings(&file)?;
        let start = Instant::now();
        let scene = &file.scene;
        let media = Media::bake(
            scene.media.clone(),
            &scene.grid_media,
            settings.octree_depth,
        );
        let build = start.elapsed().as_secs_f64();
        let (mut ws, mut adaptive) = (Vec::new(), Vec::new());
        for _ in 0..args.repeat {
            let run = |mode| bench_run(&file, &settings, &media, b.passes, mode);
            ws.push(run(Mode::Woodcock)?);
            adaptive.push(run(Mode::Adaptive)?);
        }
        let ratios: Vec<f64> = ws
            .iter()
            .zip(&adaptive)
            .map(|(w, a)| w.fps / a.fps.max(1e-9))
            .collect();
        let (lo, hi) = ratios
            .iter()
            .fold((f64::MAX, f64::MIN), |(l, h), &r| (l.min(r), h.max(r)));
        let (w, a) = (median_run(ws), median_run(adaptive));
        let per = |r: &BenchRun| r.c.density_lookups as f64 / r.c.free_paths.max(1) as f64;
        let grids = media.grids.iter();
        let active: u64 = grids.clone().map(|g| g.grid.active_voxels()).sum();
        let bytes: usize = grids.clone().map(|g| g.grid.memory_bytes()).sum();
        let depth = grids.clone().map(|g| g.octree().depth()).max().unwrap_or(0);
        let leaves: usize = grids.map(|g| g.octree().leaf_count()).sum();
        let mib = |x: f64| x / (1u64 << 20) as f64;
        println!(
            "{:>5} {:>8.2}M {:>8.1} {:>7.2} {:>6} {:>8} {:>8.2} {:>8.3} {:>6.3} {:>11} {:>7.2} {:>7.2} {:>6.1} {:>8.3} {:>8.3} {:>8}",
            res,
            active as f64 / 1e6,
            mib(bytes as f64),
            load,
            depth,
            leaves,
            build,
            w.fps,
            a.fps,
            format!("{:.2} ({lo:.1}-{hi:.1})", w.fps / a.fps.max(1e-9)),
            per(&w),
            per(&a),
            per(&w) / per(&a).max(1e-9),
            w.total / b.passes.max(1) as f64,
            a.total / b.passes.max(1) as f64,
            peak_rss().map_or("n/a".into(), |p| format!("{:.0}", mib(p as f64)))
        );
    }
    println!(
        "(active = active voxels; load = scene load incl. the procedural grid; depth = deepest \
octree level; build = octree bake; FPS = free-path sampling incl. camera transmittance, \
thread-seconds / threads, median run, ratio with its range over the interleaved pairs; lkp = \
density lookups per free path; pass = wall seconds per pass; peak = peak resident memory \
of this row)"
    );
    Ok(ExitCode::SUCCESS)
}
