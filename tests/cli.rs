//! The `ppb` binary end to end: a tiny render with its outputs and stats, `compare`'s exit
//! codes, and bad input, which must give one line naming the file and field, exit code 2
//! and no panic.
mod common;

use common::{floor_scene, write_floor};
use std::path::{Path, PathBuf};
use std::process::Command;

fn ppb() -> Command {
    Command::new(env!("CARGO_BIN_EXE_ppb"))
}

/// A small valid scene; `extra` is appended to it.
fn scene(dir: &Path, extra: &str) -> PathBuf {
    write_floor(dir);
    let render = "width = 24\nheight = 16\npasses = 2\nlight_paths = 2000";
    let rest = format!(
        r#"[[light]]
type = "point"
position = [0, 2.6, 0]
intensity = [20, 20, 20]

[[medium]]
type = "homogeneous"
bounds = [[-1, 0.25, -1], [1, 1.75, 1]]
sigma_t = 1.0
albedo = [0.8, 0.8, 0.8]
{extra}"#
    );
    let p = dir.join("scene.toml");
    std::fs::write(&p, floor_scene(render, 0.5, &rest)).unwrap();
    p
}

/// Runs `ppb render` on `scene` and returns (exit code, stderr).
fn render(scene: &Path, out: &Path) -> (i32, String) {
    let o = ppb()
        .args(["render", "-q", "-o"])
        .arg(out)
        .arg(scene)
        .output()
        .unwrap();
    (
        o.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&o.stderr).into(),
    )
}

fn assert_bad(name: &str, edit: impl Fn(&Path, &Path) -> PathBuf, expect: &[&str]) {
    let dir = common::temp_dir("cli", name);
    let good = scene(&dir, "");
    let bad = edit(&dir, &good);
    let (code, err) = render(&bad, &dir.join("out.exr"));
    assert_eq!(code, 2, "{name}: exit code {code}, stderr: {err}");
    assert!(!err.contains("panicked"), "{name}: panic: {err}");
    assert_eq!(err.trim().lines().count(), 1, "{name}: not one line: {err}");
    for e in expect {
        assert!(err.contains(e), "{name}: '{e}' missing from: {err}");
    }
    assert!(!dir.join("out.exr").exists(), "{name}: wrote an output");
}

fn rewrite(path: &Path, from: &str, to: &str) -> PathBuf {
    let text = std::fs::read_to_string(path).unwrap();
    assert!(text.contains(from), "{from}");
    std::fs::write(path, text.replace(from, to)).unwrap();
    path.to_path_buf()
}

#[test]
fn renders_with_outputs_and_stats() {
    let dir = common::temp_dir("cli", "ok");
    let s = scene(&dir, "");
    let out = dir.join("img.exr");
    let stats = dir.join("stats.json");
    let o = ppb()
        .args(["render", "-q", "--stats"])
        .arg(&stats)
        .arg("-o")
        .arg(&out)
        .arg(&s)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let img = ppb::output::read_exr(&out).unwrap();
    assert_eq!((img.width, img.height), (24, 16));
    assert!(img.pixels.iter().any(|p| p[0] > 0.0));
    assert!(dir.join("img.png").exists());
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&stats).unwrap()).unwrap();
    assert_eq!(json["passes"], 2);
    assert_eq!(json["counters"]["light_paths"], 4000);
    for k in [
        "light_tracing",
        "free_path_sampling",
        "camera_transmittance",
        "estimate",
        "other",
    ] {
        assert!(json["seconds"][k].is_number(), "{k}");
    }
    // compare: identical images pass any threshold; a scaled image fails a tight one.
    let same = ppb()
        .args(["compare", "--max-rel-l1", "0"])
        .arg(&out)
        .arg(&out)
        .output()
        .unwrap();
    assert_eq!(same.status.code(), Some(0));
    let mut brighter = img.clone();
    for p in &mut brighter.pixels {
        p[0] *= 1.5;
    }
    let b = dir.join("brighter.exr");
    ppb::output::write_exr(&b, &brighter, &Default::default()).unwrap();
    let diff = ppb()
        .args(["compare", "--max-rel-l1", "0.01"])
        .arg(&b)
        .arg(&out)
        .output()
        .unwrap();
    assert_eq!(diff.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&diff.stdout).contains("rel_l1"));
}

#[test]
fn bad_input_is_one_clear_line() {
    assert_bad("missing", |d, _| d.join("nope.toml"), &["nope.toml"]);
    assert_bad(
        "syntax",
        |_, s| rewrite(s, "sigma_t = 1.0", "sigma_t = = 1.0"),
        &["scene.toml", "line 29"],
    );
    assert_bad(
        "unknown-key",
        |_, s| rewrite(s, "sigma_t = 1.0", "sigma_t = 1.0\ndensity = 3"),
        &["scene.toml", "unknown field `density`"],
    );
    assert_bad(
        "unknown-material",
        |_, s| rewrite(s, "material = \"floor\"", "material = \"marble\""),
        &["scene.toml", "mesh[0].material", "marble"],
    );
    assert_bad(
        "nan",
        |_, s| rewrite(s, "sigma_t = 1.0", "sigma_t = nan"),
        &["scene.toml", "medium[0].sigma_t"],
    );
    assert_bad(
        "negative",
        |_, s| rewrite(s, "sigma_t = 1.0", "sigma_t = -1.0"),
        &["medium[0].sigma_t"],
    );
    assert_bad(
        "albedo",
        |_, s| rewrite(s, "albedo = [0.8, 0.8, 0.8]", "albedo = [0.8, 1.8, 0.8]"),
        &["medium[0].albedo"],
    );
    assert_bad(
        "missing-mesh",
        |_, s| rewrite(s, "path = \"floor.obj\"", "path = \"gone.obj\""),
        &["gone.obj"],
    );
    assert_bad(
        "empty-mesh",
        |d, s| {
            std::fs::write(d.join("empty.obj"), "v 0 0 0\nv 1 0 0\n").unwrap();
            rewrite(s, "path = \"floor.obj\"", "path = \"empty.obj\"")
        },
        &["empty.obj", "no triangles"],
    );
    assert_bad(
        "gltf-extension",
        |d, s| {
            let gltf = r#"{"asset":{"version":"2.0"},"extensionsUsed":["KHR_draco_mesh_compression"],
                "extensionsRequired":["KHR_draco_mesh_compression"],"scenes":[{"nodes":[]}],"scene":0}"#;
            std::fs::write(d.join("draco.gltf"), gltf).unwrap();
            rewrite(s, "path = \"floor.obj\"", "path = \"draco.gltf\"")
        },
        &[
            "draco.gltf",
            "extensionsRequired",
            "KHR_draco_mesh_compression",
        ],
    );
    assert_bad(
        "bad-light-type",
        |_, s| rewrite(s, "type = \"point\"", "type = \"laser\""),
        &["scene.toml", "laser"],
    );
    assert_bad(
        "bad-method",
        |_, s| rewrite(s, "passes = 2", "passes = 2\nmethod = \"pt\""),
        &["render.method", "expected hybrid or ppb", "\"pt\""],
    );
    assert_bad(
        "bad-beam-kernel",
        |_, s| rewrite(s, "passes = 2", "passes = 2\nbeam_kernel = \"wide\""),
        &[
            "render.beam_kernel",
            "expected auto, line or tube",
            "\"wide\"",
        ],
    );
    assert_bad(
        "bad-photon-alpha",
        |_, s| rewrite(s, "passes = 2", "passes = 2\nphoton_alpha = 1.5"),
        &["render.photon_alpha", "(0, 1)"],
    );
    assert_bad(
        "bad-smooth-radius",
        |_, s| rewrite(s, "passes = 2", "passes = 2\nsmooth_photon_radius = -1"),
        &["render.smooth_photon_radius"],
    );
}

#[test]
fn failed_render_keeps_earlier_output() {
    let dir = common::temp_dir("cli", "keep");
    let s = scene(&dir, "");
    let out = dir.join("img.exr");
    assert_eq!(render(&s, &out).0, 0);
    let before = std::fs::read(&out).unwrap();
    rewrite(&s, "sigma_t = 1.0", "sigma_t = -2.0");
    assert_eq!(render(&s, &out).0, 2);
    assert_eq!(std::fs::read(&out).unwrap(), before);
}

const NOISE: &str = r#"
[[medium]]
type = "noise"
preset = "smoke"
bounds = [[-1, 0, -1], [1, 2, 1]]
seed = 3
resolution = 24
density_scale = 6.0
albedo = [0.9, 0.9, 0.9]
"#;

fn ppb_in(args: &[&str], scene: &Path) -> (i32, String, String) {
    let o = ppb().args(args).arg(scene).output().unwrap();
    (
        o.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&o.stdout).into(),
        String::from_utf8_lossy(&o.stderr).into(),
    )
}

/// `ppb build` bakes, `--check` reports fresh/stale per medium, a parameter change makes
/// the cache stale, and a corrupt or truncated cache file is detected and rebuilt.
#[test]
fn octree_cache_lifecycle() {
    let dir = common::temp_dir("cli", "cache");
    let s = scene(&dir, NOISE);
    let (code, out, _) = ppb_in(&["build", "--check"], &s);
    assert_eq!(code, 1, "{out}");
    assert!(out.contains("stale"));
    let (code, _, err) = ppb_in(&["build"], &s);
    assert_eq!(code, 0, "{err}");
    assert!(err.contains("built"), "{err}");
    let (code, out, _) = ppb_in(&["build", "--check"], &s);
    assert_eq!(code, 0, "{out}");
    assert!(out.contains("fresh"));
    let out_exr = dir.join("img.exr");
    let o = ppb()
        .args(["render", "-o"])
        .arg(&out_exr)
        .arg(&s)
        .output()
        .unwrap();
    assert!(String::from_utf8_lossy(&o.stderr).contains("loaded from cache"));

    let cache = dir.join(".ppb-cache");
    let file = std::fs::read_dir(&cache)
        .unwrap()
        .next()
        .unwrap()
        .unwrap()
        .path();
    let bytes = std::fs::read(&file).unwrap();
    for (what, damaged) in [
        ("truncated", bytes[..bytes.len() / 2].to_vec()),
        ("bit flip", {
            let mut b = bytes.clone();
            let i = b.len() - 7;
            b[i] ^= 0x10;
            b
        }),
        ("bad magic", {
            let mut b = bytes.clone();
            b[0] = b'X';
            b
        }),
    ] {
        std::fs::write(&file, &damaged).unwrap();
        let (code, out, _) = ppb_in(&["build", "--check"], &s);
        assert_eq!(code, 1, "{what}: {out}");
        let o = ppb()
            .args(["render", "-o"])
            .arg(&out_exr)
            .arg(&s)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(
            o.status.success() && err.contains("cache invalid"),
            "{what}: {err}"
        );
        assert_eq!(
            std::fs::read(&file).unwrap(),
            bytes,
            "{what}: not rebuilt identically"
        );
    }

    rewrite(&s, "density_scale = 6.0", "density_scale = 7.0");
    let (code, out, _) = ppb_in(&["build", "--check"], &s);
    assert_eq!(code, 1, "{out}");
}

/// `ppb bench --repeat 2` on a tiny render of smoke-grid: one row per scene, both samplers'
/// counters, and the repeat count in the legend.
#[test]
fn bench_table_with_repeats() {
    let scene =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/conformance/smoke-grid/scene.toml");
    let o = ppb()
        .args([
            "bench",
            "--passes",
            "1",
            "--size",
            "16x16",
            "--light-paths",
            "2000",
            "--repeat",
            "2",
        ])
        .arg(&scene)
        .output()
        .unwrap();
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "{out}\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(out.contains("median of 2 runs"), "{out}");
    let row = out
        .lines()
        .find(|l| l.starts_with("smoke-grid"))
        .expect("a row for the scene");
    let cols: Vec<&str> = row.split_whitespace().collect();
    // lookups per free path: Woodcock's above adaptive's.
    let (w, a): (f64, f64) = (cols[8].parse().unwrap(), cols[9].parse().unwrap());
    assert!(w > a && a > 0.0, "{row}");
    let bad = ppb()
        .args(["bench", "--repeat", "0"])
        .arg(&scene)
        .output()
        .unwrap();
    assert_eq!(bad.status.code(), Some(2));
}

/// Probing for a GPU (`--device auto` and `gpu`, on every render and watch) without
/// XDG_RUNTIME_DIR set, as in ssh sessions, containers and CI: Mesa's Vulkan drivers
/// would print "error: XDG_RUNTIME_DIR is invalid"; ppb points it at a private folder, so
/// stderr holds only ppb's own lines.
#[test]
fn no_runtime_dir_noise_when_probing_the_gpu() {
    let dir = common::temp_dir("cli", "runtime-dir");
    let scene = scene(&dir, "");
    for device in ["auto", "gpu"] {
        let o = ppb()
            .env_remove("XDG_RUNTIME_DIR")
            .args(["render", "--device", device, "--passes", "1", "-o"])
            .arg(dir.join("a.exr"))
            .arg(&scene)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!err.contains("XDG_RUNTIME_DIR"), "--device {device}: {err}");
        if o.status.success() {
            assert!(
                err.lines().any(|l| l.starts_with("beam estimate on the")),
                "{err}"
            );
        }
    }
    std::fs::remove_dir_all(&dir).ok();
}

/// A first run: `--version`, an example in every subcommand's help, and a mistyped scene
/// path answered with the nearest shipped scene.
#[test]
fn help_version_and_scene_suggestions() {
    let o = ppb().arg("--version").output().unwrap();
    assert_eq!(
        String::from_utf8_lossy(&o.stdout).trim(),
        format!("ppb {}", env!("CARGO_PKG_VERSION"))
    );
    for c in [
        "render",
        "watch",
        "compare",
        "build",
        "bench",
        "bench-tr",
        "bench-gpu",
        "info",
        "plan",
        "merge",
        "farm",
    ] {
        let o = ppb().args([c, "--help"]).output().unwrap();
        let help = String::from_utf8_lossy(&o.stdout);
        assert!(
            o.status.success() && help.contains("Example"),
            "{c}: {help}"
        );
    }
    let o = ppb()
        .args(["render", "scenes/conformance/fogbox/scene.toml"])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .unwrap();
    let e = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2));
    assert!(
        e.contains("did you mean scenes/conformance/fog-box/scene.toml?"),
        "{e}"
    );
}

/// An output with the frame token and no frames, or several frames into one output name,
/// is refused before any work: exit 2, one line naming the output, nothing written.
#[test]
fn output_frame_token_and_frames_must_agree() {
    let dir = common::temp_dir("cli", "token");
    let s = scene(&dir, "");
    for (args, out, want) in [
        (vec![], "shot.####.exr", "no --frames were given"),
        (vec!["--frames", "1-2"], "shot.exr", "no frame token"),
    ] {
        let out = dir.join(out);
        let o = ppb()
            .arg("render")
            .args(&args)
            .arg("-o")
            .arg(&out)
            .arg(&s)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {err}");
        assert!(
            err.contains(want) && err.contains("shot"),
            "{args:?}: {err}"
        );
        assert!(std::fs::read_dir(&dir)
            .unwrap()
            .all(|e| { !e.unwrap().file_name().to_string_lossy().starts_with("shot") }));
    }
}
