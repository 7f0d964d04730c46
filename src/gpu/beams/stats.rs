//! What `--stats` records of the GPU estimate: time per pass split into estimate, overlap
//! with CPU tracing and waiting, bytes uploaded, and the way primaries went.
use std::time::{Duration, Instant};

use super::options::{CameraTr, PrimaryPath};

/// When the GPU ran one pass's estimate, and how long the CPU waited for it.
#[derive(Clone, Copy, Debug)]
pub struct GpuTiming {
    pub submitted: Instant,
    pub done: Instant,
    pub waited: Duration,
    pub upload_seconds: f64,
}

/// How the GPU estimate overlapped the CPU's tracing of the next pass.
#[derive(serde::Serialize, Default, Clone, Debug)]
pub struct GpuStats {
    pub adapter: String,
    /// How primary segments were estimated.
    pub primary: Option<PrimaryPath>,
    /// Where the camera transmittance came from.
    pub camera_tr: Option<CameraTr>,
    pub passes: u32,
    /// Sum over passes of submission to completion of the estimate.
    pub estimate_seconds: f64,
    /// The part of that during which the CPU was tracing the next pass.
    pub overlap_seconds: f64,
    /// Time the CPU sat waiting for the GPU.
    pub wait_seconds: f64,
    /// Building and uploading segments and the beam BVH.
    pub upload_seconds: f64,
    /// Bytes uploaded for the passes (segments, beams, BVH, quads, transmittance steps)
    /// and the transmittance steps' share: none when the GPU tracks transmittance.
    pub upload_bytes: u64,
    pub tr_step_bytes: u64,
    /// Beam-segment crossings within the radius, counted by the GPU (as of the last
    /// read-back).
    pub beam_evaluations: u64,
}

impl GpuStats {
    /// Adds one finished pass; `tracing` is the CPU's tracing interval that ran meanwhile.
    pub(super) fn record(&mut self, t: Option<GpuTiming>, tracing: Option<(Instant, Instant)>) {
        let Some(t) = t else { return };
        self.passes += 1;
        self.estimate_seconds += (t.done - t.submitted).as_secs_f64();
        self.wait_seconds += t.waited.as_secs_f64();
        self.upload_seconds += t.upload_seconds;
        if let Some((a, b)) = tracing {
            let (lo, hi) = (a.max(t.submitted), b.min(t.done));
            if hi > lo {
                self.overlap_seconds += (hi - lo).as_secs_f64();
            }
        }
    }
}
