//! The wide loops end to end: every instruction set this CPU runs renders the scalar
//! path's image bit for bit (`PPB_SIMD`), `--stats` names the set that ran, and a wrong
//! `PPB_SIMD` is bad input.
mod common;

use ppb::core::simd::Isa;
use std::path::{Path, PathBuf};
use std::process::Command;

fn ppb() -> Command {
    Command::new(env!("CARGO_BIN_EXE_ppb"))
}

fn scene(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("scenes/conformance/{name}/scene.toml"))
}

/// Renders `scene` small with `PPB_SIMD=isa`; returns the pixels' bits and `--stats`'s
/// "simd" and "beam_kernel".
fn render(dir: &Path, scene: &Path, isa: Isa) -> (Vec<u32>, String, String) {
    let (exr, stats) = (
        dir.join(format!("{}.exr", isa.name())),
        dir.join("stats.json"),
    );
    let out = ppb()
        .env("PPB_SIMD", isa.name())
        .args(["render", "-q", "--device", "cpu", "--size", "64x48"])
        .args(["--light-paths", "3000", "--passes", "3", "--stats"])
        .arg(&stats)
        .arg("-o")
        .arg(&exr)
        .arg(scene)
        .output()
        .expect("run ppb");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let image = ppb::output::read_exr(&exr).expect("read the render");
    let bits = image.pixels.iter().flatten().map(|v| v.to_bits()).collect();
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&stats).unwrap()).unwrap();
    let text = |k: &str| json[k].as_str().unwrap_or("").to_string();
    (bits, text("simd"), text("beam_kernel"))
}

/// A homogeneous box, a density grid, a cloud and glass: the splat's lanes on each (the
/// tube kernel's on cloud-hg, whose HG g = 0.7 asks for it; eq. 2's on the isotropic rest).
#[test]
fn every_isa_renders_the_scalar_image() {
    let dir = common::temp_dir("simd", "images");
    let mut wide = 0;
    for name in ["fog-box", "smoke-grid", "cloud-hg", "glass-caustic"] {
        let (reference, ran, kernel) = render(&dir, &scene(name), Isa::Scalar);
        assert_eq!(ran, "scalar");
        let want = if name == "cloud-hg" { "tube" } else { "line" };
        assert_eq!(kernel, want, "{name}");
        assert!(
            reference.iter().any(|&b| f32::from_bits(b) > 0.0),
            "{name}: black"
        );
        for isa in Isa::ALL
            .into_iter()
            .filter(|&i| i != Isa::Scalar && i.supported())
        {
            let (bits, ran, _) = render(&dir, &scene(name), isa);
            assert_eq!(ran, isa.name(), "{name}");
            let differ = bits.iter().zip(&reference).filter(|(a, b)| a != b).count();
            assert_eq!(differ, 0, "{name}: {differ} channels differ with {isa:?}");
            wide += 1;
        }
    }
    eprintln!("{wide} wide renders matched the scalar ones");
}

#[test]
fn a_wrong_ppb_simd_is_bad_input() {
    let out = ppb()
        .env("PPB_SIMD", "neon")
        .args(["render", "-q"])
        .arg(scene("fog-box"))
        .output()
        .expect("run ppb");
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("PPB_SIMD=neon") && err.contains("scalar, avx2, avx512"),
        "{err}"
    );
}
