//! One pass of the pipeline up to its beam estimate. [`Tracer`] holds what stays fixed
//! across passes (geometry, media with their majorants, lights, camera, R1) and traces a
//! [`PassPlan`]'s light paths (beams and photons) and camera paths (with the photon
//! estimate and the camera transmittance) into a [`TracedPass`], which an
//! [`Estimator`](crate::estimate::Estimator) finishes on the CPU or the GPU.
use glam::Vec3;
use std::time::Instant;

use crate::core::ray_box;
use crate::core::Rgb;
use crate::error::{Error, Result};
use crate::estimate::beams::{BeamMap, MapNeed};
use crate::estimate::{cpu, photons::Photons, Timings, TracedPass, View};
use crate::geometry::Geometry;
use crate::media::{Media, Support};
use crate::plan::{PassPlan, Plan};
use crate::scene::{Light, Scene};
use crate::settings::TrMode;
use crate::settings::{
    Method, Radius, RenderSettings, AUTO_BEAM_PIXELS, AUTO_PHOTON_PIXELS, SMOOTH_BEAM_SCALE,
    SMOOTH_PHOTON_SCALE,
};
use crate::transport::camera::{CameraTracer, Pinhole};
use crate::transport::direct::Direct;
use crate::transport::freepath::FreePath;
use crate::transport::light::{LightSampler, LightTracer};
use crate::transport::transmittance::StratStore;
use rayon::prelude::*;

pub struct Tracer {
    pub settings: RenderSettings,
    geometry: Geometry,
    media: Media,
    /// Where the media scatter light, grown by the widest beam kernel of the render.
    support: Support,
    lights: LightSampler,
    camera: Pinhole,
    /// R1 of the beams and of the photons (m).
    pub beam_r1: f32,
    pub photon_r1: f32,
    /// R1 of the smooth photons (after a diffuse or medium scattering).
    pub smooth_photon_r1: f32,
    /// Whether camera paths can continue past a surface (then later camera segments need
    /// the beam BVH).
    has_specular: bool,
}

impl Tracer {
    /// The pixels that see a light directly, which the error estimate leaves out.
    pub fn light_pixels(&self) -> Vec<u32> {
        crate::transport::camera::light_pixels(&self.camera, &self.geometry)
    }

    /// A tracer whose grids' octrees are baked in memory (no cache).
    pub fn new(scene: &Scene, settings: RenderSettings) -> Result<Self> {
        let media = Media::bake(
            scene.media.clone(),
            &scene.grid_media,
            settings.octree_depth,
        );
        Self::with_media(scene, settings, media)
    }

    /// A tracer for `scene` whose media (each grid with its majorants, e.g. from the
    /// cache) are `media`.
    pub fn with_media(scene: &Scene, settings: RenderSettings, media: Media) -> Result<Self> {
        let geometry = Geometry::new(scene)?;
        let camera = Pinhole::new(&scene.camera, settings.width, settings.height);
        // A scene of nothing but an environment is its sky, seen from the camera.
        let sky_only = scene.lights.iter().any(Light::is_background).then(|| {
            let o = scene.camera.origin;
            [o - Vec3::ONE, o + Vec3::ONE]
        });
        let bounds = union(geometry.bounds(), media.bounds())
            .or(sky_only)
            .ok_or_else(|| {
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
        let smooth_photon_r1 = match settings.smooth_photon_radius {
            Radius::Fixed(r) => r,
            Radius::Auto => photon_r1 * SMOOTH_PHOTON_SCALE,
        };
        let has_specular = scene
            .materials
            .iter()
            .any(|m| !matches!(m.material, crate::scene::Material::Lambert { .. }));
        settings
            .validate()
            .map_err(|e| Error::Other(format!("render settings: {e}")))?;
        // Eq. 3 only shrinks the radius: the first pass's widest kernel bounds them all.
        let support = media.support(beam_r1 * smooth_beam_scale(settings.method));
        Ok(Tracer {
            has_specular,
            settings,
            geometry,
            media,
            support,
            lights,
            camera,
            beam_r1,
            photon_r1,
            smooth_photon_r1,
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

    /// The plan of this render's passes.
    pub fn plan(&self) -> Plan {
        Plan {
            seed: self.settings.seed,
            alpha: self.settings.alpha,
            photon_alpha: self.settings.photon_alpha,
            beam_r1: self.beam_r1,
            photon_r1: self.photon_r1,
            smooth_photon_r1: self.smooth_photon_r1,
            light_paths: self.settings.light_paths,
            group: match self.strat_store() {
                Some(_) => self.settings.tr_block as u32,
                None => 1,
            },
        }
    }

    /// The store the stratified camera transmittance carries across a block's passes
    /// (None for the other estimators or without grids).
    pub fn strat_store(&self) -> Option<StratStore> {
        let s = &self.settings;
        (s.tr_mode == TrMode::Stratified && self.media.has_grids()).then(|| {
            let pixels = (s.width * s.height) as usize;
            StratStore::new(pixels, s.tr_block, s.tr_samples)
        })
    }

    /// Light tracing and camera paths of pass `p`, with the beam BVH that `beam_map` asks
    /// for; `strat` is the session's stratified store. The BVH's build (serial) runs
    /// beside the camera paths, which do not read it.
    pub fn trace(
        &self,
        p: &PassPlan,
        strat: Option<&mut StratStore>,
        beam_map: MapNeed,
    ) -> TracedPass {
        let s = &self.settings;
        let free_path = FreePath {
            media: &self.media,
            mode: s.free_path,
        };
        let t0 = Instant::now();
        let lt = LightTracer {
            lights: &self.lights,
            geometry: &self.geometry,
            media: &self.media,
            support: &self.support,
            free_path,
            beam_radius: p.beam_radius,
            smooth_beam_scale: smooth_beam_scale(s.method),
            skip_direct: s.method == Method::Hybrid,
        };
        let light = lt.trace_pass(p.seed, p.index, p.light_paths);
        let t1 = Instant::now();
        let photons = Photons::build(&light.photons, p.photon_radius, p.smooth_photon_radius);
        let ct = CameraTracer {
            camera: &self.camera,
            geometry: &self.geometry,
            media: &self.media,
            free_path,
            tr_samples: s.tr_samples,
            tr_mode: s.tr_mode,
            lights: &self.lights,
            photons: &photons,
            direct: (s.method == Method::Hybrid).then_some(Direct {
                lights: &self.lights,
                geometry: &self.geometry,
                free_path,
                samples: s.nee_samples,
            }),
            transparent: s.transparent,
        };
        let wanted = (beam_map.every_pass || self.has_specular) && !self.media.is_empty();
        // The build on a thread of its own: run as the other half of a rayon::join, it
        // changed how the camera rows were split between the workers and made them 20 %
        // slower on the dense smoke.
        let (beam_map, camera, camera_seconds) = std::thread::scope(|scope| {
            let build = wanted.then(|| {
                scope.spawn(|| BeamMap::build(&light.beams, p.beam_radius, beam_map.walker))
            });
            let start = Instant::now();
            let camera = ct.trace_pass(p.seed, p.index, strat);
            let seconds = start.elapsed().as_secs_f64();
            let map = build.map(|b| b.join().unwrap_or_else(|e| std::panic::resume_unwind(e)));
            (map, camera, seconds)
        });
        let t3 = Instant::now();
        let mut counters = light.counters;
        counters.add(&camera.counters);
        TracedPass {
            index: p.index,
            odd: p.odd,
            camera,
            beams: light.beams,
            beam_map,
            beam_radius: p.beam_radius,
            counters,
            timings: Timings {
                light_tracing: (t1 - t0).as_secs_f64(),
                // What the maps add to the pass's time: the photon map, and the part of
                // the BVH's build the camera paths did not cover.
                build_maps: (t3 - t1).as_secs_f64() - camera_seconds,
                camera_paths: camera_seconds,
                beam_estimate: 0.0,
            },
        }
    }

    /// The beam estimate of a traced pass on the CPU alone (see [`cpu::beam_image`]).
    pub fn beam_image(&self, t: &TracedPass) -> (Vec<Rgb>, u64) {
        cpu::beam_image(self.view(), t)
    }

    /// What the beam estimate of any pass reads besides the pass.
    pub fn view(&self) -> View<'_> {
        View {
            camera: &self.camera,
            media: &self.media,
            kernel: self.settings.beam_kernel(self.media.anisotropy()),
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

/// The smooth beams' kernel radius over the pass's (the hybrid method's wider multiple
/// scattering; the paper's method has one radius).
fn smooth_beam_scale(method: Method) -> f32 {
    match method {
        Method::Hybrid => SMOOTH_BEAM_SCALE,
        Method::Ppb => 1.0,
    }
}
