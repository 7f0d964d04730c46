//! `ppb bench-tr`: the paper's Figs. 11 and 12, error against passes and at equal time for
//! five free-path / camera-transmittance configurations, and unbiased ray marching.
use anyhow::Result;
use clap::Args;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

use ppb::compare::{block_mean, compare as metrics};
use ppb::majorant::Mode;
use ppb::media::Media;
use ppb::output::{self, Image};
use ppb::pass::Tracer;
use ppb::scene::toml::SceneFile;
use ppb::session::{Flow, Session};
use ppb::settings::TrMode;
use ppb::settings::{Method, RenderSettings};

use super::bench::bake_once;
use super::{parse_size, LightPaths, Overrides};

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

/// The five configurations of the paper's Figs. 11 and 12, and unbiased ray marching.
const TR_CONFIGS: [(&str, Mode, TrMode); 6] = [
    ("woodcock+random (PPB)", Mode::Woodcock, TrMode::Random),
    ("woodcock+stratified", Mode::Woodcock, TrMode::Stratified),
    ("adaptive+random", Mode::Adaptive, TrMode::Random),
    ("adaptive+stratified", Mode::Adaptive, TrMode::Stratified),
    ("adaptive+ratio", Mode::Adaptive, TrMode::Ratio),
    ("adaptive+march", Mode::Adaptive, TrMode::March),
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
        let media = bake_once(&file, base.octree_depth)?;
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
        ppb::core::fs::write_atomic(p, |tmp| {
            std::fs::write(tmp, &csv).map_err(|e| ppb::error::Error::io(tmp, e))
        })?;
    }
    Ok(ExitCode::SUCCESS)
}
