//! The WGSL free-path sampler (`shaders/freepath.wgsl`) against the CPU's
//! (`transport::freepath::FreePath`): the same distributions (two-sample KS), ratio
//! tracking's mean against quadrature and its consistency along a ray, and the same octree
//! leaves walked. Seeds are fixed; tolerances come from the variance. Without an adapter
//! these tests print why they skip, unless PPB_REQUIRE_GPU=1.
mod common;

use std::path::Path;
use std::sync::Arc;

use common::gpu_or_skip;
use glam::{DAffine3, IVec3, Vec3};
use ppb::core::Ray;
use ppb::gpu::freepath::{FpRay, GpuFreePaths};
use ppb::majorant::Mode;
use ppb::media::grid::GridBuilder;
use ppb::media::{GridMedium, Heterogeneous, Media, Phase};
use ppb::sampling::Rng;
use ppb::scene::toml::load;
use ppb::transport::freepath::FreePath;
use ppb::transport::Counters;

/// 20^3 voxels of (i / 19) x (1 to 2 by (j + k) mod 3), 0.1 m apart, sigma_t = 2 density
/// (the ramp of the transmittance tests).
fn ramp_media() -> Media {
    Media::with_grids(vec![], vec![ramp_grid(0.0, 2.0)])
}

/// The ramp grid shifted by `dx` (m) along x, with sigma_t = `scale` density.
fn ramp_grid(dx: f64, scale: f32) -> Heterogeneous {
    let xf = DAffine3::from_translation(glam::DVec3::new(dx, 0.0, 0.0))
        * DAffine3::from_scale(glam::DVec3::splat(0.1));
    let mut b = GridBuilder::new("density", 0.0, xf);
    for i in 0..20 {
        for j in 0..20 {
            for k in 0..20 {
                let v = (i as f32 / 19.0) * (1.0 + 0.5 * ((j + k) % 3) as f32);
                b.set(IVec3::new(i, j, k), v, true);
            }
        }
    }
    let g = GridMedium::new(
        Arc::new(b.finish()),
        DAffine3::IDENTITY,
        scale,
        Vec3::ONE,
        Phase::ISOTROPIC,
        "ramp".into(),
        [0; 32],
    );
    Heterogeneous::build(g, 5)
}

/// Two overlapping grids (extinctions add): the nearest collision over grids, later grids
/// tracked up to the nearest so far, a stream per grid.
fn two_ramps() -> Media {
    Media::with_grids(vec![], vec![ramp_grid(0.0, 1.2), ramp_grid(0.9, 0.8)])
}

fn ramp_ray() -> (Ray, f32) {
    let ray = Ray::new(
        Vec3::new(-0.5, 0.93, 1.02),
        Vec3::new(1.0, 0.05, 0.02).normalize(),
    );
    (ray, 3.0)
}

/// The cloud-hg conformance grid (OpenVDB with tiles), octrees baked as a render would,
/// and a ray from the camera through the middle of the cloud.
fn cloud_media() -> (Media, Ray, f32) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/conformance/cloud-hg/scene.toml");
    let file = load(&path).expect("cloud-hg loads");
    let media = Media::bake(vec![], &file.scene.grid_media, file.settings.octree_depth);
    let [lo, hi] = media.bounds().expect("the cloud has bounds");
    let o = Vec3::new(0.0, 1.0, 5.0);
    let target = 0.5 * (lo + hi) + Vec3::new(0.05, 0.02, 0.0);
    (media, Ray::new(o, (target - o).normalize()), 10.0)
}

fn fp_ray(ray: &Ray, tmax: f32, seed: u32) -> FpRay {
    FpRay {
        origin: ray.o.into(),
        tmax,
        dir: ray.d.into(),
        seed,
    }
}

/// Two-sample Kolmogorov-Smirnov statistic (escapes are +inf: a jump at the end).
fn ks2(a: &mut [f32], b: &mut [f32]) -> f64 {
    a.sort_by(f32::total_cmp);
    b.sort_by(f32::total_cmp);
    let (na, nb) = (a.len() as f64, b.len() as f64);
    let (mut i, mut j, mut d) = (0, 0, 0.0f64);
    while i < a.len() && j < b.len() {
        let x = a[i].min(b[j]);
        while i < a.len() && a[i] == x {
            i += 1;
        }
        while j < b.len() && b[j] == x {
            j += 1;
        }
        d = d.max((i as f64 / na - j as f64 / nb).abs());
    }
    d
}

/// GPU free paths (k per ray on one ray) against the CPU's `sample_grids`: KS D below the
/// 0.1 % critical value 1.95 sqrt(2/n), and lookups per path within 10 %.
fn free_paths_match(media: &Media, ray: &Ray, tmax: f32, mode: Mode, label: &str) {
    let Some(g) = gpu_or_skip(label) else {
        return;
    };
    let n = 20_000usize;
    let mut gpu = GpuFreePaths::new(g, media).expect("gpu free paths");
    let start = std::time::Instant::now();
    let got = gpu
        .free_paths(&[fp_ray(ray, tmax, 7)], n as u32, mode)
        .expect("free paths");
    let gpu_s = start.elapsed().as_secs_f64();
    assert_eq!(got.len(), n);
    let mut a: Vec<f32> = got.iter().map(|s| s.t.unwrap_or(f32::INFINITY)).collect();
    let fp = FreePath { media, mode };
    let mut rng = Rng::new(11, 3);
    let mut c = Counters::default();
    let start = std::time::Instant::now();
    let mut b: Vec<f32> = (0..n)
        .map(|_| {
            fp.sample_grids(ray, tmax, &mut rng, &mut c)
                .unwrap_or(f32::INFINITY)
        })
        .collect();
    let cpu_s = start.elapsed().as_secs_f64();
    assert!(a.iter().all(|&t| t.is_infinite() || (t > 0.0 && t < tmax)));
    let escaped = a.iter().filter(|t| t.is_infinite()).count();
    let d = ks2(&mut a, &mut b);
    let crit = 1.95 * (2.0 / n as f64).sqrt();
    let gpu_lookups = got.iter().map(|s| s.lookups as f64).sum::<f64>() / n as f64;
    let cpu_lookups = c.density_lookups as f64 / n as f64;
    eprintln!(
        "{label} {mode:?}: KS D {d:.4} (critical {crit:.4}), {escaped} of {n} escaped, \
         lookups per path GPU {gpu_lookups:.3} CPU {cpu_lookups:.3}, \
         {gpu_s:.3} s GPU (batch, with upload and readback) vs {cpu_s:.3} s CPU (one thread)"
    );
    assert!(d < crit, "{label} {mode:?}: KS D {d} >= {crit}");
    assert!(
        (gpu_lookups - cpu_lookups).abs() <= 0.1 * cpu_lookups + 0.05,
        "{label} {mode:?}: lookups {gpu_lookups} vs {cpu_lookups}"
    );
}

#[test]
fn free_paths_match_cpu_on_ramp() {
    let media = ramp_media();
    let (ray, tmax) = ramp_ray();
    for mode in [Mode::Adaptive, Mode::Woodcock] {
        free_paths_match(&media, &ray, tmax, mode, "ramp");
    }
}

#[test]
fn free_paths_match_cpu_through_two_grids() {
    let media = two_ramps();
    let (ray, _) = ramp_ray();
    for mode in [Mode::Adaptive, Mode::Woodcock] {
        free_paths_match(&media, &ray, 4.0, mode, "two ramps");
    }
}

#[test]
fn free_paths_match_cpu_on_cloud_hg() {
    let (media, ray, tmax) = cloud_media();
    for mode in [Mode::Adaptive, Mode::Woodcock] {
        free_paths_match(&media, &ray, tmax, mode, "cloud-hg");
    }
}

/// Midpoint quadrature of the grids' transmittance on [0, t] (30 000 steps).
fn quad_tr(media: &Media, ray: &Ray, t: f32) -> f64 {
    let n = 30_000;
    let h = t as f64 / n as f64;
    let tau: f64 = (0..n)
        .map(|i| media.grid_sigma_t(ray.at(((i as f64 + 0.5) * h) as f32)) as f64 * h)
        .sum();
    (-tau).exp()
}

/// ratio_tr_to's mean over seeds against quadrature (within 5 measured standard errors)
/// at several t, and per seed a consistent realization: non-increasing in t, and equal
/// wherever no tentative collision (counted by the lookups) lies between two distances.
fn ratio_matches(media: &Media, ray: &Ray, dists: &[f32], mode: Mode, label: &str) {
    let Some(g) = gpu_or_skip(label) else {
        return;
    };
    let n = 20_000u32;
    let mut gpu = GpuFreePaths::new(g, media).expect("gpu free paths");
    let tmax = *dists.last().unwrap();
    let rays: Vec<FpRay> = (0..n).map(|s| fp_ray(ray, tmax, s)).collect();
    let all: Vec<f32> = (0..n).flat_map(|_| dists.iter().copied()).collect();
    let got = gpu.ratio_tr(&rays, &all, mode).expect("ratio estimates");
    let m = dists.len();
    for (j, &t) in dists.iter().enumerate() {
        let v: Vec<f64> = (0..n as usize).map(|r| got[r * m + j].tr as f64).collect();
        let mean = v.iter().sum::<f64>() / n as f64;
        let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n as f64 - 1.0);
        let se = (var / n as f64).sqrt();
        let truth = quad_tr(media, ray, t);
        eprintln!(
            "{label} {mode:?} t={t}: mean {mean:.5} vs quadrature {truth:.5} \
             ({:.2} standard errors, se {se:.2e})",
            (mean - truth) / se.max(1e-12)
        );
        assert!(
            (mean - truth).abs() < 5.0 * se + 1e-4,
            "{label} {mode:?} t={t}: {mean} vs {truth} (se {se})"
        );
    }
    for r in 0..n as usize {
        let row = &got[r * m..(r + 1) * m];
        for w in row.windows(2) {
            assert!(w[1].tr <= w[0].tr, "{label} seed {r}: {row:?}");
            assert!(w[1].lookups >= w[0].lookups, "{label} seed {r}: {row:?}");
            if w[1].lookups == w[0].lookups {
                assert_eq!(w[1].tr.to_bits(), w[0].tr.to_bits(), "{label} seed {r}");
            }
        }
    }
}

#[test]
fn ratio_tracking_matches_quadrature_on_ramp() {
    let media = ramp_media();
    let (ray, _) = ramp_ray();
    for mode in [Mode::Adaptive, Mode::Woodcock] {
        ratio_matches(&media, &ray, &[0.8, 1.2, 1.6, 2.0, 2.4, 3.0], mode, "ramp");
    }
}

#[test]
fn ratio_tracking_matches_quadrature_through_two_grids() {
    let media = two_ramps();
    let (ray, _) = ramp_ray();
    for mode in [Mode::Adaptive, Mode::Woodcock] {
        ratio_matches(&media, &ray, &[0.8, 1.6, 2.4, 3.2, 4.0], mode, "two ramps");
    }
}

#[test]
fn ratio_tracking_matches_quadrature_on_cloud_hg() {
    let (media, ray, _) = cloud_media();
    let (t0, t1) = media.grids[0]
        .interval(&ray, 10.0)
        .expect("the ray crosses the cloud");
    // Where the quadrature transmittance falls to 0.8, 0.5, 0.2 and 0.05 (bisection).
    let dists: Vec<f32> = [0.8, 0.5, 0.2, 0.05]
        .iter()
        .map(|&target| {
            let (mut a, mut b) = (t0, t1);
            for _ in 0..24 {
                let m = 0.5 * (a + b);
                if quad_tr(&media, &ray, m) > target {
                    a = m;
                } else {
                    b = m;
                }
            }
            0.5 * (a + b)
        })
        .collect();
    for mode in [Mode::Adaptive, Mode::Woodcock] {
        ratio_matches(&media, &ray, &dists, mode, "cloud-hg");
    }
}

/// One seed, many distances: the estimates form the step function of one realization.
#[test]
fn ratio_tracking_is_one_realization_per_seed() {
    let Some(g) = gpu_or_skip("ratio steps") else {
        return;
    };
    let media = ramp_media();
    let (ray, tmax) = ramp_ray();
    let mut gpu = GpuFreePaths::new(g, &media).expect("gpu free paths");
    let m = 601;
    let dists: Vec<f32> = (0..m).map(|k| tmax * k as f32 / (m - 1) as f32).collect();
    let rays: Vec<FpRay> = (0..8).map(|s| fp_ray(&ray, tmax, 12345 + s)).collect();
    let all: Vec<f32> = rays.iter().flat_map(|_| dists.iter().copied()).collect();
    let got = gpu
        .ratio_tr(&rays, &all, Mode::Adaptive)
        .expect("ratio estimates");
    let mut steps = 0;
    for row in got.chunks(m) {
        assert_eq!((row[0].tr, row[0].lookups), (1.0, 0));
        for w in row.windows(2) {
            assert!(w[1].tr <= w[0].tr && w[1].lookups >= w[0].lookups);
            if w[1].lookups == w[0].lookups {
                assert_eq!(w[1].tr.to_bits(), w[0].tr.to_bits());
            } else {
                steps += 1;
            }
        }
    }
    assert!(steps > 10, "tentative collisions along the rays: {steps}");
    // The same seeds again give the same values (deterministic).
    let again = gpu
        .ratio_tr(&rays, &all, Mode::Adaptive)
        .expect("ratio estimates");
    assert_eq!(got, again);
}

/// The GPU walk hands out the leaves `Heterogeneous::majorants` does: the same count and
/// bounds, the same spans within float rounding.
fn walks_match(media: &Media, rays: &[(Ray, f32)], label: &str) {
    let Some(g) = gpu_or_skip(label) else {
        return;
    };
    let mut gpu = GpuFreePaths::new(g, media).expect("gpu free paths");
    let fp: Vec<FpRay> = rays.iter().map(|(r, t)| fp_ray(r, *t, 0)).collect();
    for mode in [Mode::Adaptive, Mode::Woodcock] {
        let got = gpu.walk(&fp, 0, 4096, mode).expect("walk");
        for ((ray, tmax), segs) in rays.iter().zip(&got) {
            let mut cpu = Vec::new();
            media.grids[0].majorants(ray, *tmax, mode, |b, t0, t1| {
                cpu.push((b, t0, t1));
                true
            });
            assert_eq!(segs.len(), cpu.len(), "{label} {mode:?}: segment count");
            let scale = tmax.max(1.0) * 1e-5;
            for (s, (b, t0, t1)) in segs.iter().zip(&cpu) {
                assert_eq!(
                    (s.majorant, s.minorant),
                    (b.majorant, b.minorant),
                    "{label}"
                );
                assert!(
                    (s.t0 - t0).abs() < scale && (s.t1 - t1).abs() < scale,
                    "{label}"
                );
            }
            if mode == Mode::Adaptive {
                eprintln!("{label}: {} leaves, as the CPU", segs.len());
            }
        }
    }
}

#[test]
fn walk_visits_the_cpu_leaves() {
    let media = ramp_media();
    let (ray, tmax) = ramp_ray();
    let diagonal = Ray::new(
        Vec3::new(-0.3, -0.2, -0.25),
        Vec3::new(1.0, 0.9, 0.8).normalize(),
    );
    let axis = Ray::new(Vec3::new(1.0, 1.0, -1.0), Vec3::Z);
    let rays = [(ray, tmax), (diagonal, 5.0), (axis, 1.3), (ray, 1.1)];
    walks_match(&media, &rays, "ramp walk");
    let (cloud, ray, tmax) = cloud_media();
    let [lo, hi] = cloud.bounds().unwrap();
    let side = Ray::new(
        Vec3::new(lo.x - 1.0, 0.6 * lo.y + 0.4 * hi.y, 0.5 * (lo.z + hi.z)),
        Vec3::new(1.0, 0.03, -0.02).normalize(),
    );
    walks_match(&cloud, &[(ray, tmax), (side, 20.0)], "cloud-hg walk");
}

/// The beam estimate with camera transmittance tracked on the GPU (`CameraTr::Track`): one
/// beam crosses 4096 copies of a camera segment through the ramp (each its own
/// realization, over 4 passes), at t = 0.6, 1.4 and 2.2. Each pixel's value divided by the
/// pair's term at transmittance 1 is that realization's transmittance at the crossing; its
/// mean must match quadrature within 5 measured standard errors.
#[test]
fn beam_estimate_tracks_camera_transmittance() {
    use ppb::estimate::beams::{BeamMap, Walker};
    use ppb::estimate::eq2;
    use ppb::estimate::eq2::BeamPiece;
    use ppb::estimate::{Timings, TracedPass};
    use ppb::gpu::beams::{CameraTr, GpuBeams, GpuOptions, PrimaryPath};
    use ppb::scene::Camera;
    use ppb::transport::camera::{CameraPass, Pinhole, Primary};
    use ppb::transport::transmittance::SegmentTr;
    use ppb::transport::Beam;
    const R: f32 = 0.05;
    const SIDE: u32 = 64;
    let Some(g) = gpu_or_skip("beam_estimate_tracks_camera_transmittance") else {
        return;
    };
    let media = ramp_media();
    let (ray, tmax) = ramp_ray();
    let camera = Pinhole::new(
        &Camera {
            origin: ray.o,
            target: ray.o + ray.d,
            up: Vec3::Z,
            vfov_deg: 30.0,
        },
        SIDE,
        SIDE,
    );
    let opts = GpuOptions {
        primary: PrimaryPath::Gather,
        camera_tr: CameraTr::Track,
        seed: 7,
        free_path: Mode::Adaptive,
        walk_budget: None,
    };
    let mut est = GpuBeams::new(g, &media, &camera, opts).expect("gpu");
    let pixels = (SIDE * SIDE) as usize;
    for tc in [0.6f32, 1.4, 2.2] {
        // Across the segment at distance 0.01, the crossing half way along the beam.
        let at = ray.at(tc) + Vec3::new(0.0, 0.01, 0.0);
        let beam = Beam::new(at - Vec3::Z * 0.4, Vec3::Z, 0.8, Vec3::ONE);
        let scatter = |x, cos| media.in_scatter(x, cos);
        let piece = BeamPiece::whole(&beam);
        let base = eq2::term(&ray, (0.0, tmax), &piece, R, scatter, |_| 1.0)
            .expect("the pair counts")
            .x as f64;
        let mut samples = Vec::with_capacity(4 * pixels);
        for index in 1..=4 {
            let pass = TracedPass {
                index,
                odd: index % 2 == 1,
                camera: CameraPass {
                    alpha: Vec::new(),
                    image: vec![Vec3::ZERO; pixels],
                    nested: vec![Vec3::ZERO; pixels],
                    primaries: vec![
                        Primary {
                            dir: ray.d,
                            t_surf: tmax,
                            tr: SegmentTr::Clear,
                            chords: media.chords(&ray),
                        };
                        pixels
                    ],
                    secondary: Vec::new(),
                    counters: Counters::default(),
                },
                beam_map: Some(BeamMap::build(&[beam], R, Walker::Gpu)),
                beams: vec![beam],
                beam_radius: R,
                counters: Counters::default(),
                timings: Timings::default(),
            };
            let view = ppb::estimate::View {
                camera: &camera,
                media: &media,
                kernel: ppb::estimate::eq2::BeamKernel::Line,
            };
            est.clear().expect("clear");
            est.submit(view, &pass).expect("submit");
            let img = est.read().expect("read back").0;
            assert!(
                img.iter().all(|p| p[3] == 1.0),
                "t={tc}: one evaluation per pixel"
            );
            samples.extend(img.iter().map(|p| p[0] as f64 / base));
        }
        let n = samples.len() as f64;
        let mean = samples.iter().sum::<f64>() / n;
        let var = samples.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0);
        let se = (var / n).sqrt();
        let truth = quad_tr(&media, &ray, tc);
        eprintln!(
            "t={tc}: mean transmittance {mean:.5} vs quadrature {truth:.5} ({:.2} standard \
             errors, sd {:.3})",
            (mean - truth) / se,
            var.sqrt()
        );
        assert!(var > 1e-4, "t={tc}: every realization gave the same value");
        assert!(
            (mean - truth).abs() < 5.0 * se + 1e-4,
            "t={tc}: {mean} vs {truth} (se {se})"
        );
    }
}
