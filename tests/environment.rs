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
use std::path::Path;

use ppb::pass::Tracer;
use ppb::scene::toml::parse;
use ppb::session::Session;

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
