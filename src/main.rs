//! `ppb`: the command line. Library errors become one line on stderr and exit code 2.
mod app;

use clap::{Parser, Subcommand};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

#[derive(Parser)]
#[command(
    name = "ppb",
    version,
    about = "Progressive photon beams renderer for fog, smoke and glass",
    long_about = "ppb renders participating media (fog, smoke, clouds) lit through glass onto diffuse \
surfaces with progressive photon beams (media) and progressive photon mapping (surfaces). \
The image converges to the exact solution as passes accumulate."
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Render a scene file to EXR (+ PNG preview).
    #[command(
        long_about = "Render a TOML scene file progressively and write an EXR (float32 linear \
RGB, with passes, seconds and settings in the header) and a PNG preview beside it.\n\n\
Radii: `beam_radius = \"auto\"` sets R1 to 2 pixel footprints at the distance from the camera to \
the centre of the media's bounds; `photon_radius = \"auto\"` sets the sharp photons' R1 (direct light, caustics) to 1.5 \
pixel footprints at the distance to the centre of the surfaces' bounds, and the smooth photons' \
to 10 times that. Both then shrink every pass by eq. 3 \
(beam radius, and photon radius squared, times (i + alpha) / (i + 1)).",
        after_help = "Examples:\n  ppb render scenes/conformance/fog-box/scene.toml -o out/fog-box.exr\n  ppb render scenes/conformance/smoke-grid/scene.toml --time 60 --stats out/stats.json\n  ppb render scenes/mantaflow/smoke.toml --frames 16,32,48 -o out/smoke.####.exr"
    )]
    Render(app::RenderArgs),
    /// Live preview: re-render progressively whenever the scene or an asset it uses changes.
    #[command(
        long_about = "Render a scene progressively and start again whenever it changes on disk, \
for moving lights, tweaking densities or re-exporting assets with ppb open.\n\n\
Watched: the scene file and every file it references: [[import]] and [[mesh]] files (glTF with \
its .bin buffers and images, OBJ with its .mtl, USD stages with their layers and VDB assets), \
grid media (.vdb, .nvdb) and a USD stage's .ppb.toml sidecar. Their folders are watched, so \
editors that save by writing a temp file and renaming it are seen.\n\n\
Reloaded: only what changed. A camera, light, material or settings edit re-reads the TOML and \
reuses the loaded meshes, grids and octrees; a changed asset is read again; a changed grid gets \
a new octree through the cache (.ppb-cache/, rebuilt only on a miss) while the other media keep \
theirs. An exposure-only edit keeps the image. Any other change restarts the accumulation, which \
refines until the pass budget (--passes, default [render].passes, 0 = forever). After a \
reload the first pass traces 1/8 of the light paths and each next one twice as many while a \
pass takes under 0.15 s, up to all of them, so the first preview comes fast and passes stay \
short (--no-ramp: all of them from the first). Reloads are applied between passes. \
--device gpu|auto estimates beams on the GPU as `ppb render` does.\n\n\
Errors: a syntax error, a missing or truncated asset or a file caught mid-write prints one line \
with the file and line, and the last good scene keeps rendering until the file is fixed. The \
EXR and PNG are rewritten atomically (after the first pass of each reload, then every \
--checkpoint), so a broken scene never replaces a good image.\n\n\
--window shows the image live (Vulkan through wgpu; title: passes, time, device, exposure, last error; keys: \
+/- exposure, S snapshot to <output>-snapshot-N.exr/png, Esc/Q quit). Without a display it \
prints an error and keeps writing the files. The terminal shows one status line: scene, pass, \
passes per second, the last reload and what it reloaded.",
        after_help = "Examples:\n  ppb watch scenes/noise-cloud/scene.toml --window\n  ppb watch shot.usda -o out/preview.exr --checkpoint 2s"
    )]
    Watch(app::WatchArgs),
    /// Compare two EXR images: rel_l1, relative RMSE, per-channel means.
    #[command(
        long_about = "Compare a candidate EXR against a reference EXR. Prints rel_l1 = \
sum|a - ref| / sum|ref| over all pixels and channels, relative RMSE and per-channel means. Exits 1 \
when rel_l1 exceeds --max-rel-l1, so CI pipelines can guard artifact renders.",
        after_help = "Example:\n  ppb compare out/fog-box.exr tests/data/conformance/fog-box/reference.exr --max-rel-l1 0.05"
    )]
    Compare(app::CompareArgs),
    /// Bake the majorant octrees of a scene's grid media into the cache.
    #[command(
        long_about = "Bake the majorant octree of every density-grid medium of a scene into \
the cache folder (default .ppb-cache/ beside the scene). The cache key is a blake3 hash of the \
grid file's bytes, the grid name, density scale and transform, the build settings and the cache \
format version. `ppb render` loads a valid cache and otherwise builds and stores it. With --check, \
print fresh or stale per medium and exit 1 if any is stale.",
        after_help = "Examples:\n  ppb build scenes/conformance/smoke-grid/scene.toml\n  ppb build scenes/conformance/smoke-grid/scene.toml --check"
    )]
    Build(app::BuildArgs),
    /// Free-path sampling benchmark: free paths and grid lookups per second on scenes.
    #[command(
        long_about = "Renders a few passes of each scene and prints a table of free-path \
sampling work: free paths, density (grid) lookups, lookups per free path (a machine-independent \
counter), and free paths and lookups per thread-second.",
        after_help = "Example:\n  ppb bench scenes/conformance/smoke-grid/scene.toml scenes/bench/dense-smoke/scene.toml --repeat 3"
    )]
    Bench(app::BenchTableArgs),
    /// Transmittance benchmark: error vs passes and at equal time (the paper's Figs. 11, 12).
    #[command(
        long_about = "Renders each scene with woodcock+random (the original PPB), \
woodcock+stratified, adaptive+random, adaptive+stratified, adaptive+ratio and adaptive+march (unbiased ray marching), and prints \
rel_l1 against the reference at each pass count with the wall time, then every configuration's \
error at the PPB baseline's wall time (log-log interpolation).",
        after_help = "Example:\n  ppb bench-tr scenes/conformance/smoke-grid/scene.toml=tests/data/conformance/smoke-grid/reference.exr"
    )]
    BenchTr(app::BenchTrArgs),
    /// Free-path sampling cost against grid size: the same cloud at 64^3 to 1024^3.
    #[command(
        long_about = "Rebuilds the scene's noise media at each resolution (voxels along the \
longest axis; the same cloud, finer voxels), bakes their octrees, renders a few passes with \
Woodcock (one global majorant) and with adaptive free-path sampling, interleaved, and prints per \
resolution: active voxels, grid memory, load and octree build time, octree depth and leaves, \
free-path time of each sampler and their ratio, density lookups per free path, wall time per \
pass and peak memory.",
        after_help = "Example:\n  ppb bench-size scenes/bench/size-cloud/scene.toml --resolutions 64,256,1024 --passes 4"
    )]
    BenchSize(app::BenchSizeArgs),
    /// GPU vs CPU beam estimate: time per pass, their ratio, crossings per second.
    #[command(
        long_about = "Traces a few passes of each scene once and runs the beam estimate of each \
pass on the CPU and on the GPU, printing milliseconds per pass on each, their ratio, beam-segment \
crossings per pass and per second, the relative L1 difference between the two images and the \
number of pixels that differ by more than 1e-3.",
        after_help = "Example:\n  ppb bench-gpu scenes/conformance/cloud-hg/scene.toml --size 256x256 --passes 8"
    )]
    BenchGpu(app::BenchGpuArgs),
    /// List a render's farm tasks: task index -> frame and pass range.
    #[command(
        long_about = "Print how a render splits into farm tasks: frame-major, each frame's passes \
cut into ranges of --passes-per-task. Task K is what `ppb render --task-index K` (or \
--task-index-env VAR) renders with the same --frames, --passes and --passes-per-task; the \
mapping is a pure function of those flags.\n\n\
Example:\n  ppb plan scenes/mantaflow/smoke.toml --frames 16-48 --passes 256 --passes-per-task 64 --json"
    )]
    Plan(app::PlanArgs),
    /// Merge a frame's part files into its image, bit-identical to one render.
    #[command(
        long_about = "Sum the part files of a frame (written by `ppb render --task-index` or \
--pass-range) into one EXR and PNG. The parts must come from the same scene and assets (hash), \
settings, resolution, seed, frame and ppb version, and cover the frame's passes exactly once; \
otherwise the merge names the files and stops. Sums are fixed-point, so the image is bit for bit \
the one a single `ppb render` of the same passes writes.\n\n\
Examples:\n  ppb merge out/shot.0016.passes-*.ppbpart -o out/shot.0016.exr\n  \
ppb merge --frames 16-48 -o out/shot.####.exr   (finds each frame's parts beside its output)"
    )]
    Merge(app::MergeArgs),
    /// Write job files that run a render on Slurm, OpenJD (Deadline Cloud) or Kubernetes.
    #[command(
        long_about = "Write the job files of a farm render: one task per (frame, pass range) \
running `ppb render --task-index-env ...`, and one merge per frame list after all of them \
succeed. ppb schedules nothing itself: the engine runs the tasks.\n\n\
slurm: render.sbatch (a job array), merge.sbatch and submit.sh (sbatch the array, then the \
merge with --dependency=afterok, and wait).\n\
openjd: job.template.yaml (a render step over a task index parameter and a merge step that \
depends on it), for `openjd run` or AWS Deadline Cloud.\n\
k8s: job.yaml (an Indexed Job reading JOB_COMPLETION_INDEX, and a merge Job) for a cluster \
whose nodes share the project folder at the same path.\n\n\
Example:\n  ppb farm slurm scenes/mantaflow/smoke.toml --frames 16-48 --passes 256 \
--passes-per-task 64 -o out/smoke.####.exr --jobs farm/"
    )]
    Farm(app::FarmArgs),
    /// Parse a USD stage and exit (ppb runs it in a child process before it parses a
    /// stage itself, so a crash in the USD reader cannot take a render down).
    #[command(name = "__usd-probe", hide = true)]
    UsdProbe {
        path: PathBuf,
        #[arg(long)]
        frame: Option<u32>,
    },
    /// Print what a scene file contains.
    #[command(
        after_help = "Examples:\n  ppb info scenes/conformance/glass-caustic/scene.toml\n  ppb info tests/data/vdb/smoke_plume.vdb"
    )]
    Info {
        /// Scene file (.toml).
        scene: PathBuf,
    },
}

fn main() -> ExitCode {
    // Like other command-line tools, end quietly when stdout is closed (`ppb info | head`)
    // instead of failing a write.
    #[cfg(unix)]
    // SAFETY: restoring the default SIGPIPE action before any thread starts.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    let cli = Cli::parse();
    if !matches!(cli.command, Command::UsdProbe { .. }) {
        ppb::scene::usd::set_probe(app::probe_in_child);
    }
    // Only the commands that may probe for a GPU need it.
    #[cfg(unix)]
    if matches!(
        cli.command,
        Command::Render(_) | Command::Watch(_) | Command::BenchGpu(_)
    ) {
        private_runtime_dir();
    }
    // A wrong PPB_SIMD is bad input, told before any work, not a silent fallback.
    if let Err(e) = ppb::core::simd::Isa::from_env() {
        eprintln!("error: {e}");
        return ExitCode::from(2);
    }
    let result = match cli.command {
        Command::Render(args) => app::render(args),
        Command::Watch(args) => app::watch(args),
        Command::Compare(args) => app::compare(args),
        Command::Bench(args) => app::bench(args),
        Command::Build(args) => app::build(args),
        Command::BenchTr(args) => app::bench_tr(args),
        Command::BenchSize(args) => app::bench_size(args),
        Command::BenchGpu(args) => app::bench_gpu(args),
        Command::Plan(args) => app::plan(args),
        Command::Merge(args) => app::merge(args),
        Command::Farm(args) => app::farm(args),
        Command::Info { scene } => app::info(&scene),
        Command::UsdProbe { path, frame } => app::usd_probe(&path, frame),
    };
    match result {
        Ok(code) => code,
        // 1: the render failed; 2: bad input or usage (as clap's usage errors).
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::from(if e.is::<app::Failed>() { 1 } else { 2 })
        }
    }
}

/// Mesa's Vulkan drivers print "error: XDG_RUNTIME_DIR is invalid or not set" whenever
/// wgpu probes adapters without that folder (ssh sessions, containers, CI), which
/// `--device auto` does on every render and watch. Without a usable one, point it at a
/// private folder of ours (0700, owned by this user) before any thread starts (clap's
/// parsing starts none).
#[cfg(unix)]
fn private_runtime_dir() {
    use std::os::unix::fs::{DirBuilderExt, MetadataExt};
    let usable = std::env::var_os("XDG_RUNTIME_DIR").is_some_and(|d| Path::new(&d).is_dir());
    if usable {
        return;
    }
    // SAFETY: getuid has no preconditions.
    let uid = unsafe { libc::getuid() };
    let dir = std::env::temp_dir().join(format!("ppb-runtime-{uid}"));
    let _ = std::fs::DirBuilder::new().mode(0o700).create(&dir);
    let ours = std::fs::symlink_metadata(&dir)
        .is_ok_and(|m| m.is_dir() && m.uid() == uid && m.mode() & 0o077 == 0);
    if ours {
        // Sound: no other thread exists yet.
        std::env::set_var("XDG_RUNTIME_DIR", &dir);
    }
}
