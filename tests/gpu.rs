//! The GPU beam estimate against the CPU's: the same traced pass (beams, camera segments,
//! transmittance estimates) must give the same per-pixel beam radiance on both devices
//! within float32 rounding. On a machine without an adapter these tests print why they
//! skip, unless PPB_REQUIRE_GPU=1 (CI, which installs lavapipe) makes that a failure.
mod common;

use common::gpu_or_skip;
use std::path::Path;
use std::process::Command;

use ppb::compare::DeviceDiff;
use ppb::gpu::beams::GpuBeams;
use ppb::pass::Tracer;
use ppb::scene::toml::load;
use ppb::transport::transmittance::TrMode;

fn data(p: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(p)
}

struct Parity {
    diff: DeviceDiff,
    evaluations: u64,
    secondary: usize,
}

fn parity(scene: &str, size: u32, beams: usize, tr: TrMode, passes: &[u32]) -> Option<Parity> {
    let g = gpu_or_skip(scene)?;
    let file = load(&data(scene)).expect("scene loads");
    let mut s = file.settings.clone();
    (s.width, s.height, s.light_paths, s.tr_mode) = (size, size, beams, tr);
    let r = Tracer::new(&file.scene, s).expect("renderer");
    let mut est = GpuBeams::new(g, r.media(), r.camera().origin(), size * size).expect("gpu");
    let mut out = Parity {
        diff: DeviceDiff::default(),
        evaluations: 0,
        secondary: 0,
    };
    for &i in passes {
        let t = r.trace(&r.plan().pass(i), None, true);
        let (cpu, evals) = r.beam_image(&t);
        est.clear().expect("clear");
        est.submit(&t, r.media()).expect("submit");
        out.diff.add(&cpu, &est.read().expect("read back").0);
        out.evaluations += evals;
        out.secondary += t.camera.secondary.len();
    }
    let d = &out.diff;
    eprintln!(
        "{scene}: rel_l1 {:.2e}, {} of {} lit pixels off by > 1e-3, {} evaluations, {} secondary segments",
        d.rel_l1(), d.off_pixels, d.lit_pixels, out.evaluations, out.secondary
    );
    Some(out)
}

/// Heterogeneous media: grid lookups, ratio-tracking steps and the splat vs BVH query.
#[test]
fn gpu_matches_cpu_on_smoke_grid() {
    let scene = "scenes/conformance/smoke-grid/scene.toml";
    for tr in [TrMode::Ratio, TrMode::Random] {
        let Some(p) = parity(scene, 96, 20_000, tr, &[1, 7]) else {
            return;
        };
        assert!(p.evaluations > 100_000 && p.diff.lit_pixels > 3000);
        assert!(
            p.diff.off_pixels * 1000 <= p.diff.lit_pixels,
            "{tr:?}: {} pixels off",
            p.diff.off_pixels
        );
        assert!(p.diff.rel_l1() < 1e-5, "{tr:?}: rel_l1 {}", p.diff.rel_l1());
    }
}

/// Glass: camera segments after refraction and reflection, weighted by Fresnel.
#[test]
fn gpu_matches_cpu_on_glass_caustic() {
    let scene = "scenes/conformance/glass-caustic/scene.toml";
    let Some(p) = parity(scene, 96, 20_000, TrMode::Ratio, &[1, 3]) else {
        return;
    };
    assert!(p.secondary > 1000 && p.evaluations > 500_000);
    assert!(
        p.diff.off_pixels * 1000 <= p.diff.lit_pixels,
        "{} pixels off",
        p.diff.off_pixels
    );
    assert!(p.diff.rel_l1() < 1e-5, "rel_l1 {}", p.diff.rel_l1());
}

/// The command line: `--device gpu` renders, says which adapter, and the stats file
/// records the GPU time and its overlap with tracing; a backend that does not exist here
/// gives one clear error line, not a panic.
#[test]
fn render_on_gpu_from_the_command_line() {
    if gpu_or_skip("render_on_gpu_from_the_command_line").is_none() {
        return;
    }
    let dir = common::temp_dir("gpu", "cli");
    let out = dir.join("smoke.exr");
    let stats = dir.join("stats.json");
    let run = Command::new(env!("CARGO_BIN_EXE_ppb"))
        .args([
            "render", "--device", "gpu", "--size", "32x32", "--passes", "6",
        ])
        .args(["--light-paths", "2000", "--quiet", "--cache-dir"])
        .arg(dir.join("cache"))
        .arg("-o")
        .arg(&out)
        .arg("--stats")
        .arg(&stats)
        .arg(data("scenes/conformance/smoke-grid/scene.toml"))
        .output()
        .unwrap();
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&stats).unwrap()).unwrap();
    let g = &json["gpu"];
    assert_eq!(g["passes"], 6, "{json}");
    assert!(g["estimate_seconds"].as_f64().unwrap() > 0.0);
    assert!(g["overlap_seconds"].as_f64().is_some());
    assert!(json["device"].as_str().unwrap() != "cpu");
    let img = ppb::output::read_exr(&out).unwrap();
    assert!(img.pixels.iter().any(|p| p[0] > 0.0));

    let none = Command::new(env!("CARGO_BIN_EXE_ppb"))
        .env(
            "WGPU_BACKEND",
            if cfg!(target_os = "macos") {
                "dx12"
            } else {
                "metal"
            },
        )
        .args([
            "render", "--device", "gpu", "--size", "8x8", "--passes", "1", "--quiet",
        ])
        .arg("-o")
        .arg(dir.join("none.exr"))
        .arg(data("scenes/conformance/fog-box/scene.toml"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&none.stderr);
    assert_eq!(none.status.code(), Some(2), "{err}");
    assert!(
        err.contains("no GPU adapter") && err.lines().count() == 1,
        "{err}"
    );
    assert!(!dir.join("none.exr").exists());
    let _ = std::fs::remove_dir_all(&dir);
}
