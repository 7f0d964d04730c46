//! Helpers shared by the integration tests.
use ppb::gpu::{self, DeviceKind, Gpu};

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
