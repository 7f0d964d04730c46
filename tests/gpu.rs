//! The GPU beam estimate against the CPU's: the same traced pass (beams, camera segments,
//! transmittance estimates) must give the same per-pixel beam radiance on both devices
//! within float32 rounding. On a machine without an adapter these tests print why they
//! skip, unless PPB_REQUIRE_GPU=1 (CI, which installs lavapipe) makes that a failure.
mod common;

use common::gpu_or_skip;
use std::path::Path;
use std::process::Command;

use glam::Vec3;
use ppb::compare::DeviceDiff;
use ppb::core::Ray;
use ppb::estimate::beams::{BeamMap, MapNeed, Walker};
use ppb::estimate::eq2;
use ppb::estimate::eq2::{BeamKernel, BeamPiece};
use ppb::estimate::{Timings, TracedPass};
use ppb::gpu::beams::{CameraTr, GpuBeams, GpuOptions, PrimaryPath};
use ppb::majorant::Mode;
use ppb::media::{Media, MediumDesc, Phase};
use ppb::pass::Tracer;
use ppb::scene::toml::load;
use ppb::scene::Camera;
use ppb::settings::MAX_TR_SAMPLES;
use ppb::settings::{Bandwidth, TrMode};
use ppb::transport::camera::{CameraPass, Pinhole, Primary};
use ppb::transport::freepath::RatioSteps;
use ppb::transport::transmittance::SegmentTr;
use ppb::transport::{Beam, Counters};

fn data(p: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(p)
}

struct Parity {
    diff: DeviceDiff,
    evaluations: u64,
    gpu_evaluations: u64,
    secondary: usize,
}

/// Both ways of estimating primary segments on the GPU: beam quads and BVH queries.
const PRIMARY: [PrimaryPath; 2] = [PrimaryPath::Raster, PrimaryPath::Gather];

fn parity(
    scene: &str,
    (size, beams): (u32, usize),
    tr: TrMode,
    passes: &[u32],
    (primary, kernel): (PrimaryPath, BeamKernel),
) -> Option<Parity> {
    let g = gpu_or_skip(scene)?;
    let file = load(&data(scene)).expect("scene loads");
    let mut s = file.settings.clone();
    (s.width, s.height, s.light_paths, s.tr_mode) = (size, size, beams, tr);
    s.beam_kernel = Some(kernel);
    let r = Tracer::new(&file.scene, s).expect("renderer");
    let opts = GpuOptions::new(primary, CameraTr::Steps, &r.settings);
    let mut est = GpuBeams::new(g, r.media(), r.camera(), opts).expect("gpu");
    assert_eq!(est.primary(), primary);
    let mut out = Parity {
        diff: DeviceDiff::default(),
        evaluations: 0,
        gpu_evaluations: 0,
        secondary: 0,
    };
    for &i in passes {
        let t = r.trace(&r.plan().pass(i), None, MapNeed::GPU_EVERY_PASS);
        let (cpu, evals) = cpu_image(&r, &t, primary);
        est.clear().expect("clear");
        est.submit(r.view(), &t).expect("submit");
        let gpu = est.read().expect("read back").0;
        // The GPU's segments end where they leave the media, so it counts no more pairs
        // than the CPU (beyond, the terms are 0).
        let gpu_evals = gpu.iter().map(|p| p[3] as f64).sum::<f64>() as u64;
        assert!(
            gpu_evals <= evals,
            "{scene} {primary:?} pass {i}: evaluations"
        );
        out.diff.add(&cpu, &gpu);
        explain_off(&r, &t, &cpu, &gpu, &format!("{scene} {primary:?} pass {i}"));
        out.evaluations += evals;
        out.gpu_evaluations += gpu_evals;
        out.secondary += t.camera.secondary.len();
    }
    let d = &out.diff;
    eprintln!(
        "{scene} ({primary:?}): rel_l1 {:.2e}, {} of {} lit pixels off by > 1e-3, {} evaluations on the CPU, {} on the GPU, {} secondary segments",
        d.rel_l1(), d.off_pixels, d.lit_pixels, out.evaluations, out.gpu_evaluations, out.secondary
    );
    Some(out)
}

/// The CPU's beam image of pass `t` and its evaluations, with the primary segments through
/// the beam pieces when the GPU gathers them. Under the tube kernel each piece draws its
/// own point on its chord, so the splat's whole beams are another draw; under eq. 2's
/// line both give the same sums.
fn cpu_image(r: &Tracer, t: &TracedPass, primary: PrimaryPath) -> (Vec<Vec3>, u64) {
    let (mut img, mut evals) = r.beam_image(t);
    if primary == PrimaryPath::Gather && r.view().kernel == BeamKernel::Tube {
        let (splat, splat_evals) = common::splat_pass(r, t, &t.beams, BeamKernel::Tube);
        let (gathered, gathered_evals) = gathered_primaries(r, t, BeamKernel::Tube);
        for ((c, s), g) in img.iter_mut().zip(&splat).zip(&gathered) {
            *c = *c - s.l + *g;
        }
        evals = evals - splat_evals + gathered_evals;
    }
    (img, evals)
}

/// Each primary segment's beam radiance through the pass's beam pieces (the BVH gather),
/// and the evaluations.
fn gathered_primaries(r: &Tracer, t: &TracedPass, kernel: BeamKernel) -> (Vec<Vec3>, u64) {
    let map = t.beam_map.as_ref().expect("a beam map");
    let (media, bounds) = (r.media(), r.media().bounds());
    let mut evals = 0;
    let img = t
        .camera
        .primaries
        .iter()
        .map(|p| {
            let ray = Ray::new(r.camera().origin(), p.dir);
            let end = p.tr.seen_until(p.t_surf);
            let Some(t1) = ppb::estimate::beam_reach(bounds.as_ref(), &ray, end) else {
                return Vec3::ZERO;
            };
            let scatter = |x, cos| media.in_scatter(x, cos);
            let tr = |tt| ppb::transport::transmittance::camera_tr(&p.chords, &p.tr, tt);
            map.nested_radiance(&ray, (0.0, t1), kernel, scatter, tr, &mut evals)
                .l
        })
        .collect();
    (img, evals)
}

/// Prints the first pixels that differ by more than `DeviceDiff`'s 1e-3 with the pairs each
/// device counted there (the CPU's through the BVH gather): the same count points at
/// arithmetic, another at a pair decided on the other side of an edge of the rule.
fn explain_off(r: &Tracer, t: &TracedPass, cpu: &[Vec3], gpu: &[[f32; 4]], what: &str) {
    let top = cpu.iter().map(|c| c.max_element()).fold(0.0f32, f32::max);
    let off = |(c, g): &(&Vec3, &[f32; 4])| {
        (0..3).any(|k| (c[k] - g[k]).abs() > 1e-3 * c[k].abs().max(1e-3 * top))
    };
    let pixels: Vec<usize> = cpu
        .iter()
        .zip(gpu)
        .enumerate()
        .filter(|(_, p)| off(p))
        .map(|(i, _)| i)
        .take(5)
        .collect();
    if pixels.is_empty() {
        return;
    }
    let (map, media) = (
        BeamMap::build(&t.beams, t.beam_radius, Walker::Gpu),
        r.media(),
    );
    let w = r.settings.width as usize;
    for i in pixels {
        let p = &t.camera.primaries[i];
        let ray = Ray::new(r.camera().origin(), p.dir);
        let mut pairs = 0;
        let scatter = |x, cos| media.in_scatter(x, cos);
        let tr = |tt| ppb::transport::transmittance::camera_tr(&p.chords, &p.tr, tt);
        let kernel = r.view().kernel;
        map.nested_radiance(&ray, (0.0, p.t_surf), kernel, scatter, tr, &mut pairs);
        let secondary = t
            .camera
            .secondary
            .iter()
            .filter(|s| s.pixel as usize == i)
            .count();
        eprintln!(
            "{what}: pixel ({}, {}) CPU {:?} from {pairs} primary pairs (+{secondary} secondary segments), GPU {:?} from {} pairs",
            i % w, i / w, cpu[i], &gpu[i][..3], gpu[i][3]
        );
    }
}

/// Both ways of estimating primaries on `scene` against the CPU: the same image within
/// float32 rounding (`enough` checks the pass exercised what the test is for), and the
/// same pairs found by beam quads as by the BVH gather. None without an adapter.
fn both_match_cpu(
    scene: &str,
    (tr, kernel): (TrMode, BeamKernel),
    passes: &[u32],
    enough: impl Fn(&Parity) -> bool,
) -> Option<()> {
    let mut runs = Vec::new();
    for primary in PRIMARY {
        let p = parity(scene, (96, 20_000), tr, passes, (primary, kernel))?;
        assert!(enough(&p), "{scene} {primary:?}: too little exercised");
        assert!(
            p.diff.off_pixels * 1000 <= p.diff.lit_pixels,
            "{scene} {tr:?} {primary:?}: {} pixels off",
            p.diff.off_pixels
        );
        assert!(
            p.diff.rel_l1() < 1e-5,
            "{scene} {tr:?} {primary:?}: rel_l1 {}",
            p.diff.rel_l1()
        );
        runs.push(p);
    }
    let [raster, gather] = &runs[..] else {
        unreachable!("two runs")
    };
    // The line's crossing lies on one piece of a beam; the tube's chord may cross several.
    match kernel {
        BeamKernel::Line => assert_eq!(
            raster.gpu_evaluations, gather.gpu_evaluations,
            "{scene} {tr:?}: pairs found by beam quads and by the gather"
        ),
        BeamKernel::Tube => assert!(
            raster.gpu_evaluations <= gather.gpu_evaluations,
            "{scene} {tr:?}: pairs found by beam quads and by the gather"
        ),
    }
    Some(())
}

/// Heterogeneous media: grid lookups, ratio-tracking steps and the splat vs BVH query.
#[test]
fn gpu_matches_cpu_on_smoke_grid() {
    let scene = "scenes/conformance/smoke-grid/scene.toml";
    for tr in [TrMode::Ratio, TrMode::Random] {
        both_match_cpu(scene, (tr, BeamKernel::Line), &[1, 7], |p| {
            p.evaluations > 100_000 && p.diff.lit_pixels > 3000
        });
    }
}

/// A grid with tiles (the cloud's dense core), which the leaf table's slots name; both
/// kernels (the tube is the hybrid default there: HG g = 0.7).
#[test]
fn gpu_matches_cpu_on_cloud_tiles() {
    let scene = "scenes/conformance/cloud-hg/scene.toml";
    for kernel in [BeamKernel::Line, BeamKernel::Tube] {
        both_match_cpu(scene, (TrMode::Ratio, kernel), &[1, 7], |p| {
            p.evaluations > 50_000 && p.diff.lit_pixels > 1000
        });
    }
}

/// Glass: camera segments after refraction and reflection, weighted by Fresnel; both
/// kernels.
#[test]
fn gpu_matches_cpu_on_glass_caustic() {
    let scene = "scenes/conformance/glass-caustic/scene.toml";
    for kernel in [BeamKernel::Line, BeamKernel::Tube] {
        both_match_cpu(scene, (TrMode::Ratio, kernel), &[1, 3], |p| {
            p.secondary > 1000 && p.evaluations > 500_000
        });
    }
}

/// `--gpu-primary auto` measures: a session rasterises pass 1, gathers pass 2, then keeps
/// one of them (its stats say which, auto until then), and its image is the CPU's within
/// float32 rounding throughout, with pipelining and a read-back mid-way.
#[test]
fn auto_primary_picks_by_measurement() {
    use ppb::session::{Flow, Session};
    let scene = "scenes/conformance/smoke-grid/scene.toml";
    let Some(g) = gpu_or_skip(scene) else {
        return;
    };
    let file = load(&data(scene)).expect("scene loads");
    let mut s = file.settings.clone();
    (s.width, s.height, s.light_paths) = (96, 96, 20_000);
    s.beam_kernel = Some(BeamKernel::Line);
    let tracer = || Tracer::new(&file.scene, s.clone()).expect("renderer");
    let mut gpu =
        Session::open(tracer(), Some(g), PrimaryPath::Auto, CameraTr::Steps).expect("gpu session");
    let mut cpu = Session::cpu(tracer());
    let primary = |s: &Session| s.gpu_stats().and_then(|g| g.primary);
    gpu.render(2).expect("gpu passes 1-2");
    assert_eq!(
        primary(&gpu),
        Some(PrimaryPath::Auto),
        "no choice before both are timed"
    );
    let early = gpu.image().expect("gpu image");
    let more = |s: &mut Session| {
        s.run(3..=6, |_, _| Ok::<_, ppb::error::Error>(Flow::Continue))
            .expect("passes 3-6");
        s.image().expect("image")
    };
    let late = more(&mut gpu);
    let chosen = primary(&gpu);
    assert!(
        matches!(chosen, Some(PrimaryPath::Raster | PrimaryPath::Gather)),
        "{chosen:?}"
    );
    let cpu_early = cpu.render(2).expect("cpu passes 1-2");
    let cpu_late = more(&mut cpu);
    for (g, c, when) in [
        (&early, &cpu_early, "2 passes"),
        (&late, &cpu_late, "6 passes"),
    ] {
        let m = ppb::compare::compare(g, c, None).expect("same size");
        eprintln!(
            "auto ({chosen:?}) after {when}: rel_l1 against the CPU {:.2e}",
            m.rel_l1
        );
        assert!(m.rel_l1 < 1e-5, "{when}: rel_l1 {}", m.rel_l1);
    }
    // The GPU keeps odd and even passes' beam sums apart, as the CPU's film does: the error
    // estimates (the halves' difference, a few % of the image) agree within the rounding.
    let (ge, ce) = (gpu.error_estimate(), cpu.error_estimate());
    let (ge, ce) = (
        ge.expect("gpu").expect("6 passes"),
        ce.expect("cpu").expect("6 passes"),
    );
    eprintln!("error estimate after 6 passes: gpu {ge:?}, cpu {ce:?}");
    let (gb, cb) = (ge.bias.expect("gpu nested sums"), ce.bias.expect("cpu"));
    for (g, c) in [
        (ge.pixel, ce.pixel),
        (ge.block, ce.block),
        (ge.noise.pixel, ce.noise.pixel),
        (gb.pixel, cb.pixel),
    ] {
        assert!(c > 0.0 && (g / c - 1.0).abs() < 1e-2, "gpu {g} cpu {c}");
    }
    // The nested sums agree too: the adaptive images (each pixel's radius chosen from
    // them) and the bias maps.
    let (gf, cf) = (gpu.film().expect("gpu film"), cpu.film().expect("cpu film"));
    let image = |f: &ppb::film::Film, px| ppb::output::Image {
        width: f.width as usize,
        height: f.height as usize,
        pixels: px,
        alpha: None,
    };
    let adaptive = |f: &ppb::film::Film| image(f, f.image_with(Bandwidth::Adaptive));
    let m = ppb::compare::compare(&adaptive(&gf), &adaptive(&cf), None).expect("same size");
    eprintln!("adaptive images: rel_l1 {:.2e}", m.rel_l1);
    assert!(m.rel_l1 < 1e-4, "adaptive: rel_l1 {}", m.rel_l1);
    let (gm, cm) = (gf.bias_map().expect("gpu"), cf.bias_map().expect("cpu"));
    let diff: f64 = gm
        .iter()
        .zip(&cm)
        .flat_map(|(g, c)| (0..3).map(move |k| (g[k] - c[k]).abs()))
        .sum();
    let total: f64 = cm.iter().flatten().map(|c| c.abs()).sum();
    eprintln!("bias maps: rel_l1 {:.2e}", diff / total);
    assert!(diff < 1e-3 * total, "bias maps differ: {}", diff / total);
}

/// Long BVH walks: fog-box's pure method at 128x128 with 100k light paths sends hundreds of
/// crossings and thousands of BVH nodes through each primary segment, past what a software
/// adapter runs in one invocation (lavapipe and llvmpipe end its loops after 65,535
/// iterations). With the walk split into rounds (the default budget) the gather matches the
/// CPU, as do the quads; with one unbounded round, a software adapter's cut walk must be
/// refused with an error naming the limit, never returned as sums (hardware: a match).
/// cloud-hg at full size (tiles: many loop iterations per crossing) needs rounds with a
/// halved budget on lavapipe; its gather must match too.
#[test]
fn long_walks_match_the_cpu_and_a_cut_one_is_an_error() {
    let Some(g) = gpu_or_skip("cloud-hg") else {
        return;
    };
    let file = load(&data("scenes/conformance/cloud-hg/scene.toml")).expect("scene loads");
    let mut s = file.settings.clone();
    s.method = ppb::settings::Method::Ppb;
    s.beam_kernel = Some(BeamKernel::Line);
    let r = Tracer::new(&file.scene, s).expect("renderer");
    let t = r.trace(&r.plan().pass(1), None, MapNeed::GPU_EVERY_PASS);
    let (cpu, _) = r.beam_image(&t);
    let opts = GpuOptions::new(PrimaryPath::Gather, CameraTr::Steps, &r.settings);
    let mut est = GpuBeams::new(g, r.media(), r.camera(), opts).expect("gpu");
    est.submit(r.view(), &t).expect("submit");
    let mut diff = DeviceDiff::default();
    let gpu = est.read().expect("cloud-hg gathered").0;
    diff.add(&cpu, &gpu);
    explain_off(&r, &t, &cpu, &gpu, "cloud-hg gathered");
    eprintln!(
        "cloud-hg gathered: rel_l1 against the CPU {:.2e}",
        diff.rel_l1()
    );
    assert!(diff.rel_l1() < 1e-5, "cloud-hg: rel_l1 {}", diff.rel_l1());

    let scene = "scenes/conformance/fog-box/scene.toml";
    let Some(g) = gpu_or_skip(scene) else {
        return;
    };
    let file = load(&data(scene)).expect("scene loads");
    let mut s = file.settings.clone();
    (s.width, s.height, s.light_paths) = (128, 128, 100_000);
    s.method = ppb::settings::Method::Ppb;
    s.beam_kernel = Some(BeamKernel::Line);
    let r = Tracer::new(&file.scene, s).expect("renderer");
    let t = r.trace(&r.plan().pass(1), None, MapNeed::GPU_EVERY_PASS);
    let (cpu, _) = r.beam_image(&t);
    let software = g.info.device_type == wgpu::DeviceType::Cpu;
    let runs = [
        (PrimaryPath::Raster, None),
        (PrimaryPath::Gather, None),
        (PrimaryPath::Gather, Some(u32::MAX)),
    ];
    for (primary, walk_budget) in runs {
        let opts = GpuOptions {
            walk_budget,
            ..GpuOptions::new(primary, CameraTr::Steps, &r.settings)
        };
        let mut est = GpuBeams::new(g.clone(), r.media(), r.camera(), opts).expect("gpu");
        est.submit(r.view(), &t).expect("submit");
        let one_round = walk_budget.is_some();
        match est.read() {
            Ok((gpu, _)) => {
                let mut diff = DeviceDiff::default();
                diff.add(&cpu, &gpu);
                eprintln!(
                    "{primary:?}, budget {walk_budget:?}: rel_l1 against the CPU {:.2e}",
                    diff.rel_l1()
                );
                assert!(
                    !(software && one_round),
                    "a software adapter ran the whole walk"
                );
                assert!(
                    diff.rel_l1() < 1e-5,
                    "{primary:?}: rel_l1 {}",
                    diff.rel_l1()
                );
            }
            Err(e) => {
                eprintln!("{primary:?}, budget {walk_budget:?}: {e}");
                assert!(
                    software && one_round,
                    "{primary:?} on {}: {e}",
                    g.describe()
                );
                assert!(e.to_string().contains("ended a shader loop"), "{e}");
            }
        }
    }
}

/// Eq. 2's edge rule (`estimate::eq2::term`: t in [0, t_surf), s in [0, length), d < r)
/// on both devices: one pixel, one camera segment (+x from the origin) and one beam per
/// pass, the beam crossing the segment on an edge of the rule or just inside or outside
/// it. Where the rule excludes the pair the GPU adds exactly nothing (no evaluation
/// either); where it counts, one evaluation and the CPU term within float32 rounding. The
/// camera transmittance has a box share and a grid estimate with a step exactly at the
/// crossing (a ratio step, a free path ending there).
#[test]
fn gpu_pair_rule_matches_cpu_on_edge_cases() {
    const R: f32 = 0.25;
    const EPS: f32 = 1.0 / 1024.0;
    const T_SURF: f32 = 2.0;
    let Some(g) = gpu_or_skip("gpu_pair_rule_matches_cpu_on_edge_cases") else {
        return;
    };
    let media = one_pixel_fog(0.3);
    // One pixel looking down +x. The rule is the shader's `piece_radiance`, which beam
    // quads share; they are not drawn here, since the splat's camera clip (as on the CPU)
    // drops beams at the camera's depth, the t = 0 cases.
    let mut est = one_pixel_estimator(g, &media);
    let ray = Ray::new(Vec3::ZERO, Vec3::X);
    let power = Vec3::new(3.0, 5.0, 7.0);
    // A beam along +z crossing the camera ray at t = tx, s = s_at, distance |dy| (exact).
    let beam = |tx: f32, dy: f32, s_at: f32, len: f32| {
        Beam::new(Vec3::new(tx, dy, -s_at), Vec3::Z, len, power)
    };
    // An oblique beam crossing at t = tx, s = 1, distance 0.1 along w x psi.
    let oblique = |tx: f32, psi: Vec3| {
        let off = Vec3::X.cross(psi).normalize() * 0.1;
        Beam::new(Vec3::new(tx, 0.0, 0.0) + off - psi, psi, 1.5, power)
    };
    let ratio = SegmentTr::Ratio(RatioSteps::from_slice(&[(0.5, 0.5), (1.0, 0.25)]));
    let mut lengths = [f32::INFINITY; MAX_TR_SAMPLES];
    (lengths[0], lengths[1]) = (1.0, 0.5);
    let free = SegmentTr::FreePaths { lengths, m: 4 };
    let clear = SegmentTr::Clear;
    let cases = [
        (
            "t = 0, the segment start",
            beam(0.0, 0.1, 0.5, 1.0),
            &clear,
            true,
        ),
        ("t just before 0", beam(-EPS, 0.1, 0.5, 1.0), &clear, false),
        ("t just after 0", beam(EPS, 0.1, 0.5, 1.0), &clear, true),
        ("t = t_surf", beam(T_SURF, 0.1, 0.5, 1.0), &clear, false),
        (
            "t just before t_surf",
            beam(T_SURF - EPS, 0.1, 0.5, 1.0),
            &clear,
            true,
        ),
        (
            "s = 0, the beam origin",
            beam(1.0, 0.1, 0.0, 1.0),
            &clear,
            true,
        ),
        ("s just before 0", beam(1.0, 0.1, -EPS, 1.0), &clear, false),
        (
            "s = length, the beam end",
            beam(1.0, 0.1, 1.0, 1.0),
            &clear,
            false,
        ),
        (
            "s just before length",
            beam(1.0, 0.1, 1.0 - EPS, 1.0),
            &clear,
            true,
        ),
        (
            "s just past length",
            beam(1.0, 0.1, 1.0 + EPS, 1.0),
            &clear,
            false,
        ),
        (
            "s on a cut between pieces",
            beam(1.0, 0.1, 3.0, 12.0),
            &clear,
            true,
        ),
        (
            "s = length of 4 pieces",
            beam(1.0, 0.1, 12.0, 12.0),
            &clear,
            false,
        ),
        ("d = r", beam(1.0, R, 0.5, 1.0), &clear, false),
        ("d = r, other side", beam(1.0, -R, 0.5, 1.0), &clear, false),
        (
            "d just inside r",
            beam(1.0, R - EPS, 0.5, 1.0),
            &clear,
            true,
        ),
        (
            "d just outside r",
            beam(1.0, R + EPS, 0.5, 1.0),
            &clear,
            false,
        ),
        ("d = 0", beam(1.0, 0.0, 0.5, 1.0), &clear, true),
        ("ratio step at t", beam(1.0, 0.1, 0.5, 1.0), &ratio, true),
        (
            "between ratio steps",
            beam(0.75, 0.1, 0.5, 1.0),
            &ratio,
            true,
        ),
        ("free path ends at t", beam(1.0, 0.1, 0.5, 1.0), &free, true),
        (
            "free paths: one ended",
            beam(0.75, 0.1, 0.5, 1.0),
            &free,
            true,
        ),
        (
            "oblique",
            oblique(1.5, Vec3::new(0.6, 0.0, 0.8)),
            &ratio,
            true,
        ),
        (
            "oblique, back",
            oblique(0.25, Vec3::new(-0.48, 0.6, 0.64)),
            &free,
            true,
        ),
    ];
    let chords = media.chords(&ray);
    for (name, b, tr, counts) in cases {
        let cpu = eq2::term(
            &ray,
            (0.0, T_SURF),
            &BeamPiece::whole(&b),
            R,
            |x, cos| media.in_scatter(x, cos),
            |t| ppb::transport::transmittance::camera_tr(&chords, tr, t),
        );
        assert_eq!(cpu.is_some(), counts, "{name}: the CPU rule");
        let gpu = one_pixel_on_gpu(&mut est, &media, ray.d, T_SURF, tr, b, R);
        match cpu {
            None => assert_eq!(gpu, [0.0; 4], "{name}: the GPU counted it"),
            Some(c) => {
                assert_eq!(gpu[3], 1.0, "{name}: GPU evaluations");
                for k in 0..3 {
                    let rel = (gpu[k] - c[k]).abs() / c[k];
                    assert!(c[k] > 0.0 && rel < 1e-5, "{name}: {gpu:?} vs {c}");
                }
            }
        }
    }
}

/// The tube's pair on both devices where its chord is hardest to round alike: beams turned
/// to within 1e-5 to 0.3 radians of the camera segment (end-on, both ways), passing 0 to
/// 1.2 r from it, some crossing the segment's end. Each pair counts on the GPU exactly
/// where it does on the CPU (the CPU's gather over the beam's pieces), with the CPU's
/// term within float32 rounding of the chord (1e-4); a chord of the exactly parallel
/// beam does not count.
#[test]
fn gpu_tube_matches_cpu_end_on() {
    const R: f32 = 0.1;
    const T_SURF: f32 = 2.0;
    let Some(g) = gpu_or_skip("gpu_tube_matches_cpu_end_on") else {
        return;
    };
    let media = one_pixel_fog(0.7);
    let mut est = one_pixel_estimator(g, &media);
    let ray = Ray::new(Vec3::ZERO, Vec3::X);
    let chords = media.chords(&ray);
    let tr = SegmentTr::Ratio(RatioSteps::from_slice(&[(0.7, 0.5), (1.3, 0.25)]));
    let (mut counted, mut checked) = (0, 0);
    for (i, tilt) in [0.0f32, 1e-5, 1e-4, 1e-3, 1e-2, 0.1, 0.3]
        .into_iter()
        .enumerate()
    {
        for (j, off) in [0.0f32, 0.03, 0.07, 0.099, 0.12].into_iter().enumerate() {
            for (k, (start, len)) in [(0.5f32, 0.6f32), (1.6, 0.8), (0.2, 0.05)]
                .into_iter()
                .enumerate()
            {
                let side = if (i + j + k) % 2 == 0 { 1.0 } else { -1.0 };
                let psi = (Vec3::X * side + Vec3::Z * tilt).normalize();
                let y = Vec3::new(start, off, 0.0) - psi * (0.5 * len) * side.min(0.0).abs();
                let b = Beam::new(y, psi, len, Vec3::new(3.0, 5.0, 7.0));
                let map = BeamMap::build(&[b], R, Walker::Gpu);
                let mut evals = 0;
                let cpu = map.nested_radiance(
                    &ray,
                    (0.0, T_SURF),
                    BeamKernel::Tube,
                    |x, cos| media.in_scatter(x, cos),
                    |t| ppb::transport::transmittance::camera_tr(&chords, &tr, t),
                    &mut evals,
                );
                let gpu = one_pixel_under(
                    BeamKernel::Tube,
                    &mut est,
                    &media,
                    (ray.d, T_SURF, &tr),
                    b,
                    R,
                );
                let what = format!("tilt {tilt}, offset {off}, beam {start} + {len}");
                assert_eq!(gpu[3] as u64, evals, "{what}: evaluations");
                if tilt == 0.0 {
                    assert_eq!(evals, 0, "{what}: a parallel beam counted");
                }
                checked += 1;
                if evals > 0 && cpu.l.max_element() > 0.0 {
                    counted += 1;
                    for c in 0..3 {
                        let rel = (gpu[c] - cpu.l[c]).abs() / cpu.l[c];
                        assert!(rel < 1e-4, "{what}: {gpu:?} vs {}", cpu.l);
                    }
                }
            }
        }
    }
    eprintln!("{counted} of {checked} pairs counted");
    assert!(counted > 30 && counted < checked, "{counted} of {checked}");
}

/// The fog box around [`one_pixel_camera`] (16 m wide, sigma_t 0.5) with HG phase `g`.
fn one_pixel_fog(g: f32) -> Media {
    Media::new(vec![MediumDesc {
        bounds: [Vec3::splat(-8.0), Vec3::splat(8.0)],
        sigma_t: 0.5,
        albedo: Vec3::new(0.8, 0.6, 0.4),
        phase: Phase { g },
    }])
}

/// One pixel looking down +x from the origin.
fn one_pixel_camera() -> Pinhole {
    let camera = Camera {
        origin: Vec3::ZERO,
        target: Vec3::X,
        up: Vec3::Y,
        vfov_deg: 30.0,
    };
    Pinhole::new(&camera, 1, 1)
}

/// A GPU estimator of [`one_pixel_camera`], primaries gathered.
fn one_pixel_estimator(g: ppb::gpu::Gpu, media: &Media) -> GpuBeams {
    let camera = one_pixel_camera();
    let opts = GpuOptions {
        primary: PrimaryPath::Gather,
        camera_tr: CameraTr::Steps,
        seed: 0,
        free_path: Mode::Adaptive,
        walk_budget: None,
    };
    GpuBeams::new(g, media, &camera, opts).expect("gpu")
}

/// The GPU estimate of one pixel whose primary segment runs along `dir` for `t_surf`
/// with grid transmittance `tr`, and one beam `b` of radius `r` under eq. 2's line:
/// (RGB, evaluations).
fn one_pixel_on_gpu(
    est: &mut GpuBeams,
    media: &Media,
    dir: Vec3,
    t_surf: f32,
    tr: &SegmentTr,
    b: Beam,
    r: f32,
) -> [f32; 4] {
    one_pixel_under(BeamKernel::Line, est, media, (dir, t_surf, tr), b, r)
}

/// [`one_pixel_on_gpu`] under `kernel`.
fn one_pixel_under(
    kernel: BeamKernel,
    est: &mut GpuBeams,
    media: &Media,
    (dir, t_surf, tr): (Vec3, f32, &SegmentTr),
    b: Beam,
    r: f32,
) -> [f32; 4] {
    let pass = TracedPass {
        index: 1,
        odd: true,
        camera: CameraPass {
            image: vec![Vec3::ZERO],
            nested: vec![Vec3::ZERO],
            alpha: Vec::new(),
            primaries: vec![Primary {
                dir,
                t_surf,
                tr: tr.clone(),
                // The camera of `one_pixel_estimator` sits at the origin.
                chords: media.chords(&Ray::new(Vec3::ZERO, dir)),
            }],
            secondary: Vec::new(),
            counters: Counters::default(),
        },
        beam_map: Some(BeamMap::build(&[b], r, Walker::Gpu)),
        beams: vec![b],
        beam_radius: r,
        counters: Counters::default(),
        timings: Timings::default(),
    };
    let camera = one_pixel_camera();
    let view = ppb::estimate::View {
        camera: &camera,
        media,
        kernel,
    };
    est.clear().expect("clear");
    est.submit(view, &pass).expect("submit");
    est.read().expect("read back").0[0]
}

/// The ray-box rule on both devices (`core::ray_box` and the WGSL's `slab`, one 1/d rule):
/// a camera segment lying in the plane two medium boxes share is in the box above it
/// (whose lower face the plane is) and not in the one below; one just off a face is
/// outside. The CPU's camera transmittance counts exactly the box above, and the GPU's
/// estimate equals the CPU's.
#[test]
fn gpu_box_rule_matches_cpu_for_rays_in_a_face() {
    const R: f32 = 0.25;
    const T_SURF: f32 = 2.0;
    let Some(g) = gpu_or_skip("gpu_box_rule_matches_cpu_for_rays_in_a_face") else {
        return;
    };
    let fog = |lo: [f32; 3], hi: [f32; 3], sigma_t: f32| MediumDesc {
        bounds: [Vec3::from(lo), Vec3::from(hi)],
        sigma_t,
        albedo: Vec3::new(0.8, 0.6, 0.4),
        phase: Phase { g: 0.3 },
    };
    let media = Media::new(vec![
        // The ray (y = z = 0) lies in the lower face y = 0 of this box ...
        fog([-8.0, 0.0, -8.0], [8.0, 8.0, 8.0], 0.5),
        // ... in the upper face y = 0 of this one ...
        fog([-8.0, -8.0, -8.0], [8.0, 0.0, 8.0], 0.25),
        // ... and just off the face y = 1e-3 of this one.
        fog([-8.0, 1e-3, -8.0], [8.0, 8.0, 8.0], 4.0),
    ]);
    let mut est = one_pixel_estimator(g, &media);
    let ray = Ray::new(Vec3::ZERO, Vec3::X);
    let chords = media.chords(&ray);
    let tr = |t| ppb::transport::transmittance::camera_tr(&chords, &SegmentTr::Clear, t);
    for t in [0.5f32, 1.0, 1.75] {
        let want = (-0.5 * t).exp();
        assert!(
            (tr(t) - want).abs() < 1e-6,
            "CPU Tr({t}) = {} vs {want}",
            tr(t)
        );
    }
    let b = Beam::new(
        Vec3::new(1.0, 0.1, -0.5),
        Vec3::Z,
        1.0,
        Vec3::new(3.0, 5.0, 7.0),
    );
    let cpu = eq2::term(
        &ray,
        (0.0, T_SURF),
        &BeamPiece::whole(&b),
        R,
        |x, cos| media.in_scatter(x, cos),
        tr,
    )
    .expect("the pair counts");
    let gpu = one_pixel_on_gpu(&mut est, &media, ray.d, T_SURF, &SegmentTr::Clear, b, R);
    assert_eq!(gpu[3], 1.0, "GPU evaluations");
    for k in 0..3 {
        let rel = (gpu[k] - cpu[k]).abs() / cpu[k];
        assert!(cpu[k] > 0.0 && rel < 1e-5, "{gpu:?} vs {cpu}");
    }
}

/// The command line: `--device gpu` renders, says which adapter, and the stats file
/// records the GPU time and its overlap with tracing; a backend that does not exist here
/// gives one clear error line, not a panic.
#[test]
fn render_on_gpu_from_the_command_line() {
    if gpu_or_skip("render_on_gpu_from_the_command_line").is_none() {
        return;
    }
    let dir = common::temp_dir("gpu", "cli");
    let out = dir.join("smoke.exr");
    let args = [
        "--device",
        "gpu",
        "--size",
        "32x32",
        "--passes",
        "6",
        "--light-paths",
        "2000",
    ];
    let json = render_with_stats(&dir, "smoke-grid", &args, &out);
    let g = &json["gpu"];
    assert_eq!(g["passes"], 6, "{json}");
    assert!(g["estimate_seconds"].as_f64().unwrap() > 0.0);
    assert!(g["overlap_seconds"].as_f64().is_some());
    assert!(json["device"].as_str().unwrap() != "cpu");
    let img = ppb::output::read_exr(&out).unwrap();
    assert!(img.pixels.iter().any(|p| p[0] > 0.0));

    let none = Command::new(env!("CARGO_BIN_EXE_ppb"))
        .env(
            "WGPU_BACKEND",
            if cfg!(target_os = "macos") {
                "dx12"
            } else {
                "metal"
            },
        )
        .args([
            "render", "--device", "gpu", "--size", "8x8", "--passes", "1", "--quiet",
        ])
        .arg("-o")
        .arg(dir.join("none.exr"))
        .arg(data("scenes/conformance/fog-box/scene.toml"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&none.stderr);
    assert_eq!(none.status.code(), Some(2), "{err}");
    assert!(
        err.contains("no GPU adapter") && err.lines().count() == 1,
        "{err}"
    );
    assert!(!dir.join("none.exr").exists());
    let _ = std::fs::remove_dir_all(&dir);
}

/// `ppb render` of conformance scene `scene` with `args`, its cache in `dir`, into `out`;
/// it must succeed. Returns its `--stats`.
fn render_with_stats(dir: &Path, scene: &str, args: &[&str], out: &Path) -> serde_json::Value {
    let stats = out.with_extension("json");
    let run = Command::new(env!("CARGO_BIN_EXE_ppb"))
        .arg("render")
        .args(args)
        .args(["--quiet", "--cache-dir"])
        .arg(dir.join("cache"))
        .arg("-o")
        .arg(out)
        .arg("--stats")
        .arg(&stats)
        .arg(data(&format!("scenes/conformance/{scene}/scene.toml")))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(run.status.success(), "{err}");
    serde_json::from_str(&std::fs::read_to_string(&stats).unwrap()).unwrap()
}

/// `ppb render` of cloud-hg on the GPU with the default kernel: the tube (its HG g = 0.7),
/// said so by `--stats` and the EXR header, and, with primaries rasterised (whole beams, as
/// the CPU's splat), the image of the same render on the CPU within float32 rounding.
#[test]
fn gpu_renders_the_tube_from_the_command_line() {
    if gpu_or_skip("gpu_renders_the_tube_from_the_command_line").is_none() {
        return;
    }
    let dir = common::temp_dir("gpu", "tube");
    let render = |device: &str| {
        let out = dir.join(format!("{device}.exr"));
        let args = [
            "--device",
            device,
            "--gpu-primary",
            "raster",
            "--size",
            "48x32",
        ];
        let args = [&args[..], &["--passes", "4", "--light-paths", "20000"]].concat();
        let json = render_with_stats(&dir, "cloud-hg", &args, &out);
        assert_eq!(json["beam_kernel"], "tube", "{device}: {json}");
        let header = ppb::output::read_exr_text(&out).unwrap();
        let kernel = header.iter().find(|(k, _)| k == "ppb/beam_kernel");
        assert_eq!(kernel.map(|(_, v)| v.as_str()), Some("tube"), "{device}");
        ppb::output::read_exr(&out).unwrap()
    };
    let (cpu, gpu) = (render("cpu"), render("gpu"));
    let m = ppb::compare::compare(&gpu, &cpu, None).unwrap();
    eprintln!("cloud-hg, tube: GPU against CPU rel_l1 {:.2e}", m.rel_l1);
    assert!(
        m.rel_l1 < 1e-5,
        "the GPU's tube image differs: {}",
        m.rel_l1
    );
    let _ = std::fs::remove_dir_all(&dir);
}
