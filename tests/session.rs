//! The one render pipeline: a pass is defined by its index alone, every command that
//! renders drives a session, and `ppb watch` estimates beams on the GPU like `ppb render`.
mod common;

use common::{floor_scene, gpu_or_skip, write_floor};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use ppb::error::Result;
use ppb::estimate::beams::MapNeed;
use ppb::estimate::Estimator;
use ppb::estimate::{cpu, TracedPass, View};
use ppb::film::Film;
use ppb::pass::Tracer;
use ppb::scene::toml::load;
use ppb::session::{Flow, Session};
use ppb::settings::TrMode;

fn data(p: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(p)
}

/// Per pass: its index, camera image and CPU beam image, as the estimator saw them.
type Seen = Arc<Mutex<Vec<(u32, Vec<[f32; 3]>, Vec<[f32; 3]>)>>>;

/// An estimator that records each pass it is handed (and adds nothing to the film).
struct Recorder(Seen);

impl Estimator for Recorder {
    fn describe(&self) -> String {
        "recorder".into()
    }
    fn beam_map(&self) -> MapNeed {
        MapNeed::CPU
    }
    fn estimate(
        &mut self,
        view: View,
        t: &TracedPass,
        _film: &mut Film,
        _traced: (Instant, Instant),
    ) -> Result<u64> {
        let rgb = |v: &[glam::Vec3]| v.iter().map(|p| p.to_array()).collect::<Vec<_>>();
        let (beams, evals) = cpu::beam_image(view, t);
        self.0
            .lock()
            .unwrap()
            .push((t.index, rgb(&t.camera.image), rgb(&beams)));
        Ok(evals)
    }
    fn held(&mut self) -> Result<Option<ppb::film::Held>> {
        Ok(None)
    }
    fn clear(&mut self) -> Result<()> {
        Ok(())
    }
}

/// smoke-grid at 24x24 with `tr` transmittance (stratified: blocks of 4 passes, 2 strata).
fn tracer(tr: TrMode) -> Tracer {
    let file = load(&data("scenes/conformance/smoke-grid/scene.toml")).expect("scene");
    let mut s = file.settings.clone();
    (s.width, s.height, s.light_paths, s.tr_mode) = (24, 24, 3000, tr);
    (s.tr_block, s.tr_samples) = (4, 2);
    Tracer::new(&file.scene, s).expect("tracer")
}

/// Pass 7 rendered alone equals pass 7 inside a render of passes 1..=8, bit for bit: with
/// stratified transmittance it sits mid-block and mid-cycle, so its free paths and the
/// order it uses them must follow from its index, not from the passes before it.
#[test]
fn a_pass_alone_equals_the_same_pass_inside_a_longer_render() {
    for tr in [TrMode::Stratified, TrMode::Ratio, TrMode::Random] {
        let long: Seen = Arc::default();
        let mut s = Session::new(tracer(tr), Box::new(Recorder(long.clone())));
        s.run(1..=8, |_, _| Ok::<_, ppb::error::Error>(Flow::Continue))
            .expect("render");
        let alone: Seen = Arc::default();
        let mut s = Session::new(tracer(tr), Box::new(Recorder(alone.clone())));
        let p = s.plan().pass(7);
        s.pass(&p).expect("pass 7");
        let long = long.lock().unwrap();
        let alone = alone.lock().unwrap();
        let inside = long.iter().find(|r| r.0 == 7).expect("pass 7 ran");
        assert_eq!(alone.len(), 1);
        assert!(inside.1.iter().any(|p| p[0] > 0.0), "{tr:?}: a lit image");
        assert!(inside.2.iter().any(|p| p[0] > 0.0), "{tr:?}: beams seen");
        assert!(
            alone[0].1 == inside.1,
            "{tr:?}: camera image of pass 7 differs"
        );
        assert!(
            alone[0].2 == inside.2,
            "{tr:?}: beam image of pass 7 differs"
        );
        // Another pass of the same render differs (the test can fail).
        assert!(long.iter().find(|r| r.0 == 8).unwrap().1 != inside.1);
    }
}

/// Runs `ppb watch --no-ramp --passes 4` on `device` until it says the passes are done;
/// returns the written image and the error estimate in its header.
fn watch_image(dir: &Path, scene: &Path, device: &str) -> (ppb::output::Image, f64) {
    let out = dir.join(format!("{device}.exr"));
    let mut child = Command::new(env!("CARGO_BIN_EXE_ppb"))
        .arg("watch")
        .arg(scene)
        .arg("-o")
        .arg(&out)
        .args([
            "--device",
            device,
            "--no-ramp",
            "--passes",
            "4",
            "--seed",
            "5",
        ])
        .args(["--checkpoint", "1", "--threads", "2"])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("starting ppb watch");
    let stderr = child.stderr.take().unwrap();
    let lines: Arc<Mutex<Vec<String>>> = Arc::default();
    let sink = lines.clone();
    std::thread::spawn(move || {
        use std::io::BufRead;
        for l in std::io::BufReader::new(stderr)
            .lines()
            .map_while(|l| l.ok())
        {
            sink.lock().unwrap().push(l);
        }
    });
    let start = Instant::now();
    let log = || lines.lock().unwrap().join("\n");
    while !log().contains("4 passes done") {
        let exited = child.try_wait().unwrap().is_some();
        assert!(
            !exited && start.elapsed() < Duration::from_secs(120),
            "{}",
            log()
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    let _ = child.kill();
    let _ = child.wait();
    let log = log();
    let want = if device == "gpu" {
        "on the GPU"
    } else {
        "on the CPU"
    };
    assert!(log.contains(want), "{log}");
    let header = ppb::output::read_exr_text(&out).expect("the watch output's header");
    let estimate = header
        .iter()
        .find(|(k, _)| k == "ppb/estimated_rel_l1")
        .map(|(_, v)| v.parse().expect("a number"))
        .expect("an error estimate after 4 passes");
    (
        ppb::output::read_exr(&out).expect("the watch output"),
        estimate,
    )
}

/// `ppb watch --device gpu` (lavapipe on CI) gives `--device cpu`'s image for the same
/// seed and passes, within float32 accumulation (the GPU parity tests' bound).
#[test]
fn watch_on_the_gpu_matches_watch_on_the_cpu() {
    if gpu_or_skip("watch_on_the_gpu_matches_watch_on_the_cpu").is_none() {
        return;
    }
    let dir = common::temp_dir("session", "watch-gpu");
    write_floor(&dir);
    let fog = "[[light]]\ntype = \"point\"\nposition = [0, 2.6, 0]\nintensity = [20, 20, 20]\n\n\
               [[medium]]\ntype = \"homogeneous\"\nbounds = [[-1, 0.25, -1], [1, 1.75, 1]]\n\
               sigma_t = 1.0\nalbedo = [0.8, 0.8, 0.8]\n";
    let scene = dir.join("scene.toml");
    // Eq. 2's line, whose sums the GPU's gathered primaries share with the CPU's splat
    // (under the tube each beam piece they cross draws its own point on its chord).
    let render =
        "width = 32\nheight = 24\npasses = 100\nlight_paths = 4000\nbeam_kernel = \"line\"";
    std::fs::write(&scene, floor_scene(render, 0.5, fog)).unwrap();
    let (cpu, cpu_error) = watch_image(&dir, &scene, "cpu");
    let (gpu, gpu_error) = watch_image(&dir, &scene, "gpu");
    // The GPU's beam sums keep their half-films apart too: the same noise estimate.
    assert!(
        cpu_error > 0.0 && (gpu_error / cpu_error - 1.0).abs() < 1e-2,
        "error estimate GPU {gpu_error} vs CPU {cpu_error}"
    );
    let (mut diff, mut sum) = (0.0f64, 0.0f64);
    for (a, b) in gpu.pixels.iter().zip(&cpu.pixels) {
        for c in 0..3 {
            diff += (a[c] - b[c]).abs() as f64;
            sum += b[c].abs() as f64;
        }
    }
    assert!(sum > 0.0);
    assert!(diff / sum < 1e-5, "rel_l1 GPU vs CPU {}", diff / sum);
    std::fs::remove_dir_all(&dir).ok();
}

/// `ppb bench --repeat 3` bakes each grid's octree once for all six runs, and says so.
#[test]
fn bench_builds_each_octree_once() {
    let o = Command::new(env!("CARGO_BIN_EXE_ppb"))
        .args([
            "bench",
            "--passes",
            "1",
            "--size",
            "16x16",
            "--light-paths",
            "500",
        ])
        .args(["--repeat", "3"])
        .arg(data("scenes/conformance/smoke-grid/scene.toml"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    let built: Vec<&str> = err.lines().filter(|l| l.contains("octree built")).collect();
    assert_eq!(built.len(), 1, "{err}");
    assert!(built[0].contains("once, for all runs"), "{err}");
}

/// The old names of the light-path count still work, each with one warning line.
#[test]
fn old_light_path_names_warn_and_work() {
    let dir = common::temp_dir("session", "old-names");
    write_floor(&dir);
    let light = "[[light]]\ntype = \"point\"\nposition = [0, 2.6, 0]\nintensity = [20, 20, 20]\n";
    let scene = dir.join("scene.toml");
    let render = "width = 8\nheight = 8\npasses = 1\nbeams_per_pass = 300";
    std::fs::write(&scene, floor_scene(render, 0.5, light)).unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_ppb"))
        .args(["render", "--quiet", "--beams", "200", "-o"])
        .arg(dir.join("a.exr"))
        .arg(&scene)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    let warnings: Vec<&str> = err.lines().filter(|l| l.starts_with("warning:")).collect();
    assert_eq!(warnings.len(), 2, "{err}");
    assert!(
        warnings.iter().any(|w| w.contains("render.light_paths")),
        "{err}"
    );
    assert!(
        warnings.iter().any(|w| w.contains("--light-paths")),
        "{err}"
    );
    assert!(dir.join("a.exr").is_file());
    std::fs::remove_dir_all(&dir).ok();
}
