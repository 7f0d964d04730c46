//! Progressive accumulation with the beam estimate on either device: on the CPU every pass
//! is finished at once; on the GPU pass i is traced on the CPU, submitted, and the GPU
//! estimates it while the CPU traces pass i+1. The GPU keeps its beam sums in a float32
//! accumulator that [`Progressive::image`] reads back (at checkpoints and at the end).
use std::time::Instant;

use crate::error::Result;
use crate::film::Film;
use crate::gpu::beams::{GpuBeams, GpuTiming};
use crate::gpu::Gpu;
use crate::output::Image;
use crate::render::{Renderer, Timings};
use crate::transport::Counters;

/// How the GPU estimate overlapped the CPU's tracing of the next pass.
#[derive(serde::Serialize, Default, Clone, Debug)]
pub struct GpuStats {
    pub adapter: String,
    pub passes: u32,
    /// Sum over passes of submission to completion of the estimate.
    pub estimate_seconds: f64,
    /// The part of that during which the CPU was tracing the next pass.
    pub overlap_seconds: f64,
    /// Time the CPU sat waiting for the GPU.
    pub wait_seconds: f64,
    /// Building and uploading segments and the beam BVH.
    pub upload_seconds: f64,
    /// Beam-segment crossings within the radius, counted by the GPU (as of the last
    /// read-back).
    pub beam_evaluations: u64,
}

impl GpuStats {
    /// Adds one finished pass; `tracing` is the CPU's tracing interval that ran meanwhile.
    fn record(&mut self, t: Option<GpuTiming>, tracing: Option<(Instant, Instant)>) {
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

pub struct Progressive {
    /// Everything but the GPU's beam estimate (all of it on the CPU path).
    pub film: Film,
    gpu: Option<GpuBeams>,
    pub gpu_stats: GpuStats,
    pub counters: Counters,
    pub timings: Timings,
}

impl Progressive {
    /// An empty accumulation for `r`'s image; with `gpu`, the beam estimate runs there.
    pub fn new(r: &Renderer, gpu: Option<Gpu>) -> Result<Self> {
        let (w, h) = (r.settings.width, r.settings.height);
        let mut stats = GpuStats::default();
        let gpu = match gpu {
            Some(g) => {
                stats.adapter = g.describe();
                Some(GpuBeams::new(g, r.media(), r.camera().origin(), w * h)?)
            }
            None => None,
        };
        Ok(Progressive {
            film: Film::new(w, h),
            gpu,
            gpu_stats: stats,
            counters: Counters::default(),
            timings: Timings::default(),
        })
    }

    pub fn on_gpu(&self) -> bool {
        self.gpu.is_some()
    }

    pub fn passes(&self) -> u32 {
        self.film.passes()
    }

    /// Runs pass i: on the CPU, or traced on the CPU and submitted to the GPU (returning
    /// while the GPU works).
    pub fn pass(&mut self, r: &Renderer, i: u32) -> Result<()> {
        match &mut self.gpu {
            None => {
                let pass = r.pass(i);
                self.film.add_pass(&pass.image);
                self.counters.add(&pass.counters);
                self.timings.add(&pass.timings);
            }
            Some(g) => {
                let t0 = Instant::now();
                let traced = r.trace(i, true);
                let t1 = Instant::now();
                self.film.add_pass(&traced.camera.image);
                self.counters.add(&traced.counters);
                self.timings.add(&traced.timings);
                let prev = g.submit(&traced, r.media())?;
                self.gpu_stats.record(prev, Some((t0, t1)));
            }
        }
        Ok(())
    }

    /// The current image: the mean over passes (reads the GPU accumulator back).
    pub fn image(&mut self) -> Result<Image> {
        let pixels = match &mut self.gpu {
            None => self.film.image(),
            Some(g) => {
                let (acc, timing) = g.read()?;
                self.gpu_stats.record(timing, None);
                self.gpu_stats.beam_evaluations =
                    acc.iter().map(|a| a[3] as f64).sum::<f64>() as u64;
                self.film.image_plus(&acc)
            }
        };
        Ok(Image {
            width: self.film.width as usize,
            height: self.film.height as usize,
            pixels,
        })
    }
}
