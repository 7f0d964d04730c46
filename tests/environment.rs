//! A constant environment light through the whole pipeline, against closed forms: a Lambert
//! floor under it reflects rho L (the upper hemisphere is unoccluded), and a non-absorbing
//! medium under it is a furnace: radiance L along every camera ray, through the medium or
//! past it. Both for the hybrid method (next-event estimation of the environment, beams and
//! photons for the rest) and the paper's pure one (all light through beams and photons).
//! Each pass is an independent estimate of the same expectation, so the bound is 4 standard
//! errors of the pass means. The photon kernel blurs nothing on the floor (constant
//! radiance). The beam kernel is biased by order r in the furnace: at a camera point just
//! inside a face it also averages beams that pass just outside without crossing it, and
//! those are not stored (measured on the pure method: -0.5 % at r = 8 cm, -0.2 % at 2 cm,
//! means over 2 and 4 seeds); the hybrid method's beams, which carry multiple scattering
//! only, also blur its peak in the middle (-0.34 % at the auto radius of about 12 cm). A
//! 5 mm beam radius keeps both well inside the bound.
use std::f64::consts::PI;
use std::path::{Path, PathBuf};

use glam::{Vec2, Vec3};
use ppb::pass::Tracer;
use ppb::scene::environment::{dir_to_uv, uv_to_dir};
use ppb::scene::toml::parse;
use ppb::scene::Light;
use ppb::session::Session;

mod common;

/// The image mean of each of `passes` passes of the scene `text` with `method`: their mean
/// and standard error.
fn pass_means(name: &str, text: &str, method: &str, passes: u32) -> (f64, f64) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("scenes/{name}.toml"));
    let text = format!("{text}\nmethod = \"{method}\"\n{RENDER}");
    let file = parse(&path, &text).expect("scene parses");
    let tracer = Tracer::new(&file.scene, file.settings).expect("tracer");
    let mut session = Session::cpu(tracer);
    let means: Vec<f64> = (1..=passes)
        .map(|i| {
            let img = session.pass_image(i).expect("pass");
            let sum: f64 = img.pixels.iter().map(|p| p[1] as f64).sum();
            sum / img.pixels.len() as f64
        })
        .collect();
    let n = means.len() as f64;
    let mean = means.iter().sum::<f64>() / n;
    let var = means.iter().map(|m| (m - mean).powi(2)).sum::<f64>() / (n - 1.0);
    (mean, (var / n).sqrt())
}

const RENDER: &str = "width = 48\nheight = 48\nlight_paths = 40000\nseed = 5";

fn check(name: &str, text: &str, method: &str, passes: u32, want: f64) {
    let (mean, se) = pass_means(name, text, method, passes);
    eprintln!("{name} ({method}): {mean:.5} +- {se:.5}, closed form {want:.5}");
    assert!(
        (mean - want).abs() < 4.0 * se,
        "{name} ({method}): {mean} vs {want} (se {se})"
    );
    assert!(
        4.0 * se < 0.02 * want,
        "{name} ({method}): test too weak, se {se}"
    );
}

const FLOOR: &str = r#"
[camera]
origin = [0, 2, 0.001]
target = [0, 0, 0]
up = [0, 0, -1]
vfov = 60

[[material]]
name = "floor"
type = "lambert"
reflectance = [0.5, 0.5, 0.5]

[[mesh]]
path = "common/floor.obj"
material = "floor"

[[light]]
type = "environment"
radiance = [0.8, 0.8, 0.8]

[render]
"#;

/// The camera looks straight down at the middle 2.3 m of a 6 m floor: every pixel sees
/// rho L = 0.5 * 0.8.
#[test]
fn constant_environment_over_a_lambert_floor_gives_rho_l() {
    check("env-floor", FLOOR, "hybrid", 80, 0.4);
    check("env-floor", FLOOR, "ppb", 80, 0.4);
}

const FURNACE: &str = r#"
[camera]
origin = [0, 0, 4]
target = [0, 0, 0]
up = [0, 1, 0]
vfov = 40

[[light]]
type = "environment"
radiance = [1, 1, 1]

[[medium]]
type = "homogeneous"
bounds = [[-1, -1, -1], [1, 1, 1]]
sigma_t = 1.5
albedo = [1, 1, 1]
phase = { type = "hg", g = 0.4 }

[render]
beam_radius = 0.005
"#;

/// The camera sees the box and the environment around it: radiance 1 everywhere, the
/// attenuated environment behind the box made up by in-scattering exactly.
#[test]
fn furnace_medium_under_a_constant_environment() {
    check("env-furnace", FURNACE, "hybrid", 80, 1.0);
    check("env-furnace", FURNACE, "ppb", 80, 1.0);
}

/// Writes a lat-long map as a float32 RGB EXR `name` in a fresh folder; returns its path.
fn write_map(name: &str, w: usize, h: usize, f: impl Fn(Vec3) -> [f32; 3] + Sync) -> PathBuf {
    let dir = common::temp_dir("env", name);
    let path = dir.join(format!("{name}.exr"));
    exr::prelude::write_rgb_file(&path, w, h, |i, j| {
        let d = uv_to_dir(Vec2::new(
            (i as f32 + 0.5) / w as f32,
            (j as f32 + 0.5) / h as f32,
        ));
        let [r, g, b] = f(d);
        (r, g, b)
    })
    .expect("writes the map");
    path
}

/// The light block of an environment read from `map` (radiance 1 unless `extra` says).
fn map_light(map: &Path, extra: &str) -> String {
    format!(
        "[[light]]\ntype = \"environment\"\nmap = \"{}\"\n{extra}\n",
        map.display()
    )
}

/// A map of constant radiance 1 is the constant environment drawn by its texels: the
/// furnace holds through map sampling, the map's emission and the MIS with the phase
/// function.
#[test]
fn furnace_under_a_constant_map() {
    let map = write_map("flat", 32, 16, |_| [1.0; 3]);
    let text = FURNACE.replace(
        "[[light]]\ntype = \"environment\"\nradiance = [1, 1, 1]\n",
        &map_light(&map, ""),
    );
    assert!(text.contains("map ="));
    check("env-map-furnace", &text, "hybrid", 80, 1.0);
    check("env-map-furnace", &text, "ppb", 80, 1.0);
}

/// A sky with a sun: a gradient, a dim ground and a 9-degree disk 60 times as bright at
/// 50 degrees elevation, turned by 30 degrees.
fn sun_sky(d: Vec3) -> [f32; 3] {
    let sun = Vec3::new(0.4, 0.766, -0.5).normalize();
    let s = if d.dot(sun) > 9f32.to_radians().cos() {
        60.0
    } else {
        0.0
    };
    if d.y < 0.0 {
        [0.05 + s, 0.04 + s, 0.03 + s]
    } else {
        let y = d.y.sqrt();
        [0.9 - 0.5 * y + s, 0.9 - 0.3 * y + s, 1.0 + s]
    }
}

/// rho / pi * int over the upper hemisphere of L(w) cos(w) dw, by a midpoint rule on the
/// scene's own environment (bilinear lookups of the map as written).
fn floor_radiance(light: &Light, rho: f64) -> f64 {
    let Light::Environment(env) = light else {
        panic!("expected the environment, got {light:?}")
    };
    let (nc, np) = (1000, 2000);
    let mut sum = 0.0;
    for a in 0..nc {
        let c = (a as f64 + 0.5) / nc as f64;
        let s = (1.0 - c * c).sqrt();
        for b in 0..np {
            let phi = 2.0 * PI * (b as f64 + 0.5) / np as f64;
            let d = Vec3::new((s * phi.cos()) as f32, c as f32, (s * phi.sin()) as f32);
            sum += env.eval(d).y as f64 * c;
        }
    }
    rho / PI * sum * 2.0 * PI / (nc * np) as f64
}

/// A Lambert floor under the sun sky (upper hemisphere unoccluded): rho / pi times the
/// cosine-weighted integral of the map, with the map importance-sampled and MIS against
/// the cosine (hybrid), and through photons emitted by the map (pure).
#[test]
fn lambert_floor_under_a_sun_sky_map() {
    let map = write_map("sun", 128, 64, sun_sky);
    let text = FLOOR.replace(
        "[[light]]\ntype = \"environment\"\nradiance = [0.8, 0.8, 0.8]\n",
        &map_light(&map, "radiance = [0.5, 0.5, 0.5]\nrotation = 30"),
    );
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/env-sun.toml");
    let file = parse(&path, &format!("{text}\n{RENDER}")).expect("scene parses");
    let want = floor_radiance(&file.scene.lights[0], 0.5);
    check("env-sun", &text, "hybrid", 80, want);
    check("env-sun", &text, "ppb", 80, want);
}

/// The map as the camera sees it: looking along +X with +Y up, a map whose texels hold
/// their own (u, v) shows, in each pixel, the (u, v) of the direction through the pixel
/// by SPEC.md's camera (u growing to the right, towards +Z; v downwards); turned by
/// 90 degrees the same pixels show the map a quarter turn further on (u + 0.25: the map's
/// u = 0 has moved from world -Z to -X).
#[test]
fn the_camera_sees_the_map_in_the_stated_convention() {
    let map = write_map("uv", 256, 128, |d| {
        let uv = dir_to_uv(d);
        [uv.x, uv.y, 1.0]
    });
    for rotation in [0.0f32, 90.0] {
        let text = format!(
            "[camera]\norigin = [0, 0, 0]\ntarget = [1, 0, 0]\nup = [0, 1, 0]\nvfov = 60\n\n{}\n[render]\nwidth = 32\nheight = 16\npasses = 16\n",
            map_light(&map, &format!("rotation = {rotation}"))
        );
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/env-uv.toml");
        let file = parse(&path, &text).expect("scene parses");
        let tracer = Tracer::new(&file.scene, file.settings).expect("tracer");
        let mut session = Session::cpu(tracer);
        let img = session.pass_image(1).expect("pass");
        let (w, h) = (32.0f32, 16.0f32);
        let a = 30f32.to_radians().tan();
        let (f, r, up) = (Vec3::X, Vec3::Z, Vec3::Y);
        let mut worst = 0.0f32;
        for y in 0..16 {
            for x in 0..32 {
                let (px, py) = (x as f32 + 0.5, y as f32 + 0.5);
                let sx = (2.0 * px / w - 1.0) * a * w / h;
                let sy = (1.0 - 2.0 * py / h) * a;
                let d = (r * sx + up * sy + f).normalize();
                let uv = dir_to_uv(d) + Vec2::new(rotation / 360.0, 0.0);
                let got = img.pixels[y * 32 + x];
                // One pass jitters within the pixel: up to about a pixel's span of u, v.
                worst = worst.max((Vec2::new(got[0], got[1]) - uv).abs().max_element());
            }
        }
        eprintln!("rotation {rotation}: worst |uv - expected| {worst:.4}");
        assert!(worst < 0.02, "rotation {rotation}: {worst}");
    }
}

const SKY: &str = "[[light]]\ntype = \"sky\"\nsun_elevation = 35\nsun_azimuth = 120\nturbidity = 3\nsun_size = 3\nresolution = 256\nradiance = [0.01, 0.01, 0.01]\n";

/// The Preetham sky (`type = "sky"`) is an environment map like any other: a Lambert
/// floor under it reflects rho / pi times its cosine-weighted integral, by both methods.
#[test]
fn lambert_floor_under_the_preetham_sky() {
    let text = FLOOR.replace(
        "[[light]]\ntype = \"environment\"\nradiance = [0.8, 0.8, 0.8]\n",
        SKY,
    );
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/env-sky.toml");
    let file = parse(&path, &format!("{text}\n{RENDER}")).expect("scene parses");
    let want = floor_radiance(&file.scene.lights[0], 0.5);
    check("env-sky", &text, "hybrid", 80, want);
    check("env-sky", &text, "ppb", 80, want);
}

/// A sky outside the model's range is an error naming the light's field.
#[test]
fn sky_parameters_are_checked() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/env-sky.toml");
    for (from, to, field) in [
        ("turbidity = 3", "turbidity = 12", "light[0].turbidity"),
        (
            "sun_elevation = 35",
            "sun_elevation = -5",
            "light[0].sun_elevation",
        ),
        ("resolution = 256", "resolution = 4", "light[0].resolution"),
    ] {
        let text = FLOOR.replace(
            "[[light]]\ntype = \"environment\"\nradiance = [0.8, 0.8, 0.8]\n",
            &SKY.replace(from, to),
        );
        let Err(e) = parse(&path, &format!("{text}\n{RENDER}")) else {
            panic!("{field}: {to} was accepted")
        };
        let e = e.to_string();
        assert!(e.contains(field) && e.contains("expected"), "{e}");
    }
}

/// A transparent film (`--transparent`, Cycles' film transparency): camera rays that leave
/// the scene show nothing of the environment, and the EXR's A channel holds 1 minus the
/// transmittance of each camera ray that leaves. The furnace's box is homogeneous, so
/// that transmittance is exact: alpha = 1 - exp(-1.5 chord) through the box (the middle
/// pixel: chord 2), and 0 with black radiance where the ray misses it.
#[test]
fn transparent_film_hides_the_environment_and_writes_alpha() {
    let dir = common::temp_dir("env", "transparent");
    let scene = dir.join("scene.toml");
    std::fs::write(
        &scene,
        FURNACE.replace(
            "beam_radius = 0.005",
            "width = 40\nheight = 40\npasses = 4\nlight_paths = 20000",
        ),
    )
    .unwrap();
    let out = dir.join("out.exr");
    let status = std::process::Command::new(env!("CARGO_BIN_EXE_ppb"))
        .args(["render", "--quiet", "--transparent", "-o"])
        .arg(&out)
        .arg(&scene)
        .status()
        .expect("runs ppb");
    assert!(status.success());
    let img = exr::prelude::read_first_rgba_layer_from_file(
        &out,
        |res, _| (res.width(), vec![[0f32; 4]; res.width() * res.height()]),
        |(w, px): &mut (usize, Vec<[f32; 4]>), p, (r, g, b, a): (f32, f32, f32, f32)| {
            px[p.y() * *w + p.x()] = [r, g, b, a];
        },
    )
    .expect("reads the EXR");
    let meta = exr::meta::MetaData::read_from_file(&out, false).expect("EXR header");
    let names: Vec<String> = meta.headers[0]
        .channels
        .list
        .iter()
        .map(|c| c.name.to_string())
        .collect();
    assert_eq!(names, ["A", "B", "G", "R"], "an RGBA EXR");
    let px = &img.layer_data.channel_data.pixels.1;
    let (corner, middle) = (px[0], px[20 * 40 + 20]);
    assert_eq!(
        corner, [0.0; 4],
        "the hidden environment: black and transparent"
    );
    // The middle pixel's rays run within 0.1 degrees of the axis: chords within 0.1 % of 2.
    let want = 1.0 - (-1.5f32 * 2.0).exp();
    assert!(
        (middle[3] - want).abs() < 2e-3,
        "alpha {} vs {want}",
        middle[3]
    );
    assert!(
        middle[1] > 0.1,
        "the box still scatters the environment's light: {middle:?}"
    );
}

/// Bad environment lights in a scene file are errors naming the field: a missing map
/// (and the file), a light with neither radiance nor map, a rotation out of range.
#[test]
fn environment_fields_are_checked() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/env-bad.toml");
    let with = |light: &str| {
        let text = FLOOR.replace(
            "[[light]]\ntype = \"environment\"\nradiance = [0.8, 0.8, 0.8]\n",
            light,
        );
        match parse(&path, &format!("{text}\n{RENDER}")) {
            Ok(_) => panic!("accepted: {light}"),
            Err(e) => e.to_string(),
        }
    };
    let e = with("[[light]]\ntype = \"environment\"\nmap = \"nowhere/sky.exr\"\n");
    assert!(
        e.contains("light[0].map") && e.contains("nowhere/sky.exr"),
        "{e}"
    );
    let e = with("[[light]]\ntype = \"environment\"\n");
    assert!(
        e.contains("light[0].radiance") && e.contains("or a map"),
        "{e}"
    );
    let e = with("[[light]]\ntype = \"environment\"\nradiance = [1, 1, 1]\nrotation = 400\n");
    assert!(e.contains("light[0].rotation"), "{e}");
}
