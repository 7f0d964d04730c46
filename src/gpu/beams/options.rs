//! How a [`super::GpuBeams`] estimates: primary segments rasterised or gathered, the
//! camera transmittance uploaded or tracked, and what the render settings fix.
use crate::error::{Error, Result};
use crate::gpu::Gpu;
use crate::majorant::Mode;
use crate::settings::RenderSettings;

/// How the GPU estimates primary camera segments (`--gpu-primary`). Both give the CPU's
/// sums; which is faster depends on the GPU and the scene (`ppb bench-gpu` times both).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum PrimaryPath {
    /// Measured: the first pass rasterised, the second gathered, then whichever took less
    /// GPU time per beam; gather where the adapter cannot blend float32 targets of the
    /// image's size.
    Auto,
    /// Beams drawn as film quads, one fragment per candidate pixel.
    Raster,
    /// A beam BVH query per primary segment, as for segments after specular bounces.
    Gather,
}

impl PrimaryPath {
    /// What `self` means on `gpu` for a `width` x `height` image (auto stays auto where
    /// raster is possible); an error when raster is asked for and the adapter cannot do it.
    pub fn resolve(self, gpu: &Gpu, width: u32, height: u32) -> Result<PrimaryPath> {
        let why_not = if !gpu
            .device
            .features()
            .contains(wgpu::Features::FLOAT32_BLENDABLE)
        {
            Some("cannot blend into float32 targets".to_string())
        } else if width.max(height) > gpu.limits.max_texture_dimension_2d {
            Some(format!(
                "has no {width}x{height} targets (largest side {})",
                gpu.limits.max_texture_dimension_2d
            ))
        } else {
            None
        };
        match (self, why_not) {
            (PrimaryPath::Raster, Some(why)) => Err(Error::Gpu(format!(
                "{} {why}: --gpu-primary raster is not possible (use gather)",
                gpu.describe()
            ))),
            (PrimaryPath::Auto, Some(_)) | (PrimaryPath::Gather, _) => Ok(PrimaryPath::Gather),
            (p, None) => Ok(p),
        }
    }
}

/// Where the GPU's camera transmittance comes from (`--gpu-tr`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum CameraTr {
    /// The CPU's estimate of each segment (`--tr`), uploaded as steps every pass: the
    /// GPU's image equals the CPU's.
    Steps,
    /// Ratio tracking on the GPU along each segment (`shaders/freepath.wgsl`), whatever
    /// `--tr` says: no steps are uploaded, and the image is another draw of the same
    /// estimate.
    Track,
}

/// How a [`GpuBeams`] estimates: primary segments, camera transmittance, and the render's
/// seed and free-path sampler (for tracking on the GPU).
#[derive(Clone, Copy, Debug)]
pub struct GpuOptions {
    pub primary: PrimaryPath,
    pub camera_tr: CameraTr,
    pub seed: u64,
    pub free_path: Mode,
    /// BVH walk iterations per segment per dispatch round; None: unbounded on hardware,
    /// [`SOFTWARE_WALK_BUDGET`] on software adapters.
    pub walk_budget: Option<u32>,
}

impl GpuOptions {
    /// The options for a render with `settings`.
    pub fn new(primary: PrimaryPath, camera_tr: CameraTr, settings: &RenderSettings) -> Self {
        GpuOptions {
            primary,
            camera_tr,
            seed: settings.seed,
            free_path: settings.free_path,
            walk_budget: None,
        }
    }
}
