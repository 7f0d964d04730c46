//! `ppb bench-gpu`: the beam estimate of the same traced passes on the CPU and on the GPU
//! (primary segments rasterised and gathered), timed and compared.
use anyhow::Result;
use clap::Args;
use std::process::ExitCode;
use std::sync::{Arc, Mutex};
use std::time::Instant;

use ppb::compare::DeviceDiff;
use ppb::error::Result as PpbResult;
use ppb::estimate::beams::MapNeed;
use ppb::estimate::Estimator;
use ppb::estimate::{TracedPass, View};
use ppb::film::{Film, Held};
use ppb::gpu::beams::{CameraTr, GpuBeams, GpuOptions, PrimaryPath};
use ppb::gpu::DeviceKind;
use ppb::pass::Tracer;
use ppb::session::{Flow, Session};

use super::bench::BenchArgs;
use super::scene_name;

#[derive(Args)]
pub struct BenchGpuArgs {
    #[command(flatten)]
    pub bench: BenchArgs,
    /// Device to measure against the CPU: gpu (any adapter, the default here) or auto
    /// (hardware adapters only).
    #[arg(long, value_enum, default_value = "gpu")]
    pub device: DeviceKind,
}

/// What `bench-gpu` measures over a session's passes.
#[derive(Default)]
struct DeviceRace {
    cpu_seconds: f64,
    gpu_seconds: f64,
    pairs: u64,
    diff: DeviceDiff,
    /// Why this way stopped (a software adapter's loop limit, say); the others go on.
    failed: Option<String>,
}

/// An estimator that runs every pass's beam estimate on the CPU (into the film) and, on
/// their own, on the GPU once per way of estimating primary segments, timing each and
/// comparing their images with the CPU's.
struct Race {
    gpus: Vec<GpuBeams>,
    out: Arc<Mutex<Vec<DeviceRace>>>,
}

impl Estimator for Race {
    fn describe(&self) -> String {
        self.gpus
            .first()
            .map_or_else(|| "cpu".into(), |g| g.describe())
    }

    /// The binary tree, which both the CPU and the GPU walk, for every pass.
    fn beam_map(&self) -> MapNeed {
        MapNeed::GPU_EVERY_PASS
    }

    fn estimate(
        &mut self,
        view: View,
        t: &TracedPass,
        film: &mut Film,
        _traced: (Instant, Instant),
    ) -> PpbResult<u64> {
        let start = Instant::now();
        let (cpu, evals) = ppb::estimate::cpu::beam_image(view, t);
        let cpu_seconds = start.elapsed().as_secs_f64();
        film.add(t.odd, &cpu);
        for (k, gpu) in self.gpus.iter_mut().enumerate() {
            if self.out.lock().unwrap_or_else(|e| e.into_inner())[k]
                .failed
                .is_some()
            {
                continue;
            }
            let run = |gpu: &mut GpuBeams| -> PpbResult<(f64, Vec<[f32; 4]>)> {
                gpu.clear()?;
                let start = Instant::now();
                gpu.submit(view, t)?;
                let done = gpu.wait()?.map_or_else(Instant::now, |t| t.done);
                Ok(((done - start).as_secs_f64(), gpu.read()?.0))
            };
            let result = run(gpu);
            let mut out = self.out.lock().unwrap_or_else(|e| e.into_inner());
            let o = &mut out[k];
            match result {
                Ok((gpu_seconds, acc)) => {
                    o.cpu_seconds += cpu_seconds;
                    o.gpu_seconds += gpu_seconds;
                    o.pairs += evals;
                    o.diff.add(&cpu, &acc);
                }
                Err(e) => o.failed = Some(e.to_string()),
            }
        }
        Ok(evals)
    }

    fn held(&mut self) -> PpbResult<Option<Held>> {
        Ok(None)
    }

    fn clear(&mut self) -> PpbResult<()> {
        Ok(())
    }
}

/// Times the beam estimate of the same traced passes on the CPU and on the GPU.
pub fn bench_gpu(args: BenchGpuArgs) -> Result<ExitCode> {
    println!(
        "{:<22} {:<7} {:>9} {:>8} {:>10} {:>10} {:>8} {:>12} {:>12} {:>12} {:>9} {:>8}",
        "scene",
        "primary",
        "size",
        "paths",
        "CPU ms/ps",
        "GPU ms/ps",
        "CPU/GPU",
        "pairs/pass",
        "pairs/s CPU",
        "pairs/s GPU",
        "rel diff",
        "px>1e-3"
    );
    let mut adapter = String::new();
    for scene in &args.bench.scenes {
        let file = args.bench.load(scene)?;
        let mut s = args.bench.settings(&file)?;
        // Eq. 2's line, whose gathered and rasterised sums both equal the CPU splat's (under
        // the tube each beam piece a gathered primary crosses draws its own point).
        s.beam_kernel = Some(ppb::settings::BeamKernel::Line);
        let tracer = Tracer::new(&file.scene, s.clone())?;
        let Some(gpu) = super::open_device(args.device, true)? else {
            anyhow::bail!("no GPU adapter to measure (try --device gpu)");
        };
        adapter = gpu.describe();
        let mut paths = vec![PrimaryPath::Gather];
        if PrimaryPath::Auto.resolve(&gpu, s.width, s.height)? != PrimaryPath::Gather {
            paths.insert(0, PrimaryPath::Raster);
        }
        let gpus = paths
            .iter()
            .map(|&p| {
                let opts = GpuOptions::new(p, CameraTr::Steps, &tracer.settings);
                GpuBeams::new(gpu.clone(), tracer.media(), tracer.camera(), opts)
            })
            .collect::<PpbResult<Vec<_>>>()?;
        let out = Arc::new(Mutex::new(
            paths.iter().map(|_| DeviceRace::default()).collect(),
        ));
        let race = Race {
            gpus,
            out: out.clone(),
        };
        let mut session = Session::new(tracer, Box::new(race));
        session.run(1..=args.bench.passes, |_, _| {
            Ok::<_, anyhow::Error>(Flow::Continue)
        })?;
        let races = out.lock().unwrap_or_else(|e| e.into_inner());
        for (path, r) in paths.iter().zip(races.iter()) {
            if let Some(why) = &r.failed {
                println!(
                    "{:<22} {:<7} failed: {why}",
                    scene_name(scene),
                    format!("{path:?}").to_lowercase()
                );
                continue;
            }
            let n = args.bench.passes.max(1) as f64;
            println!(
            "{:<22} {:<7} {:>9} {:>8} {:>10.1} {:>10.1} {:>8.2} {:>12.0} {:>12.3e} {:>12.3e} {:>9.1e} {:>8}",
            scene_name(scene),
            format!("{path:?}").to_lowercase(),
            format!("{}x{}", s.width, s.height),
            s.light_paths,
            1e3 * r.cpu_seconds / n,
            1e3 * r.gpu_seconds / n,
            r.cpu_seconds / r.gpu_seconds.max(1e-12),
            r.pairs as f64 / n,
            r.pairs as f64 / r.cpu_seconds.max(1e-12),
            r.pairs as f64 / r.gpu_seconds.max(1e-12),
            r.diff.rel_l1(),
            r.diff.off_pixels
        );
        }
    }
    println!(
        "(GPU: {adapter}; times per pass of the beam estimate alone on the same traced passes, \
         GPU including segment/BVH upload; primary: how the GPU estimated primary segments \
         (raster: beam quads, where the adapter can blend float32 targets; gather: BVH queries); pairs = beam-segment crossings within the radius; \
         rel diff = sum|GPU - CPU| / sum CPU over all passes; px>1e-3 = pixels (all passes) \
         differing by more than 1e-3 relative; CPU threads: {})",
        rayon::current_num_threads()
    );
    Ok(ExitCode::SUCCESS)
}
