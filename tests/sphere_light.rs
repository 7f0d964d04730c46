//! Sphere lights as the conformance SPEC defines them: seen by camera rays, emitting
//! outward, but neither blocking nor reflecting light (Mitsuba: an area emitter on a sphere
//! with a `null` BSDF); and the pixels that see one directly, which hold much of an image's
//! sum where the light is small and bright.
use glam::Vec3;
use std::path::Path;

use ppb::core::{ray_box, Ray};
use ppb::geometry::Geometry;
use ppb::pass::Tracer;
use ppb::scene::toml::load;
use ppb::session::Session;
use ppb::transport::camera::Pinhole;

const SCENE: &str = "scenes/conformance/fog-near-light/scene.toml";

fn scene() -> ppb::scene::toml::SceneFile {
    load(&Path::new(env!("CARGO_MANIFEST_DIR")).join(SCENE)).expect("scene loads")
}

#[test]
fn a_sphere_light_neither_blocks_nor_reflects() {
    let file = scene();
    let g = Geometry::new(&file.scene).expect("geometry");
    let (c, r) = (Vec3::new(0.9, 2.4, 1.0), 0.05);
    // Straight down through the light: the floor below is the first surface.
    let down = Ray::new(c + Vec3::Y, -Vec3::Y);
    let hit = g.intersect(&down, f32::INFINITY).expect("the floor");
    assert!((hit.p.y).abs() < 1e-4, "hit {:?}", hit.p);
    let seen: Vec<_> = g.lights_seen(&down, hit.t).collect();
    assert_eq!(seen.len(), 1);
    assert!((seen[0].0 - (1.0 - r)).abs() < 1e-5, "{seen:?}");
    // From inside, the outward emission faces away.
    let inside = Ray::new(c, Vec3::X);
    assert_eq!(g.lights_seen(&inside, f32::INFINITY).count(), 0);
    // Behind the ray, or beyond the first surface, nothing is seen.
    assert_eq!(g.lights_seen(&down, 0.5).count(), 0);
    let up = Ray::new(c + Vec3::Y, Vec3::Y);
    assert_eq!(g.lights_seen(&up, f32::INFINITY).count(), 0);
}

/// `lights_near` is conservative: every ray through a pixel that meets the light is
/// within the pixel's diagonal of a ray that `lights_near` accepts.
#[test]
fn pixels_near_a_light_are_found() {
    let file = scene();
    let g = Geometry::new(&file.scene).expect("geometry");
    let cam = Pinhole::new(&file.scene.camera, 256, 256);
    let mut rng = ppb::sampling::Rng::new(7, 1);
    let mut seen = 0;
    for y in 0..4u32 {
        for x in 195..225u32 {
            let centre = cam.ray(x as f32 + 0.5, y as f32 + 0.5);
            let near = g.lights_near(&centre, cam.pixel_diagonal());
            for _ in 0..64 {
                let u = rng.vec2();
                let ray = cam.ray(x as f32 + u.x, y as f32 + u.y);
                if g.lights_seen(&ray, f32::INFINITY).next().is_some() {
                    seen += 1;
                    assert!(near, "pixel ({x}, {y}) sees the light");
                }
            }
        }
    }
    assert!(seen > 20, "the test must see the light: {seen}");
}

/// The pixels on the light's rim match the light's coverage of each pixel (a 400x400
/// grid of rays) times its radiance and the fog's transmittance up to it, within 4
/// standard errors of the passes' mean (and their sum within 5 %); and each pass
/// estimates it with a spread well under one camera ray's coin toss.
#[test]
fn pixels_on_a_light_match_its_coverage() {
    let file = scene();
    let g = Geometry::new(&file.scene).expect("geometry");
    let cam = Pinhole::new(&file.scene.camera, 256, 256);
    let fog = [Vec3::new(-2.0, 0.03125, -2.0), Vec3::new(2.0, 2.21875, 2.0)];
    let le = 5092.958_f64;
    let expected = |x: u32| {
        let n = 400;
        let (mut sum, mut cover) = (0.0f64, 0.0f64);
        for i in 0..n {
            for j in 0..n {
                let ray = cam.ray(
                    x as f32 + (i as f32 + 0.5) / n as f32,
                    (j as f32 + 0.5) / n as f32,
                );
                if let Some((t, _)) = g.lights_seen(&ray, f32::INFINITY).next() {
                    let chord = ray_box(&ray, &fog, 0.0, t).map_or(0.0, |(a, b)| b - a);
                    sum += le * (-0.1 * chord as f64).exp();
                    cover += 1.0;
                }
            }
        }
        let k = f64::from(n * n);
        (sum / k, cover / k)
    };
    let mut settings = file.settings.clone();
    settings.light_paths = 200;
    let tracer = Tracer::new(&file.scene, settings).expect("renderer");
    let mut session = Session::cpu(tracer);
    let passes = 128;
    let rows: Vec<Vec<f64>> = (1..=passes)
        .map(|i| {
            let img = session.pass_image(i).expect("pass").pixels;
            (208..212).map(|x| f64::from(img[x][0])).collect()
        })
        .collect();
    let (mut total, mut total_want, mut total_var) = (0.0, 0.0, 0.0);
    for (k, x) in (208..212u32).enumerate() {
        let (want, cover) = expected(x);
        let v: Vec<f64> = rows.iter().map(|r| r[k]).collect();
        let n = v.len() as f64;
        let mean = v.iter().sum::<f64>() / n;
        let sd = (v.iter().map(|a| (a - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
        let se = sd / n.sqrt();
        let coin = le * (cover * (1.0 - cover)).sqrt();
        eprintln!("pixel {x}: {mean:.1} +- {se:.1}, expected {want:.1}; per pass sd {sd:.1}, one ray's {coin:.1}");
        // The fog's own in-scattering adds about 0.2 (the pixels beside the light).
        assert!(
            (mean - want).abs() < 4.0 * se + 1.0,
            "pixel {x}: {mean} vs {want}"
        );
        assert!(
            sd < 0.5 * coin,
            "pixel {x}: spread {sd} against one ray's {coin}"
        );
        (total, total_want, total_var) = (total + mean, total_want + want, total_var + se * se);
    }
    let bound = 4.0 * total_var.sqrt() + 4.0;
    assert!(
        (total - total_want).abs() < bound,
        "{total} vs {total_want}"
    );
    assert!(bound < 0.05 * total_want, "test too weak: {bound}");
}

/// The pixels ppb leaves out of its error estimate are the references' emitter masks
/// (pixels whose footprint sees the light directly, dilated by one pixel).
#[test]
fn light_pixels_are_the_references_emitter_masks() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    for name in ["fog-near-light", "glass-caustic"] {
        let file = load(&root.join(format!("scenes/conformance/{name}/scene.toml"))).unwrap();
        let tracer = Tracer::new(&file.scene, file.settings.clone()).expect("renderer");
        let mask = root.join(format!("tests/data/conformance/{name}/emitter_mask.png"));
        let (w, _, m) = ppb::compare::read_mask(&mask).expect("mask");
        let want: Vec<u32> = (0..m.len() as u32).filter(|&i| m[i as usize]).collect();
        let got = tracer.light_pixels();
        assert!(w == 256 && !want.is_empty());
        assert_eq!(got, want, "{name}");
    }
}
