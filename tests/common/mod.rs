//! Helpers shared by the integration tests (each test crate uses some of them).
#![allow(dead_code)]
use std::path::{Path, PathBuf};

use ppb::gpu::{self, DeviceKind, Gpu};

/// A fresh empty folder under the system temp folder, unique to this process.
pub fn temp_dir(prefix: &str, name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("ppb-{prefix}-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// A 6 m square floor at y = 0, as OBJ.
pub const FLOOR: &str =
    "v -3 0 -3\nv 3 0 -3\nv 3 0 3\nv -3 0 3\nvn 0 1 0\nf 1//1 4//1 3//1\nf 1//1 3//1 2//1\n";

/// Writes [`FLOOR`] as `dir/floor.obj`.
pub fn write_floor(dir: &Path) {
    std::fs::write(dir.join("floor.obj"), FLOOR).unwrap();
}

/// A scene over `floor.obj`: `[render]` with the lines `render`, the test camera, a Lambert
/// floor of grey `reflectance`, then `rest` (lights, media).
pub fn floor_scene(render: &str, reflectance: f32, rest: &str) -> String {
    let r = reflectance;
    format!(
        r#"[render]
{render}

[camera]
origin = [0, 1.5, 5]
target = [0, 0.8, 0]
vfov = 40

[[material]]
name = "floor"
type = "lambert"
reflectance = [{r}, {r}, {r}]

[[mesh]]
path = "floor.obj"
material = "floor"

{rest}"#
    )
}

/// An adapter (software ones included), or None after printing why the test skips;
/// PPB_REQUIRE_GPU=1 (CI, which installs lavapipe) makes a missing adapter a failure.
pub fn gpu_or_skip(test: &str) -> Option<Gpu> {
    match gpu::open(DeviceKind::Gpu) {
        Ok(g) => g,
        Err(e) if std::env::var("PPB_REQUIRE_GPU").as_deref() == Ok("1") => {
            panic!("{test}: PPB_REQUIRE_GPU=1 but {e}")
        }
        Err(e) => {
            eprintln!("{test}: skipped: {e}");
            None
        }
    }
}

/// The CPU splat of pass `t`'s primary segments under `kernel`, over `beams` (the pass's
/// own, or others), with this machine's lanes: per-pixel sums and evaluations.
pub fn splat_pass(
    r: &ppb::pass::Tracer,
    t: &ppb::estimate::TracedPass,
    beams: &[ppb::transport::Beam],
    kernel: ppb::estimate::eq2::BeamKernel,
) -> (Vec<ppb::core::Nested>, u64) {
    ppb::estimate::splat::splat(
        r.camera(),
        &t.camera.primaries,
        beams,
        (t.beam_radius, kernel),
        r.media(),
        ppb::core::simd::isa(),
    )
}
