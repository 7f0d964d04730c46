//! Camera paths: one jittered ray per pixel per pass, followed through specular surfaces
//! to the first diffuse hit. The diffuse hit gathers photons; every camera segment inside
//! media is recorded with its transmittance estimate and path weight, and the beam
//! estimate along all of them runs afterwards (on the CPU in `estimate::cpu`, or on the
//! GPU), so camera tracing and the beam estimate can overlap across passes.
use glam::{Mat4, Vec2, Vec3, Vec4};
use rayon::prelude::*;
use smallvec::SmallVec;

use super::direct::Direct;
use super::freepath::{FreePath, Walk};
use super::light::{enters_glass, LightSampler};
use super::transmittance::camera_tr;
use super::transmittance::{SegmentTr, StratPixel, StratStore};
use super::SurfaceEstimate;
use super::{timed, Counters};
use crate::bsdf;
use crate::core::Ray;
use crate::core::{Nested, Rgb};
use crate::geometry::{Geometry, Hit, EPS};
use crate::media::{Chords, Media};
use crate::sampling::{Rng, Stream};
use crate::scene::{Camera, Material};
use crate::settings::{TrMode, MAX_TR_BLOCK};

/// Longest chain of specular bounces a camera path follows.
pub const MAX_SPECULAR: u32 = 64;

/// Dielectric hits (per path) at which both Fresnel branches are followed.
pub const SPLIT_DEPTH: u32 = 2;

/// Where a camera path records its secondary segments, and its alpha (transparent film).
struct Out<'a> {
    pixel: u32,
    segments: &'a mut Vec<Secondary>,
    alpha: f32,
    /// The photon estimates' nested half-radius difference, weighted like their radiance.
    nested: Rgb,
}

#[derive(Clone, Copy)]
struct PathState {
    beta: Rgb,
    /// Specular bounces so far.
    depth: u32,
    in_glass: bool,
}

/// A ray leaving hit `h` along `dir`, offset to the side it leaves on.
fn leave(h: &crate::geometry::Hit, dir: Vec3) -> Ray {
    let off = if dir.dot(h.ng) > 0.0 { h.ng } else { -h.ng };
    Ray::new(h.p + off * EPS, dir)
}

/// Pinhole camera in the SPEC.md convention: pixel (0,0) top-left, vertical fov.
#[derive(Clone, Copy, Debug)]
pub struct Pinhole {
    origin: Vec3,
    right: Vec3,
    up: Vec3,
    forward: Vec3,
    tan_half: f32,
    width: u32,
    height: u32,
}

impl Pinhole {
    pub fn new(cam: &Camera, width: u32, height: u32) -> Self {
        let forward = (cam.target - cam.origin).normalize();
        let right = forward.cross(cam.up).normalize();
        let up = right.cross(forward);
        Pinhole {
            origin: cam.origin,
            right,
            up,
            forward,
            tan_half: (cam.vfov_deg.to_radians() * 0.5).tan(),
            width,
            height,
        }
    }

    /// Ray through continuous film position (px to the right, py downward).
    pub fn ray(&self, px: f32, py: f32) -> Ray {
        let aspect = self.width as f32 / self.height as f32;
        let x = (2.0 * px / self.width as f32 - 1.0) * self.tan_half * aspect;
        let y = (1.0 - 2.0 * py / self.height as f32) * self.tan_half;
        Ray::new(
            self.origin,
            (self.right * x + self.up * y + self.forward).normalize(),
        )
    }

    /// Bound on |(x, y)| / z of every ray through the film, in camera coordinates (its
    /// corners): a point at distance d from such a ray, at depth z, projects within
    /// sqrt(1 + bound^2) d of the ray's film position, in units of one pixel at depth z.
    pub fn film_slope_bound(&self) -> f32 {
        let aspect = self.width as f32 / self.height as f32;
        self.tan_half * (aspect * aspect + 1.0).sqrt()
    }

    /// Bound on the angle (radians) between two rays through one pixel: the diagonal's
    /// angle at the film's centre, where pixels subtend the most.
    pub fn pixel_diagonal(&self) -> f32 {
        std::f32::consts::SQRT_2 * 2.0 * self.tan_half / self.height as f32
    }

    /// World-space width of one pixel at distance `dist` along the view axis.
    pub fn pixel_footprint(&self, dist: f32) -> f32 {
        2.0 * dist * self.tan_half / self.height as f32
    }

    pub fn origin(&self) -> Vec3 {
        self.origin
    }

    pub fn width(&self) -> u32 {
        self.width
    }

    pub fn height(&self) -> u32 {
        self.height
    }

    /// Distance of `p` in front of the camera along the view axis.
    pub fn depth(&self, p: Vec3) -> f32 {
        (p - self.origin).dot(self.forward)
    }

    /// Continuous film position of a point in front of the camera (inverse of [`Self::ray`]).
    pub fn project(&self, p: Vec3) -> Vec2 {
        let v = p - self.origin;
        let z = v.dot(self.forward);
        let aspect = self.width as f32 / self.height as f32;
        let x = v.dot(self.right) / (z * self.tan_half * aspect);
        let y = v.dot(self.up) / (z * self.tan_half);
        Vec2::new(
            (x + 1.0) * 0.5 * self.width as f32,
            (1.0 - y) * 0.5 * self.height as f32,
        )
    }

    /// World to camera space (x right, y up, looking down -z), as a column-vector matrix.
    pub fn world_to_camera(&self) -> Mat4 {
        let (r, u, f, o) = (self.right, self.up, self.forward, self.origin);
        Mat4::from_cols(
            Vec4::new(r.x, u.x, -f.x, 0.0),
            Vec4::new(r.y, u.y, -f.y, 0.0),
            Vec4::new(r.z, u.z, -f.z, 0.0),
            Vec4::new(-r.dot(o), -u.dot(o), f.dot(o), 1.0),
        )
    }

    /// World to the camera's clip space (x and y in -1..1 across the image after the
    /// divide by w, y up; an infinite far plane, near 1 mm).
    pub fn world_to_ndc(&self) -> Mat4 {
        let aspect = self.width as f32 / self.height as f32;
        let f = 1.0 / self.tan_half;
        let projection = Mat4::from_cols(
            Vec4::new(f / aspect, 0.0, 0.0, 0.0),
            Vec4::new(0.0, f, 0.0, 0.0),
            Vec4::new(0.0, 0.0, -1.0, -1.0),
            Vec4::new(0.0, 0.0, -1e-3, 0.0),
        );
        projection * self.world_to_camera()
    }

    /// Pixels per metre for something at view depth `z`.
    pub fn pixels_per_unit_at(&self, z: f32) -> f32 {
        self.height as f32 / (2.0 * z * self.tan_half)
    }
}

/// The first segment of every pixel's camera path: its jittered direction and the
/// distance to the first surface (infinite if none).
#[derive(Clone, Debug)]
pub struct Primary {
    pub dir: Vec3,
    pub t_surf: f32,
    /// This pass's estimate of the grids' transmittance along the segment.
    pub tr: SegmentTr,
    /// The homogeneous media along the segment.
    pub chords: Chords,
}

impl Primary {
    /// A placeholder a pass's buffer starts with; every pixel overwrites its own.
    fn none() -> Primary {
        Primary {
            dir: Vec3::ZERO,
            t_surf: 0.0,
            tr: SegmentTr::Clear,
            chords: Chords::default(),
        }
    }
}

/// A camera segment after one or more specular bounces that runs through media.
#[derive(Clone, Debug)]
pub struct Secondary {
    pub pixel: u32,
    pub ray: Ray,
    pub t_surf: f32,
    /// Path weight (specular factors and transmittance up to the ray origin).
    pub beta: Rgb,
    pub tr: SegmentTr,
    /// The homogeneous media along the segment.
    pub chords: Chords,
}

/// One pass of camera paths, before the beam estimate.
pub struct CameraPass {
    /// Radiance of every pixel except the beam estimate (emitters, photons).
    pub image: Vec<Rgb>,
    /// The photon estimates' nested half-radius difference per pixel.
    pub nested: Vec<Rgb>,
    /// Alpha of every pixel with a transparent film (else empty).
    pub alpha: Vec<f32>,
    /// One per pixel, row-major.
    pub primaries: Vec<Primary>,
    /// In pixel order.
    pub secondary: Vec<Secondary>,
    pub counters: Counters,
}

/// Where a pass stands in its stratified-transmittance block (all from its index).
struct StratPlan {
    block: u32,
    /// Key of the cycle's random stream: block and cycle within it.
    cycle: u32,
    slot: usize,
    /// The store holds another block's paths: draw this one's.
    regenerate: bool,
    /// The strata are in another cycle's order: shuffle them into this one's.
    reshuffle: bool,
}

/// Strata per side of the pixel for the sphere lights seen directly.
const LIGHT_STRATA: u32 = 4;

/// The pixels whose footprint sees a sphere light directly (an 8x8 grid of rays, each to
/// its first surface), dilated by one pixel: the references' emitter masks.
pub fn light_pixels(camera: &Pinhole, geometry: &Geometry) -> Vec<u32> {
    const GRID: u32 = 8;
    let (w, h) = (camera.width, camera.height);
    let sees = |x: u32, y: u32| {
        let centre = camera.ray(x as f32 + 0.5, y as f32 + 0.5);
        geometry.lights_near(&centre, camera.pixel_diagonal())
            && (0..GRID * GRID).any(|k| {
                let (i, j) = ((k % GRID) as f32 + 0.5, (k / GRID) as f32 + 0.5);
                let ray = camera.ray(x as f32 + i / GRID as f32, y as f32 + j / GRID as f32);
                let t_surf = geometry
                    .intersect(&ray, f32::INFINITY)
                    .map_or(f32::INFINITY, |h| h.t);
                geometry.lights_seen(&ray, t_surf).next().is_some()
            })
    };
    let seen: Vec<(u32, u32)> = (0..w * h)
        .into_par_iter()
        .filter_map(|i| sees(i % w, i / w).then_some((i % w, i / w)))
        .collect();
    let mut out: Vec<u32> = seen
        .iter()
        .flat_map(|&(x, y)| {
            let (xs, ys) = (
                x.saturating_sub(1)..(x + 2).min(w),
                y.saturating_sub(1)..(y + 2).min(h),
            );
            ys.flat_map(move |v| xs.clone().map(move |u| v * w + u))
        })
        .collect();
    out.sort_unstable();
    out.dedup();
    out
}

/// Everything a camera pass reads.
pub struct CameraTracer<'a> {
    pub camera: &'a Pinhole,
    pub geometry: &'a Geometry,
    pub media: &'a Media,
    pub free_path: FreePath<'a>,
    /// Grid free paths per camera segment per pass (M).
    pub tr_samples: usize,
    pub tr_mode: TrMode,
    /// The scene's lights: what a path leaving the scene sees.
    pub lights: &'a LightSampler,
    /// Radiance stored on surfaces (the photon maps), gathered at diffuse hits.
    pub photons: &'a dyn SurfaceEstimate,
    /// Next-event estimation of direct light (the hybrid method), or None (pure PPB).
    pub direct: Option<Direct<'a>>,
    /// Transparent film: camera rays that leave the scene see no environment and give
    /// the pixel's alpha.
    pub transparent: bool,
}

impl CameraTracer<'_> {
    /// Camera paths of every pixel for one pass (row-major, top row first). `strat` holds
    /// the stratified free paths when that estimator is on.
    pub fn trace_pass(&self, seed: u64, pass: u32, strat: Option<&mut StratStore>) -> CameraPass {
        let (w, h) = (self.camera.width as usize, self.camera.height as usize);
        // Stratified blocks of N passes keep each pixel's jitter (and so its free paths)
        // for the whole block; what pass `pass` picks depends on its index alone.
        let (plan, mut rows_mut) = match strat {
            Some(st) => {
                let n = st.n as u32;
                let block = (pass - 1) / n;
                let q = st.cycle() as u32;
                let cycle = block * MAX_TR_BLOCK as u32 + (pass - 1) % n / q;
                let plan = StratPlan {
                    block,
                    cycle,
                    slot: ((pass - 1) % q) as usize,
                    regenerate: st.block != Some(block),
                    reshuffle: st.cycle != Some(cycle),
                };
                st.block = Some(block);
                st.cycle = Some(cycle);
                (Some(plan), st.rows_mut(w).into_iter().map(Some).collect())
            }
            None => (None, Vec::new()),
        };
        rows_mut.resize_with(h, || None);
        let n = w * h;
        let mut image = vec![Rgb::ZERO; n];
        let mut nested = vec![Rgb::ZERO; n];
        let mut alpha = vec![0.0f32; n];
        let mut primaries: Vec<Primary> = (0..n).into_par_iter().map(|_| Primary::none()).collect();
        // Each row writes its pixels in place: a serial gathering of the rows after was a
        // few per cent of a 2-core pass's wall time.
        let rows: Vec<(Vec<Secondary>, Counters)> = image
            .par_chunks_mut(w)
            .zip(nested.par_chunks_mut(w))
            .zip(alpha.par_chunks_mut(w))
            .zip(primaries.par_chunks_mut(w))
            .zip(rows_mut)
            .enumerate()
            .map(
                |(y, ((((image, nested), alpha), primaries), mut row_store))| {
                    let mut c = Counters::default();
                    let mut secondary = Vec::new();
                    for x in 0..w {
                        let idx = (y * w + x) as u64;
                        let mut rng = Rng::for_path(seed, pass, Stream::Camera, idx);
                        let j = match &plan {
                            Some(p) => {
                                Rng::for_path(seed, p.block, Stream::CameraJitter, idx).vec2()
                            }
                            None => rng.vec2(),
                        };
                        let ray = self.camera.ray(x as f32 + j.x, y as f32 + j.y);
                        let strat = row_store.as_mut().zip(plan.as_ref()).map(|(paths, p)| {
                            let n = paths.len() / w;
                            StratPixel {
                                paths: &mut paths[x * n..(x + 1) * n],
                                regenerate: p.regenerate,
                                reshuffle: p.reshuffle,
                                block_rng: Rng::for_path(seed, p.block, Stream::TrBlock, idx),
                                cycle_rng: Rng::for_path(seed, p.cycle, Stream::TrCycle, idx),
                                slot: p.slot,
                            }
                        });
                        let mut out = Out {
                            pixel: idx as u32,
                            segments: &mut secondary,
                            alpha: 1.0,
                            nested: Rgb::ZERO,
                        };
                        (image[x], primaries[x]) =
                            self.radiance(ray, &mut rng, &mut c, strat, &mut out);
                        (alpha[x], nested[x]) = (out.alpha, out.nested);
                    }
                    (secondary, c)
                },
            )
            .collect();
        let mut pass = CameraPass {
            image,
            nested,
            alpha: if self.transparent { alpha } else { Vec::new() },
            primaries,
            secondary: Vec::new(),
            counters: Counters::default(),
        };
        for (secondary, c) in rows {
            pass.secondary.extend(secondary);
            pass.counters.add(&c);
        }
        pass
    }

    /// Radiance along one camera path except the beam estimates; returns its first
    /// segment and records the later ones in media into `out`.
    fn radiance(
        &self,
        ray: Ray,
        rng: &mut Rng,
        c: &mut Counters,
        strat: Option<StratPixel>,
        out: &mut Out,
    ) -> (Rgb, Primary) {
        c.camera_rays += 1;
        let mut primary = Primary {
            dir: ray.d,
            t_surf: f32::INFINITY,
            ..Primary::none()
        };
        let state = PathState {
            beta: Rgb::ONE,
            depth: 0,
            in_glass: false,
        };
        let l = self.follow(ray, state, rng, c, Some((&mut primary, strat)), out);
        (l, primary)
    }

    /// Follows a camera path from `ray`. At the first [`SPLIT_DEPTH`] dielectric hits both
    /// the reflected and the refracted branch are followed, weighted by F and 1 - F, which
    /// removes the noise of picking one (highlights of the light seen in glass). `first`
    /// (the primary segment to fill in and its stratified free paths) is given for the
    /// camera ray only.
    fn follow(
        &self,
        mut ray: Ray,
        mut st: PathState,
        rng: &mut Rng,
        c: &mut Counters,
        mut first: Option<(&mut Primary, Option<StratPixel>)>,
        out: &mut Out,
    ) -> Rgb {
        let mut l = Rgb::ZERO;
        while st.depth < MAX_SPECULAR {
            let hit = self.geometry.intersect(&ray, f32::INFINITY);
            let t_surf = hit.map_or(f32::INFINITY, |h| h.t);
            let primary = first.is_some();
            l += self.segment(&ray, t_surf, &mut st, first.take(), rng, c, out);
            let Some(h) = hit else {
                if primary && self.transparent {
                    // What is left of the camera ray shows the background behind.
                    out.alpha = 1.0 - st.beta.element_sum() / 3.0;
                } else {
                    l += st.beta * self.lights.background(ray.d);
                }
                break;
            };
            let material = h.material;
            if let Material::Lambert { reflectance } = material {
                // Nothing of the surface reaches the camera (an opaque transmittance
                // estimate): no photon lookup, no shadow ray.
                if st.beta.max_element() <= 0.0 {
                    break;
                }
                let lo = st.beta * self.diffuse(&h, ray.d, reflectance, rng, c);
                l += lo.l;
                out.nested += lo.d;
                break;
            }
            st.depth += 1;
            if st.depth <= SPLIT_DEPTH {
                if let Some(branches) = bsdf::split(&material, ray.d, h.ng, h.ns) {
                    for (dir, w) in branches.into_iter().flatten() {
                        let next = PathState {
                            beta: st.beta * w,
                            in_glass: enters_glass(&material, dir, h.ng),
                            ..st
                        };
                        l += self.follow(leave(&h, dir), next, rng, c, None, out);
                    }
                    break;
                }
            }
            let Some(b) = bsdf::sample(&material, ray.d, h.ng, h.ns, rng.f32(), Vec2::ZERO) else {
                break;
            };
            st.beta *= b.weight;
            st.in_glass = enters_glass(&material, b.dir, h.ng);
            ray = leave(&h, b.dir);
        }
        l
    }

    /// One camera segment [0, t_surf) of `ray`: its transmittance estimate, direct light
    /// along it (NEE) and from the sphere lights it passes, its record for the beam
    /// estimate (`first`'s primary, or a secondary in `out`), and the path weight
    /// attenuated to its end. Returns the light it adds.
    #[allow(clippy::too_many_arguments)]
    fn segment(
        &self,
        ray: &Ray,
        t_surf: f32,
        st: &mut PathState,
        first: Option<(&mut Primary, Option<StratPixel>)>,
        rng: &mut Rng,
        c: &mut Counters,
        out: &mut Out,
    ) -> Rgb {
        let (primary, strat) = match first {
            Some((p, s)) => (Some(p), s),
            None => (None, None),
        };
        let walks = self.walks(ray, t_surf, st.in_glass, c);
        let walks = walks.as_deref();
        let gtr = self.grid_transmittance(ray, t_surf, st.in_glass, walks, rng, c, strat);
        // A segment inside glass crosses no media (as for its walks and spans).
        let chords = if st.in_glass {
            Chords::default()
        } else {
            self.media.chords(ray)
        };
        // Media spans, wanted by NEE and by segments after a bounce (the beam BVH).
        let spans = if !st.in_glass && (self.direct.is_some() || primary.is_none()) {
            self.media.spans(ray, t_surf)
        } else {
            Default::default()
        };
        let mut l = Rgb::ZERO;
        if let (Some(d), false) = (&self.direct, spans.is_empty()) {
            let tr = |t| camera_tr(&chords, &gtr, t);
            l = st.beta * d.along(ray, t_surf, &spans, walks, tr, rng, c);
        }
        let beta = st.beta;
        if primary.is_some() {
            l += self.lights_in_pixel(out.pixel, rng, c);
        } else {
            for (t, le) in self.geometry.lights_seen(ray, t_surf) {
                let tr = if st.in_glass {
                    1.0
                } else {
                    camera_tr(&chords, &gtr, t)
                };
                l += beta * le * tr;
            }
        }
        // To the surface, or to infinity for a path that leaves the scene when a light
        // there (the environment) is what it will see.
        let reaches = t_surf.is_finite() || self.lights.at_infinity() || self.transparent;
        if !self.media.is_empty() && !st.in_glass && reaches {
            let tau = chords.optical_depth(t_surf);
            st.beta *= (-tau).exp() * gtr.eval(t_surf);
        }
        record(ray, t_surf, beta, gtr, chords, primary, &spans, out);
        l
    }

    /// The sphere lights seen directly across pixel `idx`, from [`LIGHT_STRATA`]^2 jittered
    /// rays over its footprint: with the camera ray alone, a pixel on a small light's rim
    /// would be a coin toss each pass, and such pixels can hold much of an image's sum.
    fn lights_in_pixel(&self, idx: u32, rng: &mut Rng, c: &mut Counters) -> Rgb {
        let (x, y) = (
            (idx % self.camera.width) as f32,
            (idx / self.camera.width) as f32,
        );
        let centre = self.camera.ray(x + 0.5, y + 0.5);
        if !self
            .geometry
            .lights_near(&centre, self.camera.pixel_diagonal())
        {
            return Rgb::ZERO;
        }
        let n = LIGHT_STRATA;
        let mut l = Rgb::ZERO;
        for k in 0..n * n {
            let (i, j) = ((k % n) as f32, (k / n) as f32);
            let u = rng.vec2();
            let ray = self
                .camera
                .ray(x + (i + u.x) / n as f32, y + (j + u.y) / n as f32);
            let t_surf = self
                .geometry
                .intersect(&ray, f32::INFINITY)
                .map_or(f32::INFINITY, |h| h.t);
            for (t, le) in self.geometry.lights_seen(&ray, t_surf) {
                l += le * self.free_path.transmittance(&ray, t, rng, c);
            }
        }
        l / (n * n) as f32
    }

    /// Radiance leaving a diffuse hit towards the camera: the photon maps' estimate (with
    /// its nested difference) plus, in the hybrid method, direct light by a shadow ray.
    fn diffuse(
        &self,
        h: &Hit,
        dir: Vec3,
        reflectance: Rgb,
        rng: &mut Rng,
        c: &mut Counters,
    ) -> Nested {
        let n = if dir.dot(h.ng) < 0.0 { h.ng } else { -h.ng };
        let mut lo = self
            .photons
            .radiance(h.p, n, reflectance, &mut c.photon_lookups);
        if let Some(d) = &self.direct {
            lo.l += d.at_surface(h.p, n, reflectance, rng, c);
        }
        lo
    }

    /// The grids' octree walks along a camera segment in media, made once for the two
    /// users that read the same leaves: ratio tracking (at M times the majorant) and next-event
    /// estimation's distances by the majorant (lights with no position). Timed as
    /// transmittance, which they serve first.
    fn walks(
        &self,
        ray: &Ray,
        t_surf: f32,
        in_glass: bool,
        c: &mut Counters,
    ) -> Option<SmallVec<[Walk; 1]>> {
        let ratio = matches!(self.tr_mode, TrMode::Ratio | TrMode::March);
        let nee = self
            .direct
            .as_ref()
            .is_some_and(|d| d.lights.any_unplaced());
        if in_glass || !(ratio || nee) || !self.media.crosses_grids(ray, t_surf) {
            return None;
        }
        let (mut tick, mut secs) = (c.timing_ticks, c.transmittance_seconds);
        let walks = timed(&mut tick, &mut secs, || {
            self.free_path.walks(ray, t_surf, c)
        });
        (c.timing_ticks, c.transmittance_seconds) = (tick, secs);
        Some(walks)
    }

    /// The grid part of the transmittance along a camera segment (clear when the segment
    /// misses every grid or runs inside glass), ratio tracking over the segment's `walks`.
    #[allow(clippy::too_many_arguments)]
    fn grid_transmittance(
        &self,
        ray: &Ray,
        t_surf: f32,
        in_glass: bool,
        walks: Option<&[Walk]>,
        rng: &mut Rng,
        c: &mut Counters,
        strat: Option<StratPixel>,
    ) -> SegmentTr {
        if in_glass || !self.media.crosses_grids(ray, t_surf) {
            return SegmentTr::Clear;
        }
        let (fp, m) = (&self.free_path, self.tr_samples);
        let (mut tick, mut secs) = (c.timing_ticks, c.transmittance_seconds);
        let tr = timed(&mut tick, &mut secs, || {
            match (self.tr_mode, strat, walks) {
                (TrMode::Ratio, _, Some(walks)) => SegmentTr::ratio_over(fp, ray, walks, m, rng, c),
                (TrMode::Ratio, _, None) => SegmentTr::ratio(fp, ray, t_surf, m, rng, c),
                (TrMode::March, _, Some(walks)) => SegmentTr::Ratio(
                    crate::transport::march::march_steps(fp, ray, walks, m, rng, c),
                ),
                (TrMode::Stratified, Some(mut px), _) => px.pick(fp, ray, t_surf, m, c),
                _ => SegmentTr::random(fp, ray, t_surf, m, rng, c),
            }
        });
        (c.timing_ticks, c.transmittance_seconds) = (tick, secs);
        tr
    }
}

/// Keeps a segment for the beam estimate: the primary's distance and transmittance, or
/// a secondary (with `beta`, the weight at its origin) when it crosses media.
#[allow(clippy::too_many_arguments)]
fn record(
    ray: &Ray,
    t_surf: f32,
    beta: Rgb,
    tr: SegmentTr,
    chords: Chords,
    primary: Option<&mut Primary>,
    spans: &[(f32, f32)],
    out: &mut Out,
) {
    if let Some(p) = primary {
        p.t_surf = t_surf;
        p.tr = tr;
        p.chords = chords;
    } else if !spans.is_empty() {
        out.segments.push(Secondary {
            pixel: out.pixel,
            ray: *ray,
            t_surf,
            beta,
            tr,
            chords,
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The EXR header's matrices put a point where the camera's projection does: in front
    /// (negative z in camera space), at the same film position.
    #[test]
    fn header_matrices_match_the_projection() {
        let cam = Camera {
            origin: Vec3::new(1.0, 2.0, 5.0),
            target: Vec3::new(0.0, 0.5, 0.0),
            up: Vec3::Y,
            vfov_deg: 35.0,
        };
        let pin = Pinhole::new(&cam, 160, 90);
        let p = Vec3::new(0.3, 0.9, -0.4);
        let c = pin.world_to_camera().transform_point3(p);
        assert!((c.z + pin.depth(p)).abs() < 1e-5);
        let clip = pin.world_to_ndc() * p.extend(1.0);
        let ndc = clip.truncate().truncate() / clip.w;
        let film = pin.project(p);
        let want = Vec2::new(film.x / 160.0 * 2.0 - 1.0, 1.0 - film.y / 90.0 * 2.0);
        assert!((ndc - want).length() < 1e-5, "{ndc} vs {want}");
    }

    /// SPEC.md: looking down -Z from +Z with up +Y, world +X is on the right of the image,
    /// +Y in the upper half (row 0 at the top), and the field of view is vertical.
    #[test]
    fn camera_convention() {
        let cam = Camera {
            origin: Vec3::new(0.0, 0.0, 5.0),
            target: Vec3::ZERO,
            up: Vec3::Y,
            vfov_deg: 40.0,
        };
        let p = Pinhole::new(&cam, 200, 100);
        let right = p.project(Vec3::new(1.0, 0.0, 0.0));
        assert!(right.x > 100.0 && (right.y - 50.0).abs() < 1e-3);
        let up = p.project(Vec3::new(0.0, 0.5 * 20f32.to_radians().tan() * 5.0, 0.0));
        assert!((up.y - 25.0).abs() < 1e-3, "{up}");
        let r = p.ray(37.25, 81.5);
        let back = p.project(r.at(3.0));
        assert!((back - Vec2::new(37.25, 81.5)).length() < 1e-3);
    }
}
