//! One progressive render (a session, as Cycles calls it): the [`Tracer`] with the scene
//! data fixed for the render, its [`Plan`] of passes, an [`Estimator`] (CPU or GPU) and
//! the [`Film`]. [`Session::run`] is the one loop that accumulates passes: `render`,
//! `watch`, the benchmarks and the conformance tests are configurations of it, with
//! their own stopping rule and checkpoints in the callback.
//!
//! On the GPU, pass i is traced on the CPU and submitted, and the GPU estimates it while
//! the CPU traces pass i+1; its beam sums stay on the GPU until [`Session::image`].
use std::time::Instant;

use crate::error::{Error, Result};
use crate::estimate::Timings;
use crate::estimate::{cpu::CpuBeams, Estimator};
use crate::film::error::ErrorEstimate;
use crate::film::Film;
use crate::gpu::beams::{CameraTr, GpuBeams, GpuOptions, GpuStats, PrimaryPath};
use crate::gpu::Gpu;
use crate::output::Image;
use crate::pass::Tracer;
use crate::plan::{ramp_paths, PassPlan, Plan, Ramp};
use crate::transport::transmittance::StratStore;
use crate::transport::Counters;

/// Where the beam estimate runs: the GPU's estimator is kept by its type, so its
/// statistics need no place on the [`Estimator`] trait.
enum Beams {
    Gpu(Box<GpuBeams>),
    Other(Box<dyn Estimator>),
}

impl Beams {
    fn get(&mut self) -> &mut dyn Estimator {
        match self {
            Beams::Gpu(g) => g.as_mut(),
            Beams::Other(e) => e.as_mut(),
        }
    }
}

pub struct Session {
    tracer: Tracer,
    plan: Plan,
    ramp: Ramp,
    beams: Beams,
    film: Film,
    /// The stratified transmittance's free paths of the current block.
    strat: Option<StratStore>,
    pub counters: Counters,
    pub timings: Timings,
    /// Light paths and seconds of the last pass (the ramp's input).
    last: Option<(usize, f64)>,
}

/// What the loop does after a pass.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Flow {
    Continue,
    Stop,
}

/// A pass the loop just finished.
#[derive(Clone, Copy, Debug)]
pub struct PassDone {
    pub plan: PassPlan,
    /// Wall time of the pass on the CPU (tracing, and the estimate when it runs there).
    pub seconds: f64,
}

impl Session {
    /// A session estimating beams with `estimator`.
    pub fn new(tracer: Tracer, estimator: Box<dyn Estimator>) -> Self {
        Self::with_beams(tracer, Beams::Other(estimator))
    }

    fn with_beams(tracer: Tracer, beams: Beams) -> Self {
        let (w, h) = (tracer.settings.width, tracer.settings.height);
        Session {
            plan: tracer.plan(),
            strat: tracer.strat_store(),
            ramp: Ramp::Off,
            beams,
            film: Film::new(w, h).with_lights(tracer.light_pixels()),
            counters: Counters::default(),
            timings: Timings::default(),
            last: None,
            tracer,
        }
    }

    /// A session with the beam estimate on `gpu` (primary segments and camera
    /// transmittance as `primary` and `camera_tr` say), or on the CPU without one.
    pub fn open(
        tracer: Tracer,
        gpu: Option<Gpu>,
        primary: PrimaryPath,
        camera_tr: CameraTr,
    ) -> Result<Self> {
        let beams = match gpu {
            Some(g) => {
                let opts = GpuOptions::new(primary, camera_tr, &tracer.settings);
                Beams::Gpu(Box::new(GpuBeams::new(
                    g,
                    tracer.media(),
                    tracer.camera(),
                    opts,
                )?))
            }
            None => Beams::Other(Box::new(CpuBeams)),
        };
        Ok(Session::with_beams(tracer, beams))
    }

    /// A session on the CPU.
    pub fn cpu(tracer: Tracer) -> Self {
        Session::new(tracer, Box::new(CpuBeams))
    }

    /// Sets the light-path counts of the passes after a (re)start.
    pub fn with_ramp(mut self, ramp: Ramp) -> Self {
        self.ramp = ramp;
        self
    }

    pub fn tracer(&self) -> &Tracer {
        &self.tracer
    }

    pub fn plan(&self) -> &Plan {
        &self.plan
    }

    /// Passes in the film.
    pub fn passes(&self) -> u32 {
        self.film.passes()
    }

    /// "cpu", or the GPU adapter.
    pub fn device(&self) -> String {
        match &self.beams {
            Beams::Gpu(g) => g.describe(),
            Beams::Other(e) => e.describe(),
        }
    }

    /// How the GPU estimate overlapped tracing, when the GPU estimates.
    pub fn gpu_stats(&self) -> Option<GpuStats> {
        match &self.beams {
            Beams::Gpu(g) => Some(g.stats().clone()),
            Beams::Other(_) => None,
        }
    }

    /// Adds pass `p` to the film: traced on the CPU, estimated by the estimator (on the
    /// GPU, still running when this returns).
    pub fn pass(&mut self, p: &PassPlan) -> Result<()> {
        let t0 = Instant::now();
        let beam_map = self.beams.get().beam_map();
        let traced = self.tracer.trace(p, self.strat.as_mut(), beam_map);
        let t1 = Instant::now();
        self.film.add_pass(p.odd, &traced.camera.image);
        self.film.add_photon_nested(p.odd, &traced.camera.nested);
        self.film.add_alpha(&traced.camera.alpha);
        let evals =
            self.beams
                .get()
                .estimate(self.tracer.view(), &traced, &mut self.film, (t0, t1))?;
        self.counters.add(&traced.counters);
        self.counters.beam_evaluations += evals;
        self.timings.add(&traced.timings);
        self.timings.beam_estimate += t1.elapsed().as_secs_f64();
        Ok(())
    }

    /// The one loop: renders `passes` (global indices) in order, calling `each` after
    /// every pass until it answers [`Flow::Stop`]. The ramp (if any) sets each pass's
    /// light-path count from the previous pass.
    pub fn run<E: From<Error>>(
        &mut self,
        passes: impl IntoIterator<Item = u32>,
        mut each: impl FnMut(&mut Session, &PassDone) -> std::result::Result<Flow, E>,
    ) -> std::result::Result<(), E> {
        for i in passes {
            let full = self.plan.light_paths;
            let paths = match (self.ramp, self.last) {
                (Ramp::Off, _) => full,
                (Ramp::Doubling, last) => {
                    let (n, secs) = last.unwrap_or((0, 0.0));
                    ramp_paths(full, self.film.passes() + 1, n, secs)
                }
            };
            let plan = self.plan.pass_with_paths(i, paths);
            let start = Instant::now();
            self.pass(&plan)?;
            let seconds = start.elapsed().as_secs_f64();
            self.last = Some((paths, seconds));
            if each(self, &PassDone { plan, seconds })? == Flow::Stop {
                break;
            }
        }
        Ok(())
    }

    /// Renders passes 1..=`passes` and returns the image.
    pub fn render(&mut self, passes: u32) -> Result<Image> {
        self.run(1..=passes, |_, _| Ok::<_, Error>(Flow::Continue))?;
        self.image()
    }

    /// The image of pass `index` alone, with all the light paths (the film restarts).
    pub fn pass_image(&mut self, index: u32) -> Result<Image> {
        self.restart()?;
        let plan = self.plan.pass(index);
        self.pass(&plan)?;
        self.image()
    }

    /// The current image: the mean over passes at the settings' bandwidth (reads the
    /// GPU's sums back).
    pub fn image(&mut self) -> Result<Image> {
        let bandwidth = self.tracer.settings.bandwidth;
        let pixels = match self.beams.get().held()? {
            None => self.film.image_with(bandwidth),
            Some(acc) => {
                let mut film = self.film.clone();
                film.absorb(&acc);
                film.image_with(bandwidth)
            }
        };
        Ok(Image {
            width: self.film.width as usize,
            height: self.film.height as usize,
            pixels,
            alpha: self.film.alpha(),
        })
    }

    /// The film with the estimator's sums added (read back from the GPU): everything the
    /// passes so far added, to store in a part file.
    pub fn film(&mut self) -> Result<Film> {
        let mut film = self.film.clone();
        if let Some(acc) = self.beams.get().held()? {
            film.absorb(&acc);
        }
        Ok(film)
    }

    /// Continues from `film` (a partial part file's sums): the next passes add to it.
    pub fn resume(&mut self, film: Film) -> Result<()> {
        self.restart()?;
        self.film = film.with_lights(self.film.lights().to_vec());
        Ok(())
    }

    /// How far the image is from converged (its noise from the half-films, its bias from
    /// the nested sums); None until each half holds enough passes.
    pub fn error_estimate(&mut self) -> Result<Option<ErrorEstimate>> {
        let bandwidth = self.tracer.settings.bandwidth;
        Ok(match self.beams.get().held()? {
            None => self.film.error_estimate(bandwidth),
            Some(acc) => {
                let mut film = self.film.clone();
                film.absorb(&acc);
                film.error_estimate(bandwidth)
            }
        })
    }

    /// Empties the film and the estimator's sums; the next pass starts a new average.
    pub fn restart(&mut self) -> Result<()> {
        self.beams.get().clear()?;
        let lights = self.film.lights().to_vec();
        self.film = Film::new(self.film.width, self.film.height).with_lights(lights);
        self.last = None;
        Ok(())
    }
}
