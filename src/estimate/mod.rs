//! Radiance estimates from one pass's light records: beams along camera segments (eq. 2)
//! and photons at diffuse camera hits (progressive photon mapping), with the radius
//! schedule of eq. 3; and the [`Estimator`] that finishes a traced pass's beam estimate
//! on the CPU ([`cpu::CpuBeams`]) or on the GPU (`gpu::beams::GpuBeams`).
pub mod beams;
pub mod cpu;
pub mod eq2;
pub mod lanes;
pub mod photons;
pub mod radius;
pub mod splat;
pub mod tube;

use std::time::Instant;

use glam::Vec3;

use crate::core::{ray_box, Ray};
use crate::error::Result;
use crate::film::{Film, Held};
use crate::media::Media;
use crate::transport::camera::{CameraPass, Pinhole};
use crate::transport::{Beam, Counters};
use beams::{BeamMap, MapNeed};
use eq2::BeamKernel;

/// Where a camera segment [0, t_end) stops gathering beams: where it leaves `bounds`, the
/// box of every medium (None: it misses the box, and gathers nothing). Beyond, every
/// term is 0; cut there, the tube kernel's chords and their points stay in the media, and
/// the CPU and the GPU (whose segments end there) draw the same points.
pub fn beam_reach(bounds: Option<&[Vec3; 2]>, ray: &Ray, t_end: f32) -> Option<f32> {
    ray_box(ray, bounds?, 0.0, t_end).map(|(_, t1)| t1)
}

/// Wall-clock seconds of one pass's stages.
#[derive(Clone, Copy, Debug, Default, serde::Serialize)]
pub struct Timings {
    pub light_tracing: f64,
    pub build_maps: f64,
    pub camera_paths: f64,
    /// The beam estimate on the CPU (0 when the GPU does it).
    pub beam_estimate: f64,
}

impl Timings {
    pub fn add(&mut self, o: &Timings) {
        self.light_tracing += o.light_tracing;
        self.build_maps += o.build_maps;
        self.camera_paths += o.camera_paths;
        self.beam_estimate += o.beam_estimate;
    }

    pub fn total(&self) -> f64 {
        self.light_tracing + self.build_maps + self.camera_paths + self.beam_estimate
    }
}

/// A pass traced up to the beam estimate: everything the estimate reads.
pub struct TracedPass {
    /// 1-based pass number.
    pub index: u32,
    /// Whether it adds to the film's second half-film (`PassPlan::odd`).
    pub odd: bool,
    pub camera: CameraPass,
    pub beams: Vec<Beam>,
    /// The beam BVH (built when the camera can reach a specular surface, or on request).
    pub beam_map: Option<BeamMap>,
    pub beam_radius: f32,
    pub counters: Counters,
    pub timings: Timings,
}

/// What stays fixed across a render's passes that an estimate reads besides the pass.
#[derive(Clone, Copy)]
pub struct View<'a> {
    pub camera: &'a Pinhole,
    pub media: &'a Media,
    /// The beam kernel.
    pub kernel: BeamKernel,
}

/// Where the beam estimate of traced passes runs. Both implementations compute the same
/// per-pixel sums; a session calls [`Estimator::estimate`] once per pass in order.
pub trait Estimator: Send {
    /// "cpu", or the GPU adapter.
    fn describe(&self) -> String;
    /// Which beam BVH a traced pass must carry, and when.
    fn beam_map(&self) -> MapNeed;
    /// Adds pass `t`'s beam estimate to `film` (CPU), or starts it and returns while it
    /// runs, its sums kept aside until [`Estimator::held`] (GPU). `traced` is when the CPU
    /// traced `t`. Returns the beam evaluations counted now.
    fn estimate(
        &mut self,
        view: View,
        t: &TracedPass,
        film: &mut Film,
        traced: (Instant, Instant),
    ) -> Result<u64>;
    /// Per-pixel beam sums (RGB, evaluations) kept outside the film, of the even and of the
    /// odd passes, after the pass in flight ends; None when everything is in the film
    /// already.
    fn held(&mut self) -> Result<Option<Held>>;
    /// Forgets the sums kept aside (the session restarts).
    fn clear(&mut self) -> Result<()>;
}
