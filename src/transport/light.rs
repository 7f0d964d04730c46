//! Light tracing: paths from the lights, chosen by power, stored as beams in media and as
//! photons on Lambert surfaces.
use glam::Vec3;
use rayon::prelude::*;

use super::emitters::Emission;
use super::freepath::FreePath;
use super::{timed, Beam, Counters, Photon, MAX_DEPTH};
use crate::bsdf;
use crate::core::Ray;
use crate::core::Rgb;
use crate::geometry::{Geometry, EPS};
use crate::media::{Media, Support};
use crate::sampling::{Discrete, Rng, Stream};
use crate::scene::{Light, Material};
use crate::settings::SMOOTH_BEAM_AFTER;

/// Lights with a discrete distribution proportional to their power.
pub struct LightSampler {
    lights: Vec<Light>,
    /// By power; None when no light emits.
    by_power: Option<Discrete>,
    /// Sphere bounding everything a directional light must cover.
    scene_center: Vec3,
    scene_radius: f32,
}

impl LightSampler {
    pub fn new(lights: &[Light], scene_bounds: [Vec3; 2]) -> Self {
        let scene_center = 0.5 * (scene_bounds[0] + scene_bounds[1]);
        let scene_radius = 0.5 * (scene_bounds[1] - scene_bounds[0]).length() * 1.01 + 1e-3;
        let by_power = Discrete::new(
            lights
                .iter()
                .map(|l| l.power(scene_radius).element_sum() as f64),
        );
        LightSampler {
            lights: lights.to_vec(),
            by_power,
            scene_center,
            scene_radius,
        }
    }

    pub fn total_power(&self) -> Rgb {
        self.lights
            .iter()
            .map(|l| l.power(self.scene_radius))
            .fold(Vec3::ZERO, |a, b| a + b)
    }

    /// Whether a light has no position (directional, environment): next-event estimation
    /// then samples distances along a segment by the media's majorant.
    pub fn any_unplaced(&self) -> bool {
        self.lights.iter().any(|l| l.anchor().is_none())
    }

    /// Whether a ray leaving the scene sees any light (an environment).
    pub fn at_infinity(&self) -> bool {
        self.lights.iter().any(Light::is_background)
    }

    /// Radiance a ray leaving the scene along `dir` sees: the lights at infinity.
    pub fn background(&self, dir: Vec3) -> Rgb {
        self.lights.iter().map(|l| l.background(dir)).sum()
    }

    /// A light chosen by power from `u` in [0, 1), with the probability of choosing it.
    pub fn pick(&self, u: f32) -> Option<(&Light, f32)> {
        let (idx, prob, _) = self.by_power.as_ref()?.sample(u);
        Some((&self.lights[idx], prob))
    }

    /// Picks a light by power and samples a photon from it, carrying power / pdf.
    pub fn emit(&self, rng: &mut Rng) -> Option<Emission> {
        let (light, prob) = self.pick(rng.f32())?;
        let u1 = rng.vec2();
        let u2 = rng.vec2();
        let e = light.emit(self.scene_center, self.scene_radius, u1, u2);
        Some(Emission {
            power: e.power / prob,
            ..e
        })
    }
}

/// What light tracing needs to know about the scene.
pub struct LightTracer<'a> {
    pub lights: &'a LightSampler,
    pub geometry: &'a Geometry,
    pub media: &'a Media,
    /// Where the media scatter light, for the beams' stretches ([`Media::supported_spans`]).
    pub support: &'a Support,
    pub free_path: FreePath<'a>,
    /// The pass's beam radius (m): how far a beam reaches past each medium boundary it
    /// crosses (see [`LightTracer::store_beams`]).
    pub beam_radius: f32,
    /// Kernel radius of the smooth beams over `beam_radius` (1: one radius for all).
    pub smooth_beam_scale: f32,
    /// Leave out what next-event estimation covers (the hybrid method): the beams of a
    /// path's first segment and the photons it ends in, before any scattering or
    /// specular event.
    pub skip_direct: bool,
}

/// One pass worth of light-path records.
#[derive(Default)]
pub struct LightPass {
    pub beams: Vec<Beam>,
    pub photons: Vec<Photon>,
    pub counters: Counters,
}

/// A hop between two collisions shorter than this many reaches is stored whole (see
/// [`LightTracer::store_beams`]): below 2, with a margin for the rounding of the media's
/// distance bounds.
const SHORT_HOP: f32 = 1.9;

/// Paths per rayon task: small tasks balance well, and each keeps its own output.
const CHUNK: usize = 512;

impl LightTracer<'_> {
    /// Traces `n` light paths for `pass`; the output order and values depend only on
    /// (seed, pass), never on the thread count.
    pub fn trace_pass(&self, seed: u64, pass: u32, n: usize) -> LightPass {
        let chunks: Vec<LightPass> = (0..n.div_ceil(CHUNK))
            .into_par_iter()
            .map(|c| {
                let mut out = LightPass::default();
                for i in c * CHUNK..((c + 1) * CHUNK).min(n) {
                    let mut rng = Rng::for_path(seed, pass, Stream::Light, i as u64);
                    self.trace_path(&mut rng, 1.0 / n as f32, &mut out);
                }
                out
            })
            .collect();
        let mut all = LightPass::default();
        all.beams
            .reserve(chunks.iter().map(|c| c.beams.len()).sum());
        all.photons
            .reserve(chunks.iter().map(|c| c.photons.len()).sum());
        for c in chunks {
            all.beams.extend_from_slice(&c.beams);
            all.photons.extend_from_slice(&c.photons);
            all.counters.add(&c.counters);
        }
        all
    }

    fn trace_path(&self, rng: &mut Rng, scale: f32, out: &mut LightPass) {
        out.counters.light_paths += 1;
        let Some(e) = self.lights.emit(rng) else {
            return;
        };
        let mut ray = Ray::new(e.origin, e.dir);
        let mut power = e.power * scale;
        // Inside a dielectric the path sees no medium (glass interiors are clear).
        let mut in_glass = false;
        // Whether the path still runs straight from the light (what NEE covers).
        let mut direct = self.skip_direct;
        // How often the path has scattered diffusely or in a medium: its photons are smooth
        // from the first, its beams from SMOOTH_BEAM_AFTER on.
        let mut scatterings = 0u32;
        // Whether the ray starts at a real collision in a medium (extinction there > 0).
        let mut from_collision = false;
        for _ in 0..MAX_DEPTH {
            let hit = self.geometry.intersect(&ray, f32::INFINITY);
            let t_surf = hit.map_or(f32::INFINITY, |h| h.t);
            let collision = if self.media.is_empty() || in_glass {
                None
            } else {
                let cn = &mut out.counters;
                let (mut tick, mut secs) = (cn.timing_ticks, cn.free_path_seconds);
                let c = timed(&mut tick, &mut secs, || {
                    self.free_path.sample(&ray, t_surf, rng, cn)
                });
                (cn.timing_ticks, cn.free_path_seconds) = (tick, secs);
                c
            };
            let t_end = collision.unwrap_or(t_surf);
            if !in_glass && !direct {
                let scale = if scatterings >= SMOOTH_BEAM_AFTER {
                    self.smooth_beam_scale
                } else {
                    1.0
                };
                let between = from_collision && collision.is_some();
                self.store_beams(&ray, t_end, power, scale, between, out);
            }
            if let Some(t) = collision {
                let p = ray.at(t);
                let Some((albedo, phase)) = self.media.pick_collider(p, rng.f32()) else {
                    return;
                };
                let q = albedo.max_element().min(1.0);
                if q <= 0.0 || rng.f32() >= q {
                    return;
                }
                power *= albedo / q;
                direct = false;
                scatterings += 1;
                let (u1, u2) = (rng.f32(), rng.f32());
                ray = Ray::new(p, phase.sample(ray.d, u1, u2));
                from_collision = true;
                continue;
            }
            let Some(h) = hit else { return };
            let material = h.material;
            let side = if ray.d.dot(h.ng) < 0.0 { h.ng } else { -h.ng };
            if let Material::Lambert { .. } = material {
                if !direct {
                    out.photons
                        .push(Photon::new(h.p, side, power, scatterings > 0));
                    out.counters.photons += 1;
                }
                scatterings += 1;
            }
            direct = false;
            let (u, u2) = (rng.f32(), rng.vec2());
            let Some(b) = bsdf::sample(&material, ray.d, h.ng, h.ns, u, u2) else {
                return;
            };
            let q = b.weight.max_element().min(1.0);
            if q <= 0.0 || rng.f32() >= q {
                return;
            }
            power *= b.weight / q;
            in_glass = enters_glass(&material, b.dir, h.ng);
            let off = if b.dir.dot(h.ng) > 0.0 { h.ng } else { -h.ng };
            ray = Ray::new(h.p + off * EPS, b.dir);
            from_collision = false;
        }
    }

    /// Stores the ray's stretches in media up to `t_end` with kernels `scale` times the
    /// pass's radius, each reaching up to its radius past the medium boundaries it crosses
    /// (never before the ray's origin nor past `t_end`). The kernel of eq. 2 reaches a beam's points within the
    /// radius of a camera point, so a camera point just inside a face would otherwise
    /// average the fluence with the empty outside and lose up to half of it (a bias of order
    /// r at every face a view ray crosses). Outside the media the path's fluence is the same
    /// as at the face (nothing attenuates it), and camera points there have sigma_s = 0, so
    /// the extension removes that bias and adds nothing else. Beams that pass just outside
    /// a face without crossing it are not stored, so a bias of order r remains there
    /// (`tests/environment.rs` measures it).
    ///
    /// `between` says the ray runs from one real collision in a medium to another: both
    /// ends have extinction, so a stretch no longer than twice the reach lies wholly within
    /// the reach of one of them and is stored whole without asking the media (the answer
    /// would be that one span: in a thick cloud most beams are such short hops).
    fn store_beams(
        &self,
        ray: &Ray,
        t_end: f32,
        power: Rgb,
        scale: f32,
        between: bool,
        out: &mut LightPass,
    ) {
        let reach = self.beam_radius * scale;
        if between && t_end < SHORT_HOP * reach {
            out.beams
                .push(Beam::new(ray.o, ray.d, t_end, power).scaled(scale));
            out.counters.beams += 1;
            return;
        }
        for (a, b) in self.media.supported_spans(self.support, ray, t_end, reach) {
            out.beams
                .push(Beam::new(ray.at(a), ray.d, b - a, power).scaled(scale));
            out.counters.beams += 1;
        }
    }
}

/// Whether a path leaving a surface along `dir` travels inside a dielectric: meshes are
/// closed with outward normals (CCW from outside), so that is a dielectric left on the
/// side opposite its normal. Opaque surfaces always send the path back outside.
pub fn enters_glass(material: &Material, dir: Vec3, ng: Vec3) -> bool {
    matches!(material, Material::Dielectric { .. }) && dir.dot(ng) < 0.0
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::majorant::Mode;
    use crate::media::{MediumDesc, Phase};
    use crate::scene::Scene;

    /// A path's beams are sharp (scale 1) until it has scattered SMOOTH_BEAM_AFTER times,
    /// then smooth. One path per pass inside a fog far larger than any path, so each of
    /// its segments is one beam, stored in order: SMOOTH_BEAM_AFTER scales 1, then s.
    #[test]
    fn beams_turn_smooth_after_enough_scatterings() {
        let medium = MediumDesc {
            bounds: [Vec3::splat(-1e4), Vec3::splat(1e4)],
            sigma_t: 1.0,
            albedo: Vec3::splat(0.9),
            phase: Phase::ISOTROPIC,
        };
        let light = Light::Point {
            position: Vec3::ZERO,
            intensity: Vec3::ONE,
        };
        let scene = Scene {
            lights: vec![light],
            media: vec![medium.clone()],
            ..Default::default()
        };
        let media = Media::new(vec![medium]);
        let geometry = Geometry::new(&scene).unwrap();
        let lights = LightSampler::new(&scene.lights, [Vec3::splat(-1.0), Vec3::ONE]);
        let tracer = LightTracer {
            lights: &lights,
            geometry: &geometry,
            media: &media,
            support: &media.support(1.0),
            free_path: FreePath {
                media: &media,
                mode: Mode::Woodcock,
            },
            beam_radius: 0.01,
            smooth_beam_scale: 3.0,
            skip_direct: false,
        };
        let mut smooth = 0;
        for pass in 1..=300 {
            let scales: Vec<f32> = tracer
                .trace_pass(7, pass, 1)
                .beams
                .iter()
                .map(|b| b.scale)
                .collect();
            let after = SMOOTH_BEAM_AFTER as usize;
            for (k, &s) in scales.iter().enumerate() {
                assert_eq!(
                    s,
                    if k < after { 1.0 } else { 3.0 },
                    "pass {pass}: {scales:?}"
                );
            }
            smooth += scales.len().saturating_sub(after);
        }
        // With albedo 0.9 a path scatters 9 times on average: most beams are smooth.
        assert!(smooth > 1000, "{smooth} smooth beams");
    }

    /// A hop between two real collisions shorter than [`SHORT_HOP`] reaches is what the
    /// media would answer for it: one span, the whole hop, so storing it whole changes
    /// no beam. Hops between free-path collisions in the noise smoke (axis-aligned and
    /// rotated), partly inside a fog box, and in a second fog box 0.8 m off the smoke's
    /// box, at reaches up to the support's. Longer hops (across the gap) do get cut, so
    /// the property is not true of any hop.
    #[test]
    fn short_hops_between_collisions_are_one_span() {
        use crate::majorant::octree::tests::noise_medium;
        use crate::sampling::uniform_sphere;
        for rotate in [false, true] {
            let fog = MediumDesc {
                bounds: [Vec3::new(-1.0, 0.0, -1.0), Vec3::new(0.0, 1.0, 0.0)],
                sigma_t: 3.0,
                albedo: Vec3::ONE,
                phase: Phase::ISOTROPIC,
            };
            let far_fog = MediumDesc {
                bounds: [Vec3::new(1.8, 0.0, -1.0), Vec3::new(2.8, 2.0, 1.0)],
                ..fog
            };
            let media = Media::bake(vec![fog, far_fog], &[noise_medium(rotate)], 6);
            let max_reach = 0.25;
            let support = media.support(max_reach);
            let free_path = FreePath {
                media: &media,
                mode: Mode::Adaptive,
            };
            let mut rng = Rng::new(21, u64::from(rotate));
            let mut c = Counters::default();
            let (mut short, mut cut) = (0u32, 0u32);
            for _ in 0..40_000 {
                let o = Vec3::new(
                    rng.f32() * 3.8 - 1.0,
                    rng.f32() * 2.0,
                    rng.f32() * 2.0 - 1.0,
                );
                let d = uniform_sphere(rng.vec2());
                let Some(t) = free_path.sample(&Ray::new(o, d), f32::INFINITY, &mut rng, &mut c)
                else {
                    continue;
                };
                let hop = Ray::new(o + d * t, uniform_sphere(rng.vec2()));
                let Some(t_end) = free_path.sample(&hop, f32::INFINITY, &mut rng, &mut c) else {
                    continue;
                };
                let reach = max_reach * (0.1 + 0.9 * rng.f32());
                let spans = media.supported_spans(&support, &hop, t_end, reach);
                let whole = spans.len() == 1 && spans[0] == (0.0, t_end);
                if t_end < SHORT_HOP * reach {
                    assert!(whole, "{hop:?} to {t_end}, reach {reach}: {spans:?}");
                    short += 1;
                } else if !whole {
                    cut += 1;
                }
            }
            assert!(
                short > 5000 && cut > 100,
                "rotate {rotate}: {short} short hops, {cut} cut"
            );
        }
    }
}
