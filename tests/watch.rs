//! `ppb watch` end to end: the built binary watches a scene in a temp folder while the test
//! edits it the way editors do (rename over the file, or rewrite in place). Everything is
//! polled with generous deadlines so a loaded 2-core CI machine passes too.
mod common;

use common::{floor_scene, write_floor};
use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

const DEADLINE: Duration = Duration::from_secs(60);

/// A 32x32 scene: floor, one light (`light`), and `medium`.
fn scene_text(light: &str, medium: &str) -> String {
    let render = "width = 32\nheight = 32\npasses = 100000\nlight_paths = 1000";
    floor_scene(render, 0.5, &format!("{light}\n\n{medium}\n"))
}

fn point_light(intensity: f32) -> String {
    format!(
        "[[light]]\ntype = \"point\"\nposition = [0, 2.6, 0]\nintensity = [{intensity}, {intensity}, {intensity}]"
    )
}

const FOG: &str = "[[medium]]\ntype = \"homogeneous\"\nbounds = [[-1, 0.25, -1], [1, 1.75, 1]]\nsigma_t = 1.0\nalbedo = [0.8, 0.8, 0.8]";

/// How editors save: write a temp file, rename it over the original.
fn save_by_rename(path: &Path, text: &[u8]) {
    let tmp = path.with_file_name(format!(
        ".{}.swp",
        path.file_name().unwrap().to_string_lossy()
    ));
    std::fs::write(&tmp, text).unwrap();
    std::fs::rename(&tmp, path).unwrap();
}

/// The running `ppb watch` and its stderr lines; killed when dropped.
struct Watch {
    child: Child,
    lines: Arc<Mutex<Vec<String>>>,
}

impl Watch {
    fn start(scene: &Path, out: &Path, extra: &[&str]) -> Watch {
        let mut child = Command::new(env!("CARGO_BIN_EXE_ppb"))
            .arg("watch")
            .arg(scene)
            .arg("-o")
            .arg(out)
            .args(["--threads", "1", "--checkpoint", "0.2s"])
            .args(extra)
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .expect("starting ppb watch");
        let lines = Arc::new(Mutex::new(Vec::new()));
        let sink = lines.clone();
        let stderr = child.stderr.take().unwrap();
        std::thread::spawn(move || {
            for l in BufReader::new(stderr).lines().map_while(Result::ok) {
                sink.lock().unwrap().push(l);
            }
        });
        Watch { child, lines }
    }

    fn log(&self) -> String {
        self.lines.lock().unwrap().join("\n")
    }

    fn count(&self, needle: &str) -> usize {
        let lines = self.lines.lock().unwrap();
        lines.iter().filter(|l| l.contains(needle)).count()
    }

    fn alive(&mut self) -> bool {
        self.child.try_wait().unwrap().is_none()
    }

    /// Polls `cond` until it holds; fails with the log when the deadline passes or the
    /// process ends.
    fn wait(&mut self, what: &str, mut cond: impl FnMut(&Watch) -> bool) {
        let start = Instant::now();
        while !cond(self) {
            assert!(
                self.alive(),
                "ppb watch exited while waiting for {what}:\n{}",
                self.log()
            );
            assert!(
                start.elapsed() < DEADLINE,
                "timed out waiting for {what}:\n{}",
                self.log()
            );
            std::thread::sleep(Duration::from_millis(50));
        }
    }
}

impl Drop for Watch {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Mean of the output EXR; the file, once there, must always read completely.
fn mean(out: &Path) -> Option<f64> {
    if !out.exists() {
        return None;
    }
    let img = ppb::output::read_exr(out).expect("the output is always a complete EXR");
    let sum: f64 = img.pixels.iter().flatten().map(|&c| c as f64).sum();
    Some(sum / (3 * img.pixels.len()) as f64)
}

#[test]
fn light_edit_broken_toml_and_fix() {
    let dir = common::temp_dir("watch", "light");
    write_floor(&dir);
    let scene = dir.join("scene.toml");
    std::fs::write(&scene, scene_text(&point_light(20.0), FOG)).unwrap();
    let out = dir.join("out.exr");
    let mut w = Watch::start(&scene, &out, &[]);
    w.wait("the first output", |w| w.count("preview") >= 1);
    let base = mean(&out).unwrap();
    assert!(base > 0.0, "a lit scene renders non-black");

    // A light edit: the image restarts and gets 4x brighter, nothing else is read again.
    save_by_rename(&scene, scene_text(&point_light(80.0), FOG).as_bytes());
    w.wait("the brighter image", |w| {
        w.count("reload 2") >= 1 && mean(&out).unwrap() > 3.0 * base
    });
    let reload = w.log();
    let line = reload.lines().find(|l| l.contains("reload 2")).unwrap();
    assert!(
        line.contains("lights") && line.contains("read no assets"),
        "{line}"
    );
    assert!(
        out.with_extension("png").is_file(),
        "the PNG preview is written beside the EXR"
    );

    // A syntax error, written in place: one error with file and line, the process stays
    // up and the last good (bright) output stays readable and is not replaced.
    std::fs::write(&scene, "[render]\nwidth = 32\n[[light]\ntype = \n").unwrap();
    w.wait("the syntax error", |w| w.count("error: ") >= 1);
    // A save caught mid-write may first report another error; the syntax one must come.
    w.wait("the line of the syntax error", |w| w.count("line 3") >= 1);
    let err = w.log();
    let err = err.lines().find(|l| l.contains("line 3")).unwrap();
    assert!(
        err.contains("scene.toml") && err.contains("line 3"),
        "the error names the file and line: {err}"
    );
    assert!(err.contains("still rendering the last good scene"), "{err}");
    std::thread::sleep(Duration::from_millis(800));
    assert!(w.alive(), "a broken scene must not stop ppb watch");
    let kept = mean(&out).unwrap();
    assert!(
        kept > 3.0 * base,
        "the last good output stays: {kept} vs {base}"
    );

    // Fixed: rendering resumes with the new scene (2x the first).
    save_by_rename(&scene, scene_text(&point_light(40.0), FOG).as_bytes());
    w.wait("the fixed scene", |w| {
        let m = mean(&out).unwrap();
        w.count("reload 3") >= 1 && m > 1.5 * base && m < 2.5 * base
    });
    let log = w.log();
    let errors: Vec<&str> = log.lines().filter(|l| l.starts_with("error: ")).collect();
    assert!(
        errors.iter().all(|l| l.contains("scene.toml")),
        "{errors:?}"
    );
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn vdb_change_rebuilds_one_octree_and_light_edits_none() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/conformance");
    let dir = common::temp_dir("watch", "vdb");
    write_floor(&dir);
    std::fs::copy(root.join("smoke-grid/density.vdb"), dir.join("density.vdb")).unwrap();
    let grid = "[[medium]]\ntype = \"grid\"\npath = \"density.vdb\"\ngrid = \"density\"\ndensity_scale = 8.0\nalbedo = [0.9, 0.9, 0.9]";
    let scene = dir.join("scene.toml");
    std::fs::write(&scene, scene_text(&point_light(20.0), grid)).unwrap();
    let out = dir.join("out.exr");
    let cache = dir.join("cache");
    let cache_arg = cache.to_str().unwrap();
    let mut w = Watch::start(&scene, &out, &["--cache-dir", cache_arg]);
    w.wait("the first output", |w| w.count("preview") >= 1);
    assert_eq!(w.count("octree built"), 1, "{}", w.log());

    // A light edit keeps the grid and its octree.
    save_by_rename(&scene, scene_text(&point_light(30.0), grid).as_bytes());
    w.wait("the light reload", |w| w.count("preview") >= 2);
    assert_eq!(w.count("octree built"), 1, "{}", w.log());
    let log = w.log();
    let line = log.lines().find(|l| l.contains("reload 2")).unwrap();
    assert!(
        line.contains("read no assets") && line.contains("1 octree(s) reused"),
        "{line}"
    );

    // A new VDB (saved by rename): exactly one octree rebuild, for that medium.
    let other = std::fs::read(root.join("cloud-hg/density.vdb")).unwrap();
    save_by_rename(&dir.join("density.vdb"), &other);
    w.wait("the VDB reload", |w| w.count("preview") >= 3);
    // Let a late duplicate event show itself if there were one.
    std::thread::sleep(Duration::from_millis(1500));
    assert_eq!(w.count("octree built"), 1 + 1, "{}", w.log());
    let log = w.log();
    let line = log.lines().find(|l| l.contains("reload 3")).unwrap();
    assert!(
        line.contains("grid media [0]") && line.contains("density.vdb"),
        "{line}"
    );
    assert!(w.alive());
    std::fs::remove_dir_all(&dir).ok();
}

/// Writes a 16 x 8 lat-long map of constant `radiance` as EXR, by rename (as a paint or
/// bake tool saving over it).
fn save_map(path: &Path, radiance: f32) {
    let tmp = path.with_file_name(".sky.tmp.exr");
    exr::prelude::write_rgb_file(&tmp, 16, 8, |_, _| (radiance, radiance, radiance)).unwrap();
    std::fs::rename(&tmp, path).unwrap();
}

/// A changed environment map is read again and relights the image (4x the radiance, 4x
/// the image); the scene file itself is untouched.
#[test]
fn environment_map_change_relights() {
    let dir = common::temp_dir("watch", "envmap");
    write_floor(&dir);
    let map = dir.join("sky.exr");
    save_map(&map, 0.5);
    let light = "[[light]]\ntype = \"environment\"\nmap = \"sky.exr\"";
    let scene = dir.join("scene.toml");
    std::fs::write(&scene, scene_text(light, "")).unwrap();
    let out = dir.join("out.exr");
    let mut w = Watch::start(&scene, &out, &[]);
    w.wait("the first output", |w| w.count("preview") >= 1);
    let base = mean(&out).unwrap();
    assert!(base > 0.0, "the sky lights the floor");
    save_map(&map, 2.0);
    w.wait("the brighter image", |w| {
        let m = mean(&out).unwrap();
        w.count("reload 2") >= 1 && m > 3.5 * base && m < 4.5 * base
    });
    let log = w.log();
    let line = log.lines().find(|l| l.contains("reload 2")).unwrap();
    assert!(line.contains("lights"), "{line}");
    std::fs::remove_dir_all(&dir).ok();
}

/// 100 random edits while `ppb watch` runs: truncated and garbage scene files, files
/// caught half-written, assets deleted, truncated and re-created, scenes renamed away and
/// back. It never dies, the output is always a complete EXR, and every tenth edit
/// restores a good scene (with another light) that the output then shows.
#[test]
fn soak_of_random_edits() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/conformance");
    let dir = common::temp_dir("watch", "soak");
    write_floor(&dir);
    let vdb = std::fs::read(root.join("smoke-grid/density.vdb")).unwrap();
    let floor = std::fs::read(dir.join("floor.obj")).unwrap();
    std::fs::write(dir.join("density.vdb"), &vdb).unwrap();
    let grid = "[[medium]]\ntype = \"grid\"\npath = \"density.vdb\"\ngrid = \"density\"\ndensity_scale = 4.0\nalbedo = [0.9, 0.9, 0.9]";
    let good = |i: f32| scene_text(&point_light(i), grid);
    let scene = dir.join("scene.toml");
    std::fs::write(&scene, good(20.0)).unwrap();
    let out = dir.join("out.exr");
    let cache = dir.join("cache");
    let mut w = Watch::start(&scene, &out, &["--cache-dir", cache.to_str().unwrap()]);
    w.wait("the first output", |w| w.count("preview") >= 1);
    let base = mean(&out).unwrap();
    let t0 = Instant::now();
    let mut rng = 0x2545_f491_4f6c_dd1du64;
    let mut next = |n: u64| {
        rng ^= rng << 13;
        rng ^= rng >> 7;
        rng ^= rng << 17;
        rng % n
    };
    let mut restores = 0;
    for edit in 1..=100 {
        let text = good(20.0).into_bytes();
        match next(8) {
            0 => std::fs::write(&scene, &text[..next(text.len() as u64) as usize]).unwrap(),
            1 => {
                let junk: Vec<u8> = (0..next(400)).map(|_| next(256) as u8).collect();
                std::fs::write(&scene, junk).unwrap()
            }
            2 => {
                std::fs::write(&scene, &text[..text.len() / 2]).unwrap();
                std::thread::sleep(Duration::from_millis(next(60)));
                std::fs::write(&scene, &text).unwrap();
            }
            3 => {
                std::fs::remove_file(dir.join("density.vdb")).ok();
                std::thread::sleep(Duration::from_millis(next(150)));
                std::fs::write(dir.join("density.vdb"), &vdb).unwrap();
            }
            4 => std::fs::write(
                dir.join("density.vdb"),
                &vdb[..next(vdb.len() as u64) as usize],
            )
            .unwrap(),
            5 => std::fs::write(dir.join("floor.obj"), b"v 1 2\nf 1 2 9\n").unwrap(),
            6 => {
                let away = dir.join("away.toml");
                std::fs::rename(&scene, &away).unwrap();
                std::thread::sleep(Duration::from_millis(next(150)));
                std::fs::rename(&away, &scene).unwrap();
            }
            _ => {
                std::fs::remove_file(dir.join("floor.obj")).ok();
                std::thread::sleep(Duration::from_millis(next(100)));
                std::fs::write(dir.join("floor.obj"), &floor).unwrap();
            }
        }
        std::thread::sleep(Duration::from_millis(30 + next(120)));
        assert!(w.alive(), "ppb watch died after edit {edit}:\n{}", w.log());
        mean(&out);
        if edit % 10 == 0 {
            // A good scene again, 4x brighter or back to the base light.
            restores += 1;
            let bright = restores % 2 == 1;
            std::fs::write(dir.join("density.vdb"), &vdb).unwrap();
            std::fs::write(dir.join("floor.obj"), &floor).unwrap();
            save_by_rename(&scene, good(if bright { 80.0 } else { 20.0 }).as_bytes());
            // `wait` fails at once if the process ends.
            w.wait("the restored scene", |_| {
                let m = mean(&out).unwrap();
                if bright {
                    m > 2.5 * base
                } else {
                    m < 1.6 * base
                }
            });
        }
    }
    assert!(w.alive());
    eprintln!(
        "soak: 100 edits, {restores} restores in {:.1} s, {} reloads",
        t0.elapsed().as_secs_f64(),
        w.count("reload")
    );
    std::fs::remove_dir_all(&dir).ok();
}
