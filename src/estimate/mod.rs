//! Radiance estimates from one pass's light records: beams along camera segments (eq. 2)
//! and photons at diffuse camera hits (progressive photon mapping), with the radius
//! schedule of eq. 3; and the [`Estimator`] that finishes a traced pass's beam estimate
//! on the CPU ([`cpu::CpuBeams`]) or on the GPU (`gpu::beams::GpuBeams`).
pub mod beams;
pub mod cpu;
pub mod eq2;
pub mod photons;
pub mod radius;
pub mod splat;

use std::time::Instant;

use crate::error::Result;
use crate::film::Film;
use crate::gpu::beams::GpuStats;
use crate::pass::{TracedPass, Tracer};

/// Where the beam estimate of traced passes runs. Both implementations compute the same
/// per-pixel sums; a session calls [`Estimator::estimate`] once per pass in order.
pub trait Estimator: Send {
    /// "cpu", or the GPU adapter.
    fn describe(&self) -> String;
    /// Whether a traced pass must carry the beam BVH for every camera segment.
    fn needs_beam_map(&self) -> bool;
    /// Adds pass `t`'s beam estimate to `film` (CPU), or starts it and returns while it
    /// runs, its sums kept aside until [`Estimator::held`] (GPU). `traced` is when the CPU
    /// traced `t`. Returns the beam evaluations counted now.
    fn estimate(
        &mut self,
        tracer: &Tracer,
        t: &TracedPass,
        film: &mut Film,
        traced: (Instant, Instant),
    ) -> Result<u64>;
    /// Per-pixel beam sums (RGB, evaluations) kept outside the film, after the pass in
    /// flight ends; None when everything is in the film already.
    fn held(&mut self) -> Result<Option<Vec<[f32; 4]>>>;
    /// Forgets the sums kept aside (the session restarts).
    fn clear(&mut self) -> Result<()>;
    /// How the GPU estimate overlapped tracing, for a GPU estimator.
    fn gpu_stats(&self) -> Option<GpuStats> {
        None
    }
}
