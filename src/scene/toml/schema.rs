//! The scene file's schema as serde reads it: every table and key, unknown keys refused.
//! The checks and the assembly into a [`Scene`](crate::scene::Scene) are the parent's.
use serde::Deserialize;
use std::path::PathBuf;

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub(super) struct FileScene {
    #[serde(default)]
    pub(super) render: FileRender,
    pub(super) camera: Option<FileCamera>,
    #[serde(default)]
    pub(super) material: Vec<FileMaterial>,
    #[serde(default)]
    pub(super) mesh: Vec<FileMesh>,
    #[serde(default)]
    pub(super) import: Vec<FileImport>,
    #[serde(default)]
    pub(super) light: Vec<FileLight>,
    #[serde(default)]
    pub(super) medium: Vec<FileMedium>,
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub(super) struct FileRender {
    pub(super) width: Option<u32>,
    pub(super) height: Option<u32>,
    pub(super) passes: Option<u32>,
    pub(super) light_paths: Option<usize>,
    /// The old name of `light_paths` (it counts light paths, not beams).
    pub(super) beams_per_pass: Option<usize>,
    pub(super) alpha: Option<f32>,
    pub(super) photon_alpha: Option<f32>,
    pub(super) beam_radius: Option<FileRadius>,
    pub(super) photon_radius: Option<FileRadius>,
    pub(super) smooth_photon_radius: Option<FileRadius>,
    pub(super) seed: Option<u64>,
    pub(super) exposure: Option<f32>,
    pub(super) tr_samples: Option<usize>,
    pub(super) transmittance: Option<String>,
    pub(super) tr_block: Option<usize>,
    pub(super) free_path: Option<String>,
    pub(super) method: Option<String>,
    pub(super) nee_samples: Option<usize>,
    pub(super) transparent: Option<bool>,
    pub(super) bandwidth: Option<String>,
    pub(super) beam_kernel: Option<String>,
}

#[derive(Deserialize)]
#[serde(untagged)]
pub(super) enum FileRadius {
    Value(f32),
    Word(String),
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct FileCamera {
    pub(super) origin: [f32; 3],
    pub(super) target: [f32; 3],
    pub(super) up: Option<[f32; 3]>,
    pub(super) vfov: f32,
}

#[derive(Deserialize)]
#[serde(tag = "type", rename_all = "lowercase", deny_unknown_fields)]
pub(super) enum FileMaterial {
    Lambert {
        name: String,
        reflectance: [f32; 3],
    },
    Dielectric {
        name: String,
        ior: Option<f32>,
    },
    Mirror {
        name: String,
        reflectance: Option<[f32; 3]>,
    },
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct FileMesh {
    pub(super) path: PathBuf,
    pub(super) material: Option<String>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct FileImport {
    pub(super) path: PathBuf,
}

#[derive(Deserialize)]
#[serde(tag = "type", rename_all = "lowercase", deny_unknown_fields)]
pub(super) enum FileLight {
    Point {
        position: [f32; 3],
        intensity: [f32; 3],
    },
    Spot {
        position: [f32; 3],
        direction: [f32; 3],
        intensity: [f32; 3],
        inner_deg: Option<f32>,
        outer_deg: Option<f32>,
    },
    Environment {
        /// The constant sky's radiance, or the map's multiplier (default 1).
        radiance: Option<[f32; 3]>,
        /// A lat-long map (.exr, .hdr), relative to the scene file.
        map: Option<String>,
        /// Degrees about +Y.
        rotation: Option<f32>,
    },
    /// The Preetham sky with its sun, baked into a map.
    Sky {
        sun_elevation: f32,
        sun_azimuth: Option<f32>,
        turbidity: Option<f32>,
        /// The sun's angular radius, degrees.
        sun_size: Option<f32>,
        radiance: Option<[f32; 3]>,
        /// Map width in texels (height half of it).
        resolution: Option<u32>,
        /// Radiance below the horizon (before `radiance`; the model's ground is black).
        ground: Option<[f32; 3]>,
    },
    Directional {
        direction: [f32; 3],
        irradiance: [f32; 3],
    },
    Sphere {
        center: [f32; 3],
        radius: f32,
        radiance: [f32; 3],
    },
}

#[derive(Deserialize)]
#[serde(tag = "type", rename_all = "lowercase", deny_unknown_fields)]
pub(super) enum FileMedium {
    Homogeneous {
        bounds: [[f32; 3]; 2],
        sigma_t: f32,
        albedo: [f32; 3],
        phase: Option<FilePhase>,
    },
    Grid {
        path: PathBuf,
        grid: Option<String>,
        density_scale: f32,
        albedo: [f32; 3],
        phase: Option<FilePhase>,
        transform: Option<FileTransform>,
    },
    Noise {
        preset: String,
        bounds: [[f32; 3]; 2],
        seed: Option<u32>,
        octaves: Option<usize>,
        frequency: Option<f64>,
        resolution: Option<u32>,
        density_scale: f32,
        albedo: [f32; 3],
        phase: Option<FilePhase>,
    },
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub(super) struct FileTransform {
    pub(super) translate: Option<[f64; 3]>,
    pub(super) rotate_deg: Option<[f64; 3]>,
    pub(super) scale: Option<f64>,
}

#[derive(Deserialize)]
#[serde(tag = "type", rename_all = "lowercase", deny_unknown_fields)]
pub(super) enum FilePhase {
    Isotropic,
    Hg { g: f32 },
}
