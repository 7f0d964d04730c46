//! The command line: arguments, progress, status lines and outputs. Every command that
//! renders drives a [`ppb::session::Session`]; this module only configures it.
mod bench;
mod bench_gpu;
mod bench_size;
mod bench_tr;
mod build;
mod compare;
mod farm;
mod info;
mod isolate;
mod live;
mod merge;
mod plan;
mod progress;
mod render;
mod watch;
mod window;

use anyhow::{Context, Result};
use clap::Args;
use std::path::{Path, PathBuf};

pub use bench::{bench, BenchTableArgs};
pub use bench_gpu::{bench_gpu, BenchGpuArgs};
pub use bench_size::{bench_size, BenchSizeArgs};
pub use bench_tr::{bench_tr, BenchTrArgs};
pub use build::{build, BuildArgs};
pub use compare::{compare, CompareArgs};
pub use farm::{farm, FarmArgs};
pub use info::info;
pub use isolate::{probe_in_child, usd_probe};
pub use merge::{merge, MergeArgs};
pub use plan::{plan, PlanArgs};
pub use render::{render, RenderArgs};
pub use watch::{watch, WatchArgs};

use ppb::gpu::beams::{CameraTr, PrimaryPath};
use ppb::gpu::{DeviceKind, Gpu};
use ppb::majorant::Mode;
use ppb::media::octrees::{self, OctreeStore};
use ppb::media::Media;
use ppb::output::{self, ExrMeta, Image};
use ppb::scene::toml::{self as scene_toml, SceneFile};
use ppb::settings::TrMode;
use ppb::settings::{Bandwidth, Method, RenderSettings};

/// Command-line overrides of a scene's `[render]` settings, shared by every command that
/// renders and applied in one place ([`Overrides::apply`]).
#[derive(Args, Clone, Debug, Default)]
pub struct Overrides {
    /// Random seed (overrides [render].seed); the image depends only on it, not on threads.
    #[arg(long)]
    pub seed: Option<u64>,
    /// Image size, e.g. 64x64 (overrides [render].width and height).
    #[arg(long, value_parser = parse_size)]
    pub size: Option<(u32, u32)>,
    #[command(flatten)]
    pub paths: LightPaths,
    /// PNG (and window) exposure in stops (overrides [render].exposure).
    #[arg(long)]
    pub exposure: Option<f32>,
    /// Grid free paths (random, stratified) per camera segment per pass, or (ratio) the
    /// ratio tracking's rate in multiples of the majorant, as many lookups as that many
    /// trackings, or (march) the marches' lookups per unit of the majorant's optical depth
    /// times 2 (overrides [render].tr_samples; 1..=16, default 4).
    #[arg(long, value_name = "M")]
    pub tr_samples: Option<usize>,
    /// Free-path sampler for light paths and camera transmittance (overrides
    /// [render].free_path).
    #[arg(long, value_enum)]
    pub free_path: Option<Mode>,
    /// Camera-segment transmittance through grids: march (unbiased ray marching, Kettunen
    /// et al. 2021: jittered marches, one the control of a power series; cells of 2 / M of
    /// the majorant's optical depth; the default: lowest error per time in our
    /// measurements), ratio (ratio tracking on the octree's local majorants at M times
    /// them), stratified (the paper's estimator: free paths of --tr-block passes drawn at
    /// once, M strata) or random (M free paths per pass, the progressive deep shadow map).
    #[arg(long, value_enum)]
    pub transmittance: Option<TrMode>,
    /// Passes whose free paths the stratified estimator draws at once (N, <= 64, a
    /// multiple of --tr-samples). Memory: 4 N bytes per pixel (256 at N = 64).
    #[arg(long, value_name = "N")]
    pub tr_block: Option<usize>,
    /// Light samples per camera segment in media for single scattering (hybrid method;
    /// overrides [render].nee_samples; 1..=64, default 4). Their distances are stratified
    /// along the segment.
    #[arg(long, value_name = "K")]
    pub nee_samples: Option<usize>,
    /// How light reaches the camera (overrides [render].method). The default, hybrid,
    /// reaches a given error sooner; ppb reproduces the paper's tables.
    #[arg(long, value_enum)]
    pub method: Option<Method>,
    /// Transparent film (overrides [render].transparent): the environment is hidden from
    /// camera rays that leave the scene, and the EXR gets an alpha channel (A) for
    /// compositing over another background.
    #[arg(long)]
    pub transparent: bool,
    /// The beams' kernel radius per pixel (overrides [render].bandwidth): fixed (eq. 3's
    /// radius everywhere, the paper's) or adaptive (each pixel's between that radius and
    /// its half, by the estimated bias and noise: narrower at edges, wider where the
    /// radiance is smooth).
    #[arg(long, value_enum)]
    pub bandwidth: Option<ppb::settings::Bandwidth>,
    /// How a beam is blurred across its direction (overrides [render].beam_kernel): tube
    /// (a 2D disk, gathered over each camera ray's chord through it: no 1/sin(theta)
    /// weight, far less noise where a forward-scattering medium sends beams at the camera;
    /// the default where a phase function has |g| >= 0.3) or line (the paper's eq. 2; the
    /// default otherwise, and always with --method ppb). Both run on the CPU and the GPU.
    #[arg(long, value_enum)]
    pub beam_kernel: Option<ppb::settings::BeamKernel>,
}

impl Overrides {
    /// `base` (a scene's settings) with these overrides; one line warns of a deprecated
    /// flag.
    pub fn apply(&self, base: &RenderSettings) -> Result<RenderSettings> {
        let mut s = base.clone();
        if let Some(x) = self.seed {
            s.seed = x;
        }
        if let Some((w, h)) = self.size {
            (s.width, s.height) = (w, h);
        }
        if let Some(n) = self.paths.get() {
            s.light_paths = n;
        }
        if let Some(e) = self.exposure {
            s.exposure = e;
        }
        if let Some(m) = self.tr_samples {
            s.tr_samples = m;
        }
        if let Some(k) = self.nee_samples {
            s.nee_samples = k;
        }
        if let Some(f) = self.free_path {
            s.free_path = f;
        }
        if let Some(t) = self.transmittance {
            s.tr_mode = t;
        }
        if let Some(n) = self.tr_block {
            s.tr_block = n;
        }
        if let Some(m) = self.method {
            s.method = m;
        }
        s.transparent |= self.transparent;
        if let Some(b) = self.bandwidth {
            s.bandwidth = b;
        }
        if let Some(k) = self.beam_kernel {
            s.beam_kernel = Some(k);
        }
        if let Err(e) = s.validate() {
            let flag = match e.field {
                "width" | "height" => "--size".to_string(),
                f @ ("light_paths" | "tr_samples" | "nee_samples" | "tr_block" | "exposure") => {
                    format!("--{}", f.replace('_', "-"))
                }
                f => format!("[render].{f}"),
            };
            anyhow::bail!("{flag}: {}", e.msg);
        }
        Ok(s)
    }
}

/// `--light-paths` and its deprecated old name `--beams`.
#[derive(Args, Clone, Debug, Default)]
pub struct LightPaths {
    /// Light paths traced per pass (overrides [render].light_paths).
    #[arg(long, value_name = "N")]
    pub light_paths: Option<usize>,
    /// Deprecated name of --light-paths.
    #[arg(long, hide = true, value_name = "N")]
    pub beams: Option<usize>,
}

impl LightPaths {
    /// The count asked for; one line warns of the old name.
    fn get(&self) -> Option<usize> {
        if self.beams.is_some() {
            eprintln!("warning: --beams is deprecated, use --light-paths (it counts light paths)");
        }
        self.light_paths.or(self.beams)
    }
}

/// Where a session runs: threads, octree cache and the beam estimate's device (shared by
/// `render` and `watch`).
#[derive(Args, Clone, Debug)]
pub struct Machine {
    /// Worker threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Where baked octrees are cached (default: .ppb-cache/ beside the scene).
    #[arg(long)]
    pub cache_dir: Option<PathBuf>,
    /// Where the beam estimate runs: auto (a hardware GPU if wgpu finds one, else the CPU),
    /// gpu (any adapter, software Vulkan such as lavapipe included; an error if none) or
    /// cpu. On the GPU the estimate of pass i overlaps the CPU tracing pass i+1. One line
    /// names the adapter. WGPU_BACKEND=vulkan|metal|dx12|gl narrows the search.
    #[arg(long, value_enum, default_value = "auto")]
    pub device: DeviceKind,
    /// How the GPU estimates primary camera segments: raster (each beam drawn as a quad on
    /// the film, the original PPB's way), gather (a beam BVH query per pixel, as for
    /// segments after glass) or auto (the first pass rasterised, the second gathered, then
    /// the one that took less GPU time per beam; gather where the adapter cannot blend
    /// float32 targets). All give the CPU's image; `--stats` records the choice.
    #[arg(long, value_enum, default_value = "auto")]
    pub gpu_primary: PrimaryPath,
    /// The GPU's camera transmittance: steps (the CPU's estimate of each segment, per
    /// --tr, uploaded every pass; the image equals the CPU's) or track (ratio tracking on
    /// the GPU over the same octrees, whatever --tr says; no per-pass upload, and another
    /// draw of the same estimate).
    #[arg(long, value_enum, default_value = "steps")]
    pub gpu_tr: CameraTr,
}

/// An error met while rendering (a device lost, an output that cannot be written), not
/// in the input: `ppb` exits 1 for it, 2 for bad input.
#[derive(Debug)]
pub struct Failed(anyhow::Error);

impl std::fmt::Display for Failed {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{:#}", self.0)
    }
}

impl std::error::Error for Failed {}

/// `e` marked as a failure of the render (exit code 1).
pub fn failed(e: impl Into<anyhow::Error>) -> anyhow::Error {
    anyhow::Error::new(Failed(e.into()))
}

/// Loads a scene file and prints its warnings (deprecated keys) on stderr.
fn load_scene(path: &Path) -> Result<SceneFile> {
    load_frame(path, None)
}

/// Loads frame `frame` of a scene (the frame token in its paths replaced) and prints its
/// warnings on stderr.
fn load_frame(path: &Path, frame: Option<u32>) -> Result<SceneFile> {
    if !path.exists() && !path.to_string_lossy().contains('#') {
        let hint = nearest_scene(path)
            .map(|s| format!(" (did you mean {}?)", s.display()))
            .unwrap_or_default();
        anyhow::bail!("{}: no such scene file{hint}", path.display());
    }
    let file = scene_toml::load_frame(path, frame)?;
    for w in &file.warnings {
        eprintln!("warning: {w}");
    }
    Ok(file)
}

/// The shipped scene (under `scenes/` here or in the source tree ppb was built from)
/// whose path is closest to `path` in edit distance, if any is close.
fn nearest_scene(path: &Path) -> Option<PathBuf> {
    let wanted = path.to_string_lossy();
    let mut best: Option<(f64, PathBuf)> = None;
    let roots = [
        PathBuf::from("scenes"),
        Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes"),
    ];
    for root in roots.iter().filter(|r| r.is_dir()) {
        let mut stack = vec![(root.clone(), 0)];
        while let Some((dir, depth)) = stack.pop() {
            let Ok(entries) = std::fs::read_dir(&dir) else {
                continue;
            };
            for e in entries.flatten() {
                let p = e.path();
                if p.is_dir() && depth < 3 {
                    stack.push((p, depth + 1));
                } else if p.extension().is_some_and(|x| x == "toml" || x == "usda") {
                    let score = strsim::normalized_levenshtein(&wanted, &p.to_string_lossy());
                    if best.as_ref().is_none_or(|(b, _)| score > *b) {
                        best = Some((score, p));
                    }
                }
            }
        }
        if best.is_some() {
            break;
        }
    }
    best.filter(|(score, _)| *score > 0.6).map(|(_, p)| p)
}

/// Sets the worker thread count (default: all cores).
fn set_threads(threads: Option<usize>) -> Result<()> {
    if let Some(n) = threads {
        rayon::ThreadPoolBuilder::new()
            .num_threads(n.max(1))
            .build_global()
            .context("setting up the thread pool")?;
    }
    Ok(())
}

/// The output path (default: `<scene stem>.exr` here), its folder created.
fn output_path(scene: &Path, over: Option<&PathBuf>) -> Result<PathBuf> {
    let out = over.cloned().unwrap_or_else(|| {
        let stem = scene.file_stem().unwrap_or_default().to_string_lossy();
        PathBuf::from(format!("{stem}.exr"))
    });
    if let Some(dir) = out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    Ok(out)
}

/// Opens the device for the beam estimate and says which in one line.
pub fn open_device(kind: DeviceKind, quiet: bool) -> Result<Option<Gpu>> {
    let gpu = ppb::gpu::open(kind)?;
    if !quiet {
        match &gpu {
            Some(g) => eprintln!("beam estimate on the GPU: {}", g.describe()),
            None if kind == DeviceKind::Auto => {
                eprintln!("beam estimate on the CPU (no hardware GPU adapter found)")
            }
            None => eprintln!("beam estimate on the CPU"),
        }
    }
    Ok(gpu)
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

/// The scene's media, every grid with its octree loaded from a valid cache in `dir`, else
/// built and stored. One line per grid medium says which (unless quiet).
fn cached_media(file: &SceneFile, depth: u32, dir: &Path, quiet: bool) -> Result<Media> {
    let scene = &file.scene;
    let media = OctreeStore::new().media(
        &scene.media,
        &scene.grid_media,
        depth,
        Some(dir),
        |i, g, origin| {
            if !quiet {
                eprintln!("{}", octrees::describe(i, g, origin));
            }
        },
    )?;
    Ok(media)
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

/// What an output's EXR header records besides the pixels.
struct OutputMeta<'a> {
    scene: &'a Path,
    settings: &'a RenderSettings,
    /// The beam kernel that ran (the settings may say auto).
    kernel: ppb::settings::BeamKernel,
    passes: u32,
    seconds: f64,
    /// More header attributes (e.g. `ppb watch`'s reload number).
    extra: &'a [(String, String)],
}

impl OutputMeta<'_> {
    /// The EXR header: OpenEXR's standard attributes and `ppb/...` for the rest.
    fn exr(&self) -> ExrMeta {
        let s = self.settings;
        let mut m = ExrMeta::text(&[
            ("ppb/version", env!("CARGO_PKG_VERSION").to_string()),
            ("ppb/scene", self.scene.display().to_string()),
            ("ppb/passes", self.passes.to_string()),
            ("ppb/render_seconds", format!("{:.3}", self.seconds)),
            ("ppb/method", format!("{:?}", s.method).to_lowercase()),
            ("ppb/transparent", s.transparent.to_string()),
            ("ppb/bandwidth", format!("{:?}", s.bandwidth).to_lowercase()),
            (
                "ppb/beam_kernel",
                format!("{:?}", self.kernel).to_lowercase(),
            ),
            ("ppb/light_paths", s.light_paths.to_string()),
            ("ppb/alpha", s.alpha.to_string()),
            ("ppb/photon_alpha", s.photon_alpha.to_string()),
            ("ppb/seed", s.seed.to_string()),
            ("ppb/beam_radius", format!("{:?}", s.beam_radius)),
            ("ppb/photon_radius", format!("{:?}", s.photon_radius)),
            (
                "ppb/smooth_photon_radius",
                format!("{:?}", s.smooth_photon_radius),
            ),
        ]);
        for (k, v) in self.extra {
            m.set(k, v.clone());
        }
        m.owner = std::env::var("USER").ok().filter(|u| !u.is_empty());
        m.comments = Some(format!("rendered by ppb from {}", self.scene.display()));
        m
    }
}

/// Writes the EXR (atomically, settings in the header) and its PNG preview beside it.
fn write_outputs(out: &Path, img: &Image, m: &OutputMeta) -> Result<()> {
    write_image(out, img, &m.exr(), m.settings.exposure)
}

/// Writes the EXR with header `meta` and its PNG preview beside it.
fn write_image(out: &Path, img: &Image, meta: &ExrMeta, exposure: f32) -> Result<()> {
    write_image_with(out, img, meta, &[], exposure)
}

/// The film's error estimate (of the image `bandwidth` resolves) as EXR attributes
/// `ppb/estimated_rel_l1` (per pixel), `ppb/estimated_rel_l1_4x4`, and the bias part
/// alone as `ppb/estimated_bias_rel_l1` and `..._4x4` where the film has nested sums;
/// nothing until each half-film holds 2 passes.
fn set_error_estimate(meta: &mut ExrMeta, film: &ppb::film::Film, bandwidth: Bandwidth) {
    if let Some(e) = film.error_estimate(bandwidth) {
        meta.set("ppb/estimated_rel_l1", format!("{:.6}", e.pixel));
        meta.set("ppb/estimated_rel_l1_4x4", format!("{:.6}", e.block));
        if let Some(b) = e.bias {
            meta.set("ppb/estimated_bias_rel_l1", format!("{:.6}", b.pixel));
            meta.set("ppb/estimated_bias_rel_l1_4x4", format!("{:.6}", b.block));
        }
    }
}

/// [`write_image`] with `extra` EXR channels.
fn write_image_with(
    out: &Path,
    img: &Image,
    meta: &ExrMeta,
    extra: &[output::Channel],
    exposure: f32,
) -> Result<()> {
    output::write_exr_with(out, img, meta, extra)?;
    output::write_png(&out.with_extension("png"), img, exposure)?;
    Ok(())
}

/// A benchmark table's name for a scene: its folder's name.
fn scene_name(scene: &Path) -> String {
    scene.parent().and_then(|p| p.file_name()).map_or_else(
        || scene.display().to_string(),
        |n| n.to_string_lossy().into(),
    )
}
