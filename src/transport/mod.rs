//! Path tracing from the lights (beams and surface photons) and from the camera.
//!
//! [`Beam`] and [`Photon`] are `#[repr(C)]` + `Pod`: the one definition that CPU code and
//! GPU buffers share.
pub mod camera;
pub mod direct;
pub mod emitters;
pub mod freepath;
pub mod light;
pub mod march;
pub mod transmittance;

use bytemuck::{Pod, Zeroable};
use glam::Vec3;

use crate::core::{Nested, Rgb};

/// Radiance leaving a diffuse point from light stored on surfaces, which camera paths ask
/// for at their diffuse end. The photon maps (`estimate::photons::Photons`) answer it;
/// camera tracing does not know how the light is stored.
pub trait SurfaceEstimate: Sync {
    /// Radiance towards the camera at `x` (normal `n` on the camera's side, Lambert
    /// reflectance `rho`) with its nested half-radius difference, counting the photons
    /// looked at in `lookups`.
    fn radiance(&self, x: Vec3, n: Vec3, rho: Rgb, lookups: &mut u64) -> Nested;
}

/// A photon beam (Jarosz et al. 2011, "short beam"): the stretch of a light path inside
/// media, from `origin` along unit `dir` for `length` m, ending where the path collided or
/// left the media (reaching one beam radius past the faces it crosses, see
/// `LightTracer::store_beams`). Its power is the path's power at `origin`, not attenuated
/// along it: the free-path sampling that ended it already accounts for the transmittance.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
pub struct Beam {
    pub origin: [f32; 3],
    pub length: f32,
    pub dir: [f32; 3],
    /// Its kernel's radius as a multiple of the pass's beam radius: 1, or
    /// [`crate::settings::SMOOTH_BEAM_SCALE`] for smooth light (`LightTracer::store_beams`).
    pub scale: f32,
    /// W per channel.
    pub power: [f32; 3],
    pub _pad2: f32,
}

/// A photon on a Lambert surface.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
pub struct Photon {
    pub position: [f32; 3],
    /// 1 when its path scattered diffusely or in a medium before (smooth light, estimated
    /// with a wider radius), 0 for light straight from a light or through specular
    /// surfaces only (direct light and caustics, which have sharp edges).
    pub smooth: u32,
    /// Surface normal on the side the photon arrived from.
    pub normal: [f32; 3],
    pub _pad2: f32,
    /// W per channel.
    pub power: [f32; 3],
    pub _pad3: f32,
}

impl Beam {
    pub fn new(origin: Vec3, dir: Vec3, length: f32, power: Vec3) -> Self {
        Beam {
            origin: origin.into(),
            length,
            dir: dir.into(),
            scale: 1.0,
            power: power.into(),
            _pad2: 0.0,
        }
    }

    /// The beam with its kernel `scale` times the pass's radius.
    pub fn scaled(self, scale: f32) -> Self {
        Beam { scale, ..self }
    }
}

impl Photon {
    pub fn new(position: Vec3, normal: Vec3, power: Vec3, smooth: bool) -> Self {
        Photon {
            position: position.into(),
            smooth: smooth as u32,
            normal: normal.into(),
            _pad2: 0.0,
            power: power.into(),
            _pad3: 0.0,
        }
    }
}

/// Machine-independent work counters, summed over threads.
#[derive(Clone, Copy, Debug, Default, serde::Serialize)]
pub struct Counters {
    pub light_paths: u64,
    pub beams: u64,
    pub photons: u64,
    pub free_paths: u64,
    pub density_lookups: u64,
    /// Octree leaves entered by adaptive tracking.
    pub octree_steps: u64,
    /// Tentative collisions found real below a leaf's minorant, without a lookup.
    pub minorant_accepts: u64,
    pub camera_rays: u64,
    pub beam_evaluations: u64,
    pub photon_lookups: u64,
    /// Shadow rays of next-event estimation.
    pub shadow_rays: u64,
    /// Thread-seconds spent sampling free paths (light and camera paths).
    pub free_path_seconds: f64,
    /// Thread-seconds spent on camera-segment transmittance.
    pub transmittance_seconds: f64,
    /// Calls seen by [`timed`] (drives its sampling).
    #[serde(skip)]
    pub timing_ticks: u64,
}

impl Counters {
    pub fn add(&mut self, o: &Counters) {
        self.light_paths += o.light_paths;
        self.beams += o.beams;
        self.photons += o.photons;
        self.free_paths += o.free_paths;
        self.density_lookups += o.density_lookups;
        self.octree_steps += o.octree_steps;
        self.minorant_accepts += o.minorant_accepts;
        self.camera_rays += o.camera_rays;
        self.beam_evaluations += o.beam_evaluations;
        self.photon_lookups += o.photon_lookups;
        self.shadow_rays += o.shadow_rays;
        self.free_path_seconds += o.free_path_seconds;
        self.transmittance_seconds += o.transmittance_seconds;
    }
}

/// Times one call in [`TIMING_STRIDE`] and counts it that many times: an unbiased
/// estimate of the total with a sixteenth of the clock reads, which would otherwise cost
/// as much as a short free path.
pub const TIMING_STRIDE: u64 = 16;

/// Runs `f`, adding its (sampled) duration to `*seconds`; `tick` counts the calls. The
/// clock's own cost inside a timed interval (about 45 ns on a VM, as much as a third of a
/// free path) is subtracted, so short calls are not overstated.
pub fn timed<T>(tick: &mut u64, seconds: &mut f64, f: impl FnOnce() -> T) -> T {
    *tick += 1;
    if !(*tick).is_multiple_of(TIMING_STRIDE) {
        return f();
    }
    let overhead = clock_overhead();
    let t0 = std::time::Instant::now();
    let out = f();
    // No clamp at 0: single samples may go negative, their sum stays unbiased.
    *seconds += (t0.elapsed().as_secs_f64() - overhead) * TIMING_STRIDE as f64;
    out
}

/// Mean duration of an empty timed interval (seconds), measured once per process.
fn clock_overhead() -> f64 {
    static OVERHEAD: std::sync::OnceLock<f64> = std::sync::OnceLock::new();
    *OVERHEAD.get_or_init(|| {
        const N: u32 = 20_000;
        let total: f64 = (0..N)
            .map(|_| std::time::Instant::now().elapsed().as_secs_f64())
            .sum();
        total / N as f64
    })
}

/// Upper bound on scattering events per path, as the references (Mitsuba max_depth 1024).
pub const MAX_DEPTH: u32 = 1024;
