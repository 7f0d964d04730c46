//! The conformance scenes at low resolution against the Mitsuba references averaged over
//! 4x4 pixel blocks. The tolerance comes from the render's own measured noise: two
//! independent seeds A and B give rel_l1(A, B) / 2, the noise-only rel_l1 expected of their
//! mean; the bound is 1.3 times that (the spread of that estimate) plus the reference's own
//! 4x4-block noise (reference.json) and a 1 % allowance for kernel bias. Radii are those of
//! the full-resolution render. A 10 % error in brightness fails both tests.
use std::path::Path;

use ppb::compare::{block_mean, compare, read_mask};
use ppb::film::Film;
use ppb::output::{read_exr, Image};
use ppb::render::Renderer;
use ppb::scene::toml::load;
use ppb::settings::Radius;

const SIZE: u32 = 64;
const BLOCK: usize = 4;

fn data(p: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(p)
}

fn render(scene: &str, seed: u64, passes: u32, paths: usize) -> Image {
    let file = load(&data(scene)).expect("scene loads");
    // The radii the full-resolution render would use: blocks of the reference are
    // compared, so the kernel must not blur more than the full-resolution render does.
    let full = Renderer::new(&file.scene, file.settings.clone()).expect("renderer");
    let mut s = file.settings.clone();
    s.beam_radius = Radius::Fixed(full.beam_r1);
    s.photon_radius = Radius::Fixed(full.photon_r1);
    s.width = SIZE;
    s.height = SIZE;
    s.seed = seed;
    s.beams_per_pass = paths;
    let r = Renderer::new(&file.scene, s).expect("renderer");
    let mut film = Film::new(SIZE, SIZE);
    for i in 1..=passes {
        film.add_pass(&r.pass(i).image);
    }
    Image {
        width: SIZE as usize,
        height: SIZE as usize,
        pixels: film.image(),
    }
}

fn average(a: &Image, b: &Image) -> Image {
    Image {
        pixels: a
            .pixels
            .iter()
            .zip(&b.pixels)
            .enumerate()
            .map(|(i, _)| {
                let (x, y) = (a.pixels[i], b.pixels[i]);
                [
                    0.5 * (x[0] + y[0]),
                    0.5 * (x[1] + y[1]),
                    0.5 * (x[2] + y[2]),
                ]
            })
            .collect(),
        ..a.clone()
    }
}

struct Outcome {
    rel_l1: f64,
    noise: f64,
    mean_ratio: f64,
}

fn check(scene: &str, reference: &str, mask: Option<&str>, passes: u32, paths: usize) -> Outcome {
    let reference = block_mean(&read_exr(&data(reference)).expect("reference"), BLOCK);
    let skip = mask.map(|m| {
        let (w, _, full) = read_mask(&data(m)).expect("mask");
        let mut s = vec![false; (SIZE * SIZE) as usize];
        for (i, &m) in full.iter().enumerate() {
            if m {
                let (x, y) = (i % w / BLOCK, i / w / BLOCK);
                s[y * SIZE as usize + x] = true;
            }
        }
        s
    });
    let a = render(scene, 1, passes, paths);
    let b = render(scene, 2, passes, paths);
    let noise = compare(&a, &b, skip.as_deref()).unwrap().rel_l1 / 2.0;
    let m = compare(&average(&a, &b), &reference, skip.as_deref()).unwrap();
    eprintln!(
        "{scene}: rel_l1 {:.4}, noise-only {:.4}, mean {:.5} vs {:.5}",
        m.rel_l1, noise, m.mean[0], m.mean_ref[0]
    );
    Outcome {
        rel_l1: m.rel_l1,
        noise,
        mean_ratio: m.mean[0] / m.mean_ref[0],
    }
}

#[test]
fn fog_box_matches_reference() {
    let o = check(
        "scenes/conformance/fog-box/scene.toml",
        "tests/data/conformance/fog-box/reference.exr",
        None,
        192,
        20_000,
    );
    let bound = 1.3 * o.noise + 0.0011 + 0.01;
    assert!(o.rel_l1 < bound, "rel_l1 {} >= {bound}", o.rel_l1);
    assert!(
        (o.mean_ratio - 1.0).abs() < 0.01,
        "mean ratio {}",
        o.mean_ratio
    );
}

#[test]
fn glass_caustic_matches_reference() {
    let o = check(
        "scenes/conformance/glass-caustic/scene.toml",
        "tests/data/conformance/glass-caustic/reference.exr",
        Some("tests/data/conformance/glass-caustic/emitter_mask.png"),
        192,
        20_000,
    );
    // The reference's 4x4-block noise outside the emitter is 1.8 %: its caustic outliers.
    let bound = 1.3 * o.noise + 0.018 + 0.01;
    assert!(o.rel_l1 < bound, "rel_l1 {} >= {bound}", o.rel_l1);
    assert!(
        (o.mean_ratio - 1.0).abs() < 0.02,
        "mean ratio {}",
        o.mean_ratio
    );
}
