//! The reference-free error estimate (`film::error`) against what it estimates, and
//! `ppb render --target-error`.
mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

use ppb::compare::{block_mean, compare};
use ppb::film::Film;
use ppb::output::{read_exr, read_exr_text, Image};
use ppb::pass::Tracer;
use ppb::scene::toml::load;
use ppb::session::Session;
use ppb::settings::{Bandwidth, Radius, RenderSettings, TrMode, AUTO_PHOTON_PIXELS};

fn data(p: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(p)
}

/// How a test renders: scene, size (square), light paths, passes, camera transmittance.
#[derive(Clone, Copy)]
struct Setup {
    scene: &'static str,
    size: u32,
    paths: usize,
    passes: u32,
    tr: TrMode,
}

/// `setup` with seed `seed`: the image and the estimate the film made of its own error.
/// Stratified transmittance runs blocks of 4 passes (2 strata).
fn render(setup: Setup, seed: u64) -> (Image, [f64; 2]) {
    let Setup {
        scene,
        size,
        paths,
        passes,
        tr,
    } = setup;
    let file = load(&data(scene)).expect("scene");
    let mut s = file.settings.clone();
    (s.width, s.height, s.light_paths, s.seed) = (size, size, paths, seed);
    (s.tr_mode, s.tr_block, s.tr_samples) = (tr, 4, 2);
    let mut session = Session::cpu(Tracer::new(&file.scene, s).expect("tracer"));
    let img = session.render(passes).expect("render");
    let e = session
        .error_estimate()
        .expect("film")
        .expect("enough passes");
    (img, [e.noise.pixel, e.noise.block])
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len() as f64
}

fn var(v: &[f64]) -> f64 {
    let m = mean(v);
    v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (v.len() - 1) as f64
}

/// Independent renders (other seeds) of one scene differ from each other by what each
/// differs from the converged mean, times sqrt 2: rel_l1(a, b) / sqrt 2 over pairs is the
/// noise the estimate claims to measure, per pixel and on 4x4 block means. Per pair, the
/// mean of the two renders' estimates minus that measure has expectation zero; the mean of
/// these differences must be within 4 standard errors (from their spread over the pairs:
/// pairing cancels most of a rare bright path's sway, which moves both) of zero, and that
/// bound must be tight enough to catch an estimate off by a quarter.
fn estimate_matches_independent_renders(setup: Setup) {
    let scene = setup.scene;
    let renders: Vec<(Image, [f64; 2])> = (1..=16).map(|seed| render(setup, seed)).collect();
    for (k, metric) in ["pixel", "4x4"].iter().enumerate() {
        let pairs: Vec<(f64, f64)> = renders
            .chunks(2)
            .map(|p| {
                let (a, b) = (&p[0].0, &p[1].0);
                let m = if k == 0 {
                    compare(a, b, None)
                } else {
                    compare(&block_mean(a, 4), &block_mean(b, 4), None)
                };
                let estimate = (p[0].1[k] + p[1].1[k]) / 2.0;
                (estimate, m.expect("same size").rel_l1 / 2f64.sqrt())
            })
            .collect();
        let (estimates, measured): (Vec<f64>, Vec<f64>) = pairs.iter().copied().unzip();
        let diff: Vec<f64> = pairs.iter().map(|(e, m)| e - m).collect();
        let (e, m) = (mean(&estimates), mean(&measured));
        let se = (var(&diff) / diff.len() as f64).sqrt();
        eprintln!("{scene} {metric}: estimated {e:.5}, measured {m:.5} (standard error {se:.5})");
        assert!(
            4.0 * se < 0.25 * m,
            "{scene} {metric}: too few renders to tell"
        );
        assert!(
            (e - m).abs() < 4.0 * se,
            "{scene} {metric}: estimated {e}, measured {m}"
        );
    }
}

const SMOKE: Setup = Setup {
    scene: "scenes/conformance/smoke-grid/scene.toml",
    size: 96,
    paths: 1500,
    passes: 32,
    tr: TrMode::Ratio,
};

#[test]
fn noise_estimate_matches_the_spread_of_independent_renders_in_media() {
    estimate_matches_independent_renders(SMOKE);
}

/// Stratified transmittance: a block's passes share their jitter, so the half-films take
/// alternate blocks (alternate passes would share it and miss its noise).
#[test]
fn noise_estimate_matches_independent_renders_under_stratified_transmittance() {
    estimate_matches_independent_renders(Setup {
        tr: TrMode::Stratified,
        ..SMOKE
    });
}

/// A floor lit through homogeneous fog: surface photons and next-event estimation beside
/// the beams.
#[test]
fn noise_estimate_matches_the_spread_of_independent_renders_on_a_floor_in_fog() {
    estimate_matches_independent_renders(Setup {
        scene: "scenes/conformance/fog-box/scene.toml",
        ..SMOKE
    });
}

/// `scene` at its full size with `widen` applied to its settings (given the tracer of its
/// own, for the auto radii): seed `seed`'s film after `passes`.
fn widened(scene: &str, widen: fn(&mut RenderSettings, &Tracer), seed: u64, passes: u32) -> Film {
    let file = load(&data(scene)).expect("scene");
    let auto = Tracer::new(&file.scene, file.settings.clone()).expect("tracer");
    let mut s = file.settings.clone();
    s.seed = seed;
    widen(&mut s, &auto);
    let mut session = Session::cpu(Tracer::new(&file.scene, s).expect("tracer"));
    session.render(passes).expect("render");
    session.film().expect("film")
}

/// fog-box with the beam R1 at 3 times the auto radius, so the kernel's blur at the box's
/// faces dominates its error.
fn wide_fog_box(seed: u64, passes: u32) -> Film {
    let widen = |s: &mut RenderSettings, t: &Tracer| {
        s.beam_radius = Radius::Fixed(3.0 * t.beam_r1);
    };
    widened("scenes/conformance/fog-box/scene.toml", widen, seed, passes)
}

/// 16x16 block means of a film-sized RGB map.
fn blocks16(film: &Film, px: Vec<[f32; 3]>) -> Vec<[f32; 3]> {
    let img = Image {
        width: film.width as usize,
        height: film.height as usize,
        pixels: px,
        alpha: None,
    };
    block_mean(&img, 16).pixels
}

/// The bias estimate against the converged render (the Mitsuba reference) on a medium's
/// faces, and the adaptive bandwidth that uses it. Along a direction p in the space of
/// 16x16 block maps, the bias estimate b (-K D) of seed 1 and its measured error x - ref
/// both estimate the true bias's component; p is seed 2's bias estimate, independent of
/// seed 1's noise. Their ratio must lie in the estimate's model range, 0.77 (a step)
/// to 1.16 (smooth radiance; `film::error`), widened by 4 standard errors of the
/// measured component: sum p^2 var(x) over the blocks, var(x) from the two seeds'
/// difference, (x1 - x2)^2 / 2 (the reference's own noise is 6 times smaller on these
/// blocks). The adaptive image, the same
/// passes resolved per pixel, must have less error than the fixed one, per pixel and on
/// 4x4 blocks.
#[test]
fn bias_estimate_has_the_measured_sign_and_size_at_a_medium_face() {
    let reference = read_exr(&data("tests/data/conformance/fog-box/reference.exr")).unwrap();
    let (one, two) = (wide_fog_box(1, 150), wide_fog_box(2, 150));
    bias_along_its_own_direction("fog-box faces", &one, &two, &reference);
    let image = |px: Vec<[f32; 3]>| Image {
        width: one.width as usize,
        height: one.height as usize,
        pixels: px,
        alpha: None,
    };
    let err = |im: &Image| {
        let pixel = compare(im, &reference, None).unwrap().rel_l1;
        let blocks = compare(&block_mean(im, 4), &block_mean(&reference, 4), None);
        [pixel, blocks.unwrap().rel_l1]
    };
    let fixed = err(&image(one.image()));
    let adaptive = err(&image(one.image_with(Bandwidth::Adaptive)));
    eprintln!("fog-box: fixed {fixed:?}, adaptive {adaptive:?}");
    assert!(adaptive[0] < fixed[0] && adaptive[1] < fixed[1]);
}

/// The ratio test above for films `one` and `two` of a scene whose converged render is
/// `reference`; the 16x16 blocks that touch a pixel seeing a light are left out, as the
/// estimate leaves those pixels out.
fn bias_along_its_own_direction(what: &str, one: &Film, two: &Film, reference: &Image) {
    let as_f32 = |m: Vec<[f64; 3]>| m.iter().map(|p| p.map(|c| c as f32)).collect();
    let p = blocks16(two, as_f32(two.bias_map().unwrap()));
    let b = blocks16(one, as_f32(one.bias_map().unwrap()));
    let x = blocks16(one, one.image());
    let x2 = blocks16(two, two.image());
    let r = block_mean(reference, 16).pixels;
    let (w, bw) = (one.width as usize, one.width as usize / 16);
    let lit: Vec<usize> = (one.lights().iter())
        .map(|&i| (i as usize / w / 16) * bw + i as usize % w / 16)
        .collect();
    let (mut pp, mut pb, mut pt, mut var_pt) = (0.0, 0.0, 0.0, 0.0);
    for i in (0..p.len()).filter(|i| !lit.contains(i)) {
        for c in 0..3 {
            let w = f64::from(p[i][c]);
            pp += w * w;
            pb += w * f64::from(b[i][c]);
            pt += w * f64::from(x[i][c] - r[i][c]);
            var_pt += w * w * f64::from(x[i][c] - x2[i][c]).powi(2) / 2.0;
        }
    }
    let se = var_pt.sqrt();
    let (est, measured) = (pb / pp, pt / pp);
    let tol = 4.0 * se / pp;
    eprintln!("{what}: bias along p {est:.5}, measured {measured:.5} +- {tol:.5}");
    assert!(est > 0.0 && measured > 0.0, "the estimate's sign");
    assert!(tol < 0.25 * measured, "too noisy to tell: {tol}");
    assert!(
        est > 0.77 * (measured - tol) && est < 1.16 * (measured + tol),
        "estimated {est}, measured {measured} +- {tol}"
    );
}

/// The same for the surface photons' kernels: glass-caustic with the sharp photons' R1 at
/// 15 pixels, whatever the auto radius, so their blur of the caustic's rim dominates the
/// floor's error.
#[test]
fn bias_estimate_has_the_measured_sign_and_size_at_a_caustic_rim() {
    let reference = read_exr(&data("tests/data/conformance/glass-caustic/reference.exr")).unwrap();
    let widen = |s: &mut RenderSettings, t: &Tracer| {
        s.photon_radius = Radius::Fixed(15.0 / AUTO_PHOTON_PIXELS * t.photon_r1);
        s.smooth_photon_radius = Radius::Fixed(t.smooth_photon_r1);
    };
    let scene = "scenes/conformance/glass-caustic/scene.toml";
    let (one, two) = (widened(scene, widen, 1, 40), widened(scene, widen, 2, 40));
    bias_along_its_own_direction("glass-caustic rim", &one, &two, &reference);
}

fn ppb() -> Command {
    Command::new(env!("CARGO_BIN_EXE_ppb"))
}

/// The arguments that render smoke-grid small and fast to `out`.
fn small(out: &Path) -> Vec<String> {
    let scene = data("scenes/conformance/smoke-grid/scene.toml");
    [
        "render",
        &scene.display().to_string(),
        "-o",
        &out.display().to_string(),
        "--size",
        "48x48",
        "--light-paths",
        "3000",
        "--threads",
        "2",
        "--progress",
        "none",
    ]
    .map(String::from)
    .to_vec()
}

/// `--target-error` stops when the estimate is below the target (not before its minimum
/// passes); the stats, the EXR header and the optional error channels carry the estimate.
#[test]
fn target_error_stops_at_the_target_and_reports_the_estimate() {
    let dir = common::temp_dir("error", "target");
    let out = dir.join("t.exr");
    let stats = dir.join("t.json");
    let run = ppb()
        .args(small(&out))
        .args(["--target-error", "0.05", "--error-layer", "--stats"])
        .arg(&stats)
        .output()
        .unwrap();
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let s: serde_json::Value = serde_json::from_slice(&std::fs::read(&stats).unwrap()).unwrap();
    let e = &s["estimated_rel_l1"];
    let (pixel, passes) = (e["pixel"].as_f64().unwrap(), s["passes"].as_u64().unwrap());
    assert!(pixel < 0.05 && pixel > 0.0, "{s}");
    assert!(passes >= 4, "stopped after {passes} passes");
    let header = read_exr_text(&out).unwrap();
    let attr = |k: &str| header.iter().find(|(n, _)| n == k).map(|(_, v)| v.clone());
    let written: f64 = attr("ppb/estimated_rel_l1").unwrap().parse().unwrap();
    assert!((written - pixel).abs() < 1e-6, "{written} vs {pixel}");
    assert!(attr("ppb/estimated_rel_l1_4x4").is_some());
    // The error channels: expected absolute error, summing to about the estimate.
    let channels = exr::meta::MetaData::read_from_file(&out, false)
        .unwrap()
        .headers[0]
        .channels
        .list
        .iter()
        .map(|c| c.name.to_string())
        .collect::<Vec<_>>();
    let layer = [
        "bias.B", "bias.G", "bias.R", "error.B", "error.G", "error.R", "lambda",
    ];
    assert_eq!(channels[..3], ["B", "G", "R"]);
    assert_eq!(channels[3..], layer);
    let img = read_exr(&out).unwrap();
    assert_eq!((img.width, img.height), (48, 48));

    // A target the passes cannot reach: --passes stops first, with a warning.
    let run = ppb()
        .args(small(&dir.join("u.exr")))
        .args(["--target-error", "0.0001", "--passes", "8"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(run.status.success(), "{err}");
    assert!(
        err.contains("--passes ran out before --target-error 0.0001"),
        "{err}"
    );
}

#[test]
fn target_error_refuses_what_it_cannot_do() {
    let dir = common::temp_dir("error", "refuse");
    let out = dir.join("r.exr");
    for (extra, says) in [
        (
            vec!["--target-error", "1.5"],
            "expected a rel_l1 between 0 and 1",
        ),
        (
            vec!["--target-error", "0"],
            "expected a rel_l1 between 0 and 1",
        ),
        (
            vec!["--target-error", "0.01", "--pass-range", "0..4"],
            "cannot be used with a pass range or a task",
        ),
        (vec!["--target-on", "blocks"], "--target-error"),
    ] {
        let run = ppb().args(small(&out)).args(&extra).output().unwrap();
        let err = String::from_utf8_lossy(&run.stderr);
        assert!(
            !run.status.success() && err.contains(says),
            "{extra:?}: {err}"
        );
    }
    assert!(!out.exists());
}

/// `--bandwidth adaptive` renders with the bias in the stats and the EXR header, on the
/// CPU and on a GPU (where one is found; lavapipe in CI) alike.
#[test]
fn adaptive_bandwidth_from_the_command_line() {
    let dir = common::temp_dir("error", "adaptive");
    let (out, stats) = (dir.join("a.exr"), dir.join("a.json"));
    let run = ppb()
        .args(small(&out))
        .args([
            "--passes",
            "8",
            "--bandwidth",
            "adaptive",
            "--error-layer",
            "--stats",
        ])
        .arg(&stats)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(run.status.success(), "{err}");
    // The layer's narrowing gives back the fixed image of the same passes.
    let fixed_out = dir.join("f.exr");
    let fixed = ppb()
        .args(small(&fixed_out))
        .args(["--passes", "8"])
        .output()
        .unwrap();
    assert!(fixed.status.success());
    let channel = |name: &str| -> Vec<f32> {
        let image = exr::prelude::read_all_flat_layers_from_file(&out).unwrap();
        let c = image.layer_data[0]
            .channel_data
            .list
            .iter()
            .find(|c| c.name.to_string() == name)
            .unwrap_or_else(|| panic!("channel {name}"));
        c.sample_data.values_as_f32().collect()
    };
    let (lambda, narrowing) = (channel("lambda"), channel("narrowing.R"));
    assert!(
        lambda.iter().any(|&l| l > 0.0),
        "adaptive narrowed no pixel"
    );
    assert!(channel("bias.R").iter().any(|&b| b != 0.0));
    let want = read_exr(&fixed_out).unwrap();
    let got: Vec<f64> = channel("R")
        .iter()
        .zip(&narrowing)
        .map(|(x, n)| f64::from(*x) - f64::from(*n))
        .collect();
    let diff: f64 = got
        .iter()
        .zip(&want.pixels)
        .map(|(g, w)| (g - f64::from(w[0])).abs())
        .sum();
    let total: f64 = want.pixels.iter().map(|w| f64::from(w[0])).sum();
    assert!(
        diff < 1e-5 * total,
        "fixed image from the layer: rel_l1 {}",
        diff / total
    );
    let s: serde_json::Value = serde_json::from_slice(&std::fs::read(&stats).unwrap()).unwrap();
    let e = &s["estimated_rel_l1"];
    let (total, noise) = (
        e["pixel"].as_f64().unwrap(),
        e["noise"]["pixel"].as_f64().unwrap(),
    );
    let bias = e["bias"]["pixel"].as_f64().unwrap();
    assert!(total >= noise && total <= noise + bias, "{s}");
    let header = read_exr_text(&out).unwrap();
    let attr = |k: &str| header.iter().find(|(n, _)| n == k).map(|(_, v)| v.clone());
    assert_eq!(attr("ppb/bandwidth").as_deref(), Some("adaptive"));
    assert!(attr("ppb/estimated_bias_rel_l1").is_some());
    // Eq. 2's line on both devices, whose sums the GPU's gathered primaries share with the
    // CPU's splat (under the tube each beam piece they cross draws its own point).
    let line_args = [
        "--beam-kernel",
        "line",
        "--passes",
        "8",
        "--bandwidth",
        "adaptive",
    ];
    let line_out = dir.join("l.exr");
    let line = ppb()
        .args(small(&line_out))
        .args(line_args)
        .output()
        .unwrap();
    assert!(line.status.success());
    let gpu_out = dir.join("g.exr");
    let gpu = ppb()
        .args(small(&gpu_out))
        .args(line_args)
        .args(["--device", "gpu"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&gpu.stderr);
    if err.contains("no GPU adapter found") {
        assert!(!gpu.status.success() && !gpu_out.exists());
        return;
    }
    assert!(gpu.status.success(), "{err}");
    let (cpu_img, gpu_img) = (read_exr(&line_out).unwrap(), read_exr(&gpu_out).unwrap());
    let m = compare(&gpu_img, &cpu_img, None).unwrap();
    assert!(
        m.rel_l1 < 1e-4,
        "the GPU's adaptive image differs: {}",
        m.rel_l1
    );
}
