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
    /// Grid free paths per camera segment per pass (M of the deep-shadow and stratified
    /// estimates), or the ratio tracking's rate in multiples of the majorant.
    pub tr_samples: usize,
    pub free_path: crate::majorant::Mode,
    /// Camera-segment transmittance estimator through grids.
    pub tr_mode: TrMode,
    /// Passes whose free paths the stratified estimator draws at once (N).
    pub tr_block: usize,
    /// Depth of the majorant octree pyramid (2^depth finest cells per axis).
    pub octree_depth: u32,
    pub method: Method,
    /// Light samples per camera segment in media (hybrid method's single scattering).
    pub nee_samples: usize,
    /// Film transparency (Cycles' "transparent" film): camera rays that leave the scene
    /// see nothing of the environment, and the image gets an alpha channel, 1 - the
    /// transmittance of each camera ray that leaves (1 where it hits a surface).
    pub transparent: bool,
    /// The beams' kernel radius per pixel: eq. 3's everywhere, or chosen per pixel
    /// between it and its half (`film::error`).
    pub bandwidth: Bandwidth,
    /// The beams' kernel across their direction; None: with the hybrid method the tube
    /// where a phase function is anisotropic ([`RenderSettings::beam_kernel`]), else eq.
    /// 2's line.
    pub beam_kernel: Option<BeamKernel>,
}

pub use crate::film::error::Bandwidth;

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

/// How a beam is blurred across its direction (Jarosz et al. 2011's beam x beam
/// estimators; `estimate::eq2` and `estimate::tube`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum BeamKernel {
    /// The paper's eq. 2: a 1D box across both lines, each pair weighted by 1/sin(theta).
    Line,
    /// A 2D box across the beam, which the camera ray gathers over its chord through it:
    /// no 1/sin(theta), whose tail was a third of cloud-hg's per-pixel noise.
    Tube,
}

impl BeamKernel {
    /// How many times as high the kernel is at r/2 as at r (the nested estimate's ratio).
    pub fn inner_ratio(self) -> f32 {
        match self {
            BeamKernel::Line => 2.0,
            BeamKernel::Tube => 4.0,
        }
    }
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
            tr_samples: DEFAULT_TR_SAMPLES,
            free_path: crate::majorant::Mode::Adaptive,
            tr_mode: TrMode::March,
            tr_block: DEFAULT_TR_BLOCK,
            octree_depth: crate::majorant::DEFAULT_MAX_DEPTH,
            method: Method::Hybrid,
            nee_samples: DEFAULT_NEE_SAMPLES,
            transparent: false,
            bandwidth: Bandwidth::Fixed,
            beam_kernel: None,
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

/// A setting out of its range: its name in the `[render]` table and what was expected.
/// Each reader names the place it came from (`render.tr_block` in a scene, `--tr-block`
/// on the command line).
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("{field}: {msg}")]
pub struct Invalid {
    pub field: &'static str,
    pub msg: String,
}

impl RenderSettings {
    /// The kernel the beam estimate (CPU or GPU) uses in media whose phase functions' largest
    /// |g| is `anisotropy`: the one asked for, else the tube where a phase function peaks
    /// ([`TUBE_FROM_G`]), or the paper's line (always with its pure method, so that
    /// `--method ppb` reproduces its tables).
    pub fn beam_kernel(&self, anisotropy: f32) -> BeamKernel {
        self.beam_kernel.unwrap_or(match self.method {
            Method::Hybrid if anisotropy >= TUBE_FROM_G => BeamKernel::Tube,
            _ => BeamKernel::Line,
        })
    }

    /// The one check of every range: the scene reader, the command-line overrides and
    /// the tracer all ask it.
    pub fn validate(&self) -> Result<(), Invalid> {
        let bad = |field, msg| Err(Invalid { field, msg });
        if let Some((field, msg)) = self.limits_error() {
            return bad(field, msg);
        }
        if !(1..=MAX_TR_SAMPLES).contains(&self.tr_samples) {
            let msg = format!("expected 1..={MAX_TR_SAMPLES}, got {}", self.tr_samples);
            return bad("tr_samples", msg);
        }
        if self.tr_block == 0
            || self.tr_block > MAX_TR_BLOCK
            || !self.tr_block.is_multiple_of(self.tr_samples)
        {
            let msg = format!(
                "expected a multiple of tr_samples ({}) in 1..={MAX_TR_BLOCK}, got {}",
                self.tr_samples, self.tr_block
            );
            return bad("tr_block", msg);
        }
        if !(1..=MAX_NEE_SAMPLES).contains(&self.nee_samples) {
            let msg = format!("expected 1..={MAX_NEE_SAMPLES}, got {}", self.nee_samples);
            return bad("nee_samples", msg);
        }
        for (field, a) in [("alpha", self.alpha), ("photon_alpha", self.photon_alpha)] {
            if !(a > 0.0 && a < 1.0) {
                return bad(field, format!("expected a number in (0, 1), got {a}"));
            }
        }
        if !self.exposure.is_finite() {
            return bad("exposure", "expected a finite number".into());
        }
        Ok(())
    }

    /// The settings that change pixels (all but the pass count and the exposure), as one
    /// comparable string: what makes two part files one render, and what makes `ppb
    /// watch` restart its image.
    pub fn pixel_key(&self) -> String {
        let pixels = RenderSettings {
            passes: 0,
            exposure: 0.0,
            ..self.clone()
        };
        format!("{pixels:?}")
    }

    /// What is wrong with the image size or the light-path count, if anything: the
    /// setting's name and the message.
    fn limits_error(&self) -> Option<(&'static str, String)> {
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

/// The smallest |g| of a phase function from which the hybrid render (CPU or GPU) takes
/// the tube kernel. The line kernel's 1/sin(theta) tail is heaviest where the phase function's
/// peak (at theta = 0 or pi, beams along the camera ray) multiplies it. At equal passes
/// the tube took off the per-pixel / 4x4 noise: nothing with isotropic media (fog-box,
/// smoke-grid), 10 % / 4 % at g = 0.3, 22 % / 11 % at 0.5 and 34 % / 19 % at 0.7
/// (cloud-hg's cloud at each g), for about 15 % more time per pass: at 0.3 a small gain
/// per pixel and none on blocks, above it a gain on both.
pub const TUBE_FROM_G: f32 = 0.3;

/// Most free paths per camera segment (`--tr-samples`).
pub const MAX_TR_SAMPLES: usize = 16;
/// Default free paths per camera segment per pass (M in the paper).
pub const DEFAULT_TR_SAMPLES: usize = 4;
/// Default and largest stratified block (N passes' free paths drawn at once).
pub const DEFAULT_TR_BLOCK: usize = 64;
pub const MAX_TR_BLOCK: usize = 64;

#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum TrMode {
    /// M free paths per pass (the progressive deep shadow map).
    Random,
    /// The paper's estimator: free paths of a block of passes drawn at once, M strata.
    Stratified,
    /// Ratio tracking on the octree's local majorants.
    Ratio,
    /// Unbiased ray marching (Kettunen et al. 2021): jittered marches by the majorant, one
    /// the control of a power series cut by Russian roulette (the default).
    March,
}

/// Most light samples per camera segment (`--nee-samples`).
pub const MAX_NEE_SAMPLES: usize = 64;
/// Default light samples per camera segment: on smoke-grid at 48 passes, 4 stratified
/// samples cut the smoke's error by a third for 19 % more time (docs/benchmarks.md, "Direct light").
pub const DEFAULT_NEE_SAMPLES: usize = 4;

/// Default alpha of the surface photons (docs/benchmarks.md: measured against the beams' 0.9).
pub const DEFAULT_PHOTON_ALPHA: f32 = 0.9;

/// Auto beam radius R1, in pixel footprints at the distance of the media's centre.
/// Measured at 60 s on the conformance scenes (docs/benchmarks.md, "Radius schedules"): since the
/// beams carry only multiple scattering (4 NEE samples take the single), 2 against 1.5
/// cuts cloud-hg's error by 9 % and leaves fog-box and smoke-grid within their noise.
pub const AUTO_BEAM_PIXELS: f32 = 2.0;
/// Auto photon radius R1, in pixel footprints at the distance of the surfaces' centre.
/// Measured on glass-caustic's caustic at 60 and 300 s (docs/benchmarks.md, "Radius
/// schedules"): 1.5 beat 2 and 2 beat 3 on both metrics, the rim's blur costing more than
/// the noise a wider kernel saves.
pub const AUTO_PHOTON_PIXELS: f32 = 1.5;
/// R1 of the smooth photons (after a diffuse or medium scattering) over the photon radius
/// R1: 15 pixels (docs/benchmarks.md: measured at equal time).
pub const SMOOTH_PHOTON_SCALE: f32 = 10.0;
/// Kernel radius of the smooth beams (light that scattered [`SMOOTH_BEAM_AFTER`] times or
/// more, in media or on diffuse surfaces, before the beam) over the pass's beam radius,
/// with the hybrid method. Such light varies slowly, and each of its beams, dear to trace
/// through a dense medium, then serves more camera rays (docs/benchmarks.md, "Smooth
/// beams"). The pure method keeps one radius for every beam, as the paper does.
pub const SMOOTH_BEAM_SCALE: f32 = 2.0;
/// Scatterings after which a light path's beams are smooth: 4, so that thin media, whose
/// paths rarely scatter that often, pay almost nothing for the wider kernels (fog-box: 9 %
/// more beam evaluations, against 46 % from the second scattering on).
pub const SMOOTH_BEAM_AFTER: u32 = 4;
