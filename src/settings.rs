//! Render settings: what the `[render]` table and the command line control.

/// A progressive radius: derived from the scene, or a fixed world-space R1 (m).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Radius {
    Auto,
    Fixed(f32),
}

#[derive(Clone, Debug, PartialEq)]
pub struct RenderSettings {
    pub width: u32,
    pub height: u32,
    /// Number of progressive passes (each: one light pass + one camera pass).
    pub passes: u32,
    /// Light paths traced per pass.
    pub light_paths: usize,
    /// Radius reduction parameter of eq. 3, in (0, 1), for the beams.
    pub alpha: f32,
    /// The same for the surface photons (their radius squared follows eq. 3).
    pub photon_alpha: f32,
    pub beam_radius: Radius,
    pub photon_radius: Radius,
    /// R1 of the photons after a diffuse or medium scattering (auto: the photon R1 times
    /// [`SMOOTH_PHOTON_SCALE`]).
    pub smooth_photon_radius: Radius,
    pub seed: u64,
    /// PNG preview exposure in stops.
    pub exposure: f32,
    /// Grid free paths per camera segment per pass (M of the deep-shadow estimate).
    pub tr_samples: usize,
    pub free_path: crate::transport::freepath::Mode,
    /// Camera-segment transmittance estimator through grids.
    pub tr_mode: crate::transport::transmittance::TrMode,
    /// Passes whose free paths the stratified estimator draws at once (N).
    pub tr_block: usize,
    /// Depth of the majorant octree pyramid (2^depth finest cells per axis).
    pub octree_depth: u32,
    pub method: Method,
    /// Light samples per camera segment in media (hybrid method's single scattering).
    pub nee_samples: usize,
}

/// How light reaches the camera.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Method {
    /// Direct light by next-event estimation (a shadow ray from each diffuse camera hit
    /// and from a point on each camera segment in media), beams and photons for the rest.
    Hybrid,
    /// The paper's pure method: all light through photon beams and photons.
    Ppb,
}

impl Default for RenderSettings {
    fn default() -> Self {
        RenderSettings {
            width: 256,
            height: 256,
            passes: 64,
            light_paths: 100_000,
            alpha: 0.9,
            photon_alpha: DEFAULT_PHOTON_ALPHA,
            beam_radius: Radius::Auto,
            photon_radius: Radius::Auto,
            smooth_photon_radius: Radius::Auto,
            seed: 1,
            exposure: 0.0,
            tr_samples: crate::transport::transmittance::DEFAULT_TR_SAMPLES,
            free_path: crate::transport::freepath::Mode::Adaptive,
            tr_mode: crate::transport::transmittance::TrMode::Ratio,
            tr_block: crate::transport::transmittance::DEFAULT_TR_BLOCK,
            octree_depth: crate::majorant::octree::DEFAULT_MAX_DEPTH,
            method: Method::Hybrid,
            nee_samples: crate::transport::direct::DEFAULT_NEE_SAMPLES,
        }
    }
}

/// Largest image side, pixel count and light paths per pass: a scene or flag asking for
/// more gets an error instead of an out-of-memory kill. A pixel holds about 200 bytes
/// across the film and the camera paths, a light path a few 48-byte beams and photons, so
/// both limits stay within a few GiB.
pub const MAX_SIDE: u32 = 16384;
pub const MAX_PIXELS: u64 = 1 << 26;
pub const MAX_LIGHT_PATHS: usize = 1 << 24;

impl RenderSettings {
    /// What is wrong with the image size or the light-path count, if anything: the
    /// setting's name and the message.
    pub fn limits_error(&self) -> Option<(&'static str, String)> {
        for (field, v) in [("width", self.width), ("height", self.height)] {
            if v == 0 || v > MAX_SIDE {
                return Some((field, format!("expected 1..={MAX_SIDE} pixels, got {v}")));
            }
        }
        let pixels = self.width as u64 * self.height as u64;
        if pixels > MAX_PIXELS {
            return Some((
                "width",
                format!(
                    "{}x{} is {pixels} pixels, more than the {MAX_PIXELS} ppb renders",
                    self.width, self.height
                ),
            ));
        }
        if self.light_paths == 0 || self.light_paths > MAX_LIGHT_PATHS {
            return Some((
                "light_paths",
                format!(
                    "expected 1..={MAX_LIGHT_PATHS} light paths per pass (more passes give more), got {}",
                    self.light_paths
                ),
            ));
        }
        None
    }
}

/// Default alpha of the surface photons (README: measured against the beams' 0.9).
pub const DEFAULT_PHOTON_ALPHA: f32 = 0.9;

/// Auto beam radius R1, in pixel footprints at the distance of the media's centre.
/// Measured at 60 s on the conformance scenes (README, "Radius schedules"): since the
/// beams carry only multiple scattering (4 NEE samples take the single), 2 against 1.5
/// cuts cloud-hg's error by 9 % and leaves fog-box and smoke-grid within their noise.
pub const AUTO_BEAM_PIXELS: f32 = 2.0;
/// Auto photon radius R1, in pixel footprints at the distance of the surfaces' centre.
pub const AUTO_PHOTON_PIXELS: f32 = 3.0;
/// R1 of the smooth photons (after a diffuse or medium scattering) over the photon radius
/// R1 (README: measured at equal time).
pub const SMOOTH_PHOTON_SCALE: f32 = 5.0;
