//! One progressive pass = light tracing (beams + photons), camera paths (with the photon
//! estimate and the camera transmittance), then the beam estimate along the camera
//! segments, on the CPU ([`Renderer::pass`]) or on the GPU (`gpu::beams`) while the next
//! pass is traced. [`Renderer`] holds what stays fixed across passes.
use glam::Vec3;
use std::time::Instant;

use crate::error::{Error, Result};
use crate::estimate::{beams::BeamMap, cpu, photons::PhotonMap, radius};
use crate::geometry::Geometry;
use crate::majorant::Octree;
use crate::media::homogeneous::ray_box;
use crate::media::Media;
use crate::scene::{Rgb, Scene};
use crate::settings::{Radius, RenderSettings, AUTO_BEAM_PIXELS, AUTO_PHOTON_PIXELS};
use crate::transport::camera::{CameraPass, CameraTracer, Pinhole};
use crate::transport::freepath::{Adaptive, FreePath, Mode, Woodcock};
use crate::transport::light::{LightSampler, LightTracer};
use crate::transport::transmittance::{StratStore, TrMode, MAX_TR_BLOCK};
use crate::transport::{Beam, Counters};
use rayon::prelude::*;
use std::sync::Mutex;

pub struct Renderer {
    pub settings: RenderSettings,
    geometry: Geometry,
    media: Media,
    lights: LightSampler,
    camera: Pinhole,
    /// R1 of the beams and of the photons (m).
    pub beam_r1: f32,
    pub photon_r1: f32,
    /// Whether camera paths can continue past a surface (then later camera segments need
    /// the beam BVH).
    has_specular: bool,
    /// Majorant octree of each grid medium (same order as the scene's grid media).
    octrees: Vec<Octree>,
    /// Stratified transmittance state carried across the passes of a block.
    strat: Mutex<Option<StratStore>>,
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
    pub camera: CameraPass,
    pub beams: Vec<Beam>,
    /// The beam BVH (built when the camera can reach a specular surface, or on request).
    pub beam_map: Option<BeamMap>,
    pub beam_radius: f32,
    pub counters: Counters,
    pub timings: Timings,
}

pub struct PassResult {
    pub image: Vec<Rgb>,
    pub counters: Counters,
    pub timings: Timings,
}

impl Renderer {
    /// A renderer that bakes the grids' octrees in memory (no cache).
    pub fn new(scene: &Scene, settings: RenderSettings) -> Result<Self> {
        let octrees = scene
            .grid_media
            .iter()
            .map(|g| Octree::build(g, settings.octree_depth))
            .collect();
        Self::with_octrees(scene, settings, octrees)
    }

    /// A renderer using already built (or cached) octrees, one per grid medium.
    pub fn with_octrees(
        scene: &Scene,
        settings: RenderSettings,
        octrees: Vec<Octree>,
    ) -> Result<Self> {
        if octrees.len() != scene.grid_media.len() {
            return Err(Error::Other("one octree per grid medium expected".into()));
        }
        let geometry = Geometry::new(scene)?;
        let media = Media::with_grids(scene.media.clone(), scene.grid_media.clone());
        let camera = Pinhole::new(&scene.camera, settings.width, settings.height);
        let bounds = union(geometry.bounds(), media.bounds()).ok_or_else(|| {
            Error::Other("the scene has neither surfaces nor media to light".into())
        })?;
        let lights = LightSampler::new(&scene.lights, bounds);
        if lights.total_power().max_element() <= 0.0 {
            return Err(Error::Other("the lights emit no power".into()));
        }
        let auto = |b: Option<[Vec3; 2]>, pixels: f32| {
            let c = b.map_or(0.5 * (bounds[0] + bounds[1]), |b| 0.5 * (b[0] + b[1]));
            pixels * camera.pixel_footprint((c - camera.origin()).length().max(1e-3))
        };
        let beam_r1 = match settings.beam_radius {
            Radius::Fixed(r) => r,
            Radius::Auto => auto(media.bounds(), AUTO_BEAM_PIXELS),
        };
        let photon_r1 = match settings.photon_radius {
            Radius::Fixed(r) => r,
            Radius::Auto => auto(geometry.bounds(), AUTO_PHOTON_PIXELS),
        };
        let has_specular = scene
            .materials
            .iter()
            .any(|m| !matches!(m.material, crate::scene::Material::Lambert { .. }));
        if settings.tr_block == 0
            || settings.tr_block > MAX_TR_BLOCK
            || !settings.tr_block.is_multiple_of(settings.tr_samples)
        {
            return Err(Error::Other(format!(
                "tr_block must be a multiple of tr_samples ({}) in 1..={MAX_TR_BLOCK}, got {}",
                settings.tr_samples, settings.tr_block
            )));
        }
        let strat = (settings.tr_mode == TrMode::Stratified && media.has_grids()).then(|| {
            let pixels = (settings.width * settings.height) as usize;
            StratStore::new(pixels, settings.tr_block, settings.tr_samples)
        });
        Ok(Renderer {
            strat: Mutex::new(strat),
            octrees,
            has_specular,
            settings,
            geometry,
            media,
            lights,
            camera,
            beam_r1,
            photon_r1,
        })
    }

    /// Optical depth of the media along each pixel's centre ray up to the first surface
    /// (midpoint rule, 512 steps over the media's span), row by row: where the camera
    /// transmittance estimate matters (the paper measures its error in such a region).
    pub fn camera_optical_depths(&self) -> Vec<f32> {
        const STEPS: usize = 512;
        let (w, h) = (self.settings.width, self.settings.height);
        let Some(bounds) = self.media.bounds() else {
            return vec![0.0; (w * h) as usize];
        };
        (0..w * h)
            .into_par_iter()
            .map(|i| {
                let ray = self.camera.ray((i % w) as f32 + 0.5, (i / w) as f32 + 0.5);
                let t_surface = self
                    .geometry
                    .intersect(&ray, f32::MAX)
                    .map_or(f32::MAX, |h| h.t);
                let Some((a, b)) = ray_box(&ray, &bounds, 0.0, t_surface) else {
                    return 0.0;
                };
                let dt = (b - a) / STEPS as f32;
                (0..STEPS)
                    .map(|k| self.media.sigma_t(ray.at(a + (k as f32 + 0.5) * dt)) * dt)
                    .sum()
            })
            .collect()
    }

    /// Renders pass `i` (1-based) on the CPU.
    pub fn pass(&self, i: u32) -> PassResult {
        self.estimate_cpu(self.trace(i, false))
    }

    /// Light tracing and camera paths of pass `i`; `beam_map` forces the beam BVH (the GPU
    /// estimate walks it for every segment).
    pub fn trace(&self, i: u32, beam_map: bool) -> TracedPass {
        let s = &self.settings;
        let woodcock = Woodcock { media: &self.media };
        let adaptive = Adaptive {
            media: &self.media,
            octrees: &self.octrees,
        };
        let free_path: &dyn FreePath = match s.free_path {
            Mode::Adaptive => &adaptive,
            Mode::Woodcock => &woodcock,
        };
        let t0 = Instant::now();
        let beam_r = radius::beam_radius(self.beam_r1, i, s.alpha);
        let lt = LightTracer {
            lights: &self.lights,
            geometry: &self.geometry,
            media: &self.media,
            free_path,
            beam_margin: beam_r,
        };
        let light = lt.trace_pass(s.seed, i, s.beams_per_pass);
        let t1 = Instant::now();
        let beam_map = ((beam_map || self.has_specular) && !self.media.is_empty())
            .then(|| BeamMap::build(&light.beams, beam_r));
        let photons = PhotonMap::build(
            &light.photons,
            radius::photon_radius(self.photon_r1, i, s.alpha),
        );
        let t2 = Instant::now();
        let ct = CameraTracer {
            camera: &self.camera,
            geometry: &self.geometry,
            media: &self.media,
            free_path,
            tr_samples: s.tr_samples,
            tr_mode: s.tr_mode,
            photons: &photons,
        };
        let mut strat = self.strat.lock().unwrap_or_else(|e| e.into_inner());
        let camera = ct.trace_pass(s.seed, i, strat.as_mut());
        let t3 = Instant::now();
        let mut counters = light.counters;
        counters.add(&camera.counters);
        TracedPass {
            index: i,
            camera,
            beams: light.beams,
            beam_map,
            beam_radius: beam_r,
            counters,
            timings: Timings {
                light_tracing: (t1 - t0).as_secs_f64(),
                build_maps: (t2 - t1).as_secs_f64(),
                camera_paths: (t3 - t2).as_secs_f64(),
                beam_estimate: 0.0,
            },
        }
    }

    /// The beam estimate of a traced pass on the CPU alone (without the camera paths'
    /// photon estimate), with its count of beam evaluations.
    pub fn beam_image(&self, t: &TracedPass) -> (Vec<Rgb>, u64) {
        cpu::beam_image(
            &self.camera,
            &self.media,
            &t.camera,
            &t.beams,
            t.beam_map.as_ref(),
            t.beam_radius,
        )
    }

    /// Finishes a traced pass with the beam estimate on the CPU.
    pub fn estimate_cpu(&self, t: TracedPass) -> PassResult {
        let start = Instant::now();
        let (beam_img, evals) = self.beam_image(&t);
        let mut image = t.camera.image;
        for (a, b) in image.iter_mut().zip(beam_img) {
            *a += b;
        }
        let mut counters = t.counters;
        counters.beam_evaluations += evals;
        let mut timings = t.timings;
        timings.beam_estimate = start.elapsed().as_secs_f64();
        PassResult {
            image,
            counters,
            timings,
        }
    }

    pub fn camera(&self) -> &Pinhole {
        &self.camera
    }

    pub fn media(&self) -> &Media {
        &self.media
    }

    pub fn triangle_count(&self) -> usize {
        self.geometry.triangle_count()
    }
}

fn union(a: Option<[Vec3; 2]>, b: Option<[Vec3; 2]>) -> Option<[Vec3; 2]> {
    match (a, b) {
        (Some(a), Some(b)) => Some([a[0].min(b[0]), a[1].max(b[1])]),
        (a, None) => a,
        (None, b) => b,
    }
}
