//! Reliability end to end through the `ppb` binary: absurd sizes get an error before any
//! allocation, a .usdc that crashes the USD crate is one clean line, outputs that cannot
//! be written leave the previous ones intact, and processes sharing a cache folder, a
//! part folder and an output never leave a torn or foreign file behind.
mod common;

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

fn ppb() -> Command {
    Command::new(env!("CARGO_BIN_EXE_ppb"))
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into()
}

/// Bad input: exit 2 and one line holding every `expect`, no panic text.
fn one_line(o: &Output, expect: &[&str]) {
    let e = stderr(o);
    assert_eq!(o.status.code(), Some(2), "{e}");
    assert!(
        !e.contains("panicked") && !e.contains("memory allocation"),
        "{e}"
    );
    assert_eq!(e.trim().lines().count(), 1, "not one line: {e}");
    for x in expect {
        assert!(e.contains(x), "'{x}' missing from: {e}");
    }
}

/// A small homogeneous-fog scene (no grids, so no cache) at `dir/scene.toml`.
fn fog_scene(dir: &Path, render: &str) -> PathBuf {
    common::write_floor(dir);
    let rest = "[[light]]\ntype = \"point\"\nposition = [0, 2.6, 0]\nintensity = [20, 20, 20]\n\n[[medium]]\ntype = \"homogeneous\"\nbounds = [[-1, 0.25, -1], [1, 1.75, 1]]\nsigma_t = 1.0\nalbedo = [0.8, 0.8, 0.8]\n";
    let p = dir.join("scene.toml");
    std::fs::write(&p, common::floor_scene(render, 0.5, rest)).unwrap();
    p
}

const SMALL: &str = "width = 24\nheight = 16\npasses = 2\nlight_paths = 2000";

#[test]
fn absurd_sizes_are_refused_before_allocating() {
    let dir = common::temp_dir("rel", "sizes");
    let s = fog_scene(&dir, SMALL);
    let render = |args: &[&str]| {
        ppb()
            .args(["render", "-q", "--device", "cpu"])
            .arg(&s)
            .args(args)
            .output()
            .unwrap()
    };
    one_line(
        &render(&["--size", "1000000x1000000"]),
        &["--size", "16384"],
    );
    one_line(&render(&["--size", "16384x16384"]), &["--size", "pixels"]);
    one_line(
        &render(&["--light-paths", "1000000000000"]),
        &["--light-paths", "light paths per pass"],
    );
    let big = fog_scene(&dir, "width = 16000\nheight = 16000\npasses = 2");
    one_line(
        &render_scene(&big),
        &["scene.toml", "render.width", "pixels"],
    );
    let many = fog_scene(&dir, "light_paths = 1000000000000");
    one_line(&render_scene(&many), &["render.light_paths"]);
    assert!(!dir.join("scene.exr").exists());
}

fn render_scene(s: &Path) -> Output {
    ppb()
        .args(["render", "-q", "--device", "cpu"])
        .arg(s)
        .output()
        .unwrap()
}

/// Mutated copies of the shipped glass_smoke.usdc: one made the USD crate ask for a 4 TB
/// allocation (the process aborted), one made it panic on a slice index. Both are now
/// one line, from `info` and from a render that imports the stage.
#[test]
fn corrupt_usdc_is_one_clean_line() {
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/fuzz");
    let dir = common::temp_dir("rel", "usd");
    for name in ["usd-abort-alloc.usdc", "usd-panic-slice.usdc"] {
        let f = data.join(name);
        let o = ppb().arg("info").arg(&f).output().unwrap();
        one_line(&o, &[name]);
        let s = fog_scene(&dir, SMALL);
        let text = std::fs::read_to_string(&s).unwrap();
        std::fs::write(
            &s,
            format!("{text}\n[[import]]\npath = {:?}\n", f.display().to_string()),
        )
        .unwrap();
        one_line(&render_scene(&s), &[name]);
    }
    // The abort is named as such (the child process that parsed it died).
    let o = ppb()
        .arg("info")
        .arg(data.join("usd-abort-alloc.usdc"))
        .output()
        .unwrap();
    assert!(stderr(&o).contains("aborted"), "{}", stderr(&o));
}

/// Renders `scene` to `out` with `limit` applied to the child before it starts.
fn render_limited(scene: &Path, out: &Path, limit: impl Fn(&mut Command)) -> Output {
    let mut c = ppb();
    c.args(["render", "-q", "--device", "cpu", "--size", "96x64", "-o"])
        .arg(out)
        .arg(scene);
    limit(&mut c);
    c.output().unwrap()
}

/// An output that cannot be written (a read-only folder, a full disk, a folder in the
/// way) is a clear error, exit 1, and the previous output stays as it was.
#[test]
fn unwritable_outputs_keep_the_previous_one() {
    use std::os::unix::fs::PermissionsExt;
    use std::os::unix::process::CommandExt;
    let dir = common::temp_dir("rel", "out");
    let s = fog_scene(&dir, SMALL);
    let outs = dir.join("outs");
    std::fs::create_dir_all(&outs).unwrap();
    let out = outs.join("img.exr");
    let o = render_limited(&s, &out, |_| {});
    assert!(o.status.success(), "{}", stderr(&o));
    let (exr, png) = (
        std::fs::read(&out).unwrap(),
        std::fs::read(outs.join("img.png")).unwrap(),
    );
    let intact = |what: &str| {
        assert_eq!(std::fs::read(&out).unwrap(), exr, "{what}: the EXR changed");
        assert_eq!(std::fs::read(outs.join("img.png")).unwrap(), png, "{what}");
        let names: Vec<String> = std::fs::read_dir(&outs)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into())
            .collect();
        assert_eq!(names.len(), 2, "{what}: left behind {names:?}");
    };
    let failed = |o: &Output, what: &str, expect: &[&str]| {
        let e = stderr(o);
        assert_eq!(o.status.code(), Some(1), "{what}: {e}");
        assert!(expect.iter().all(|x| e.contains(x)), "{what}: {e}");
        assert!(!e.contains("panicked"), "{what}: {e}");
    };

    // Read-only folder: as root (CI) permissions do not bind, so the render runs as
    // nobody; the scene folder stays readable to everyone.
    std::fs::set_permissions(&outs, std::fs::Permissions::from_mode(0o555)).unwrap();
    // SAFETY: getuid has no preconditions.
    let root = unsafe { libc::getuid() } == 0;
    let o = render_limited(&s, &out, |c| {
        if root {
            c.uid(65534).gid(65534);
        }
    });
    failed(&o, "read-only folder", &["img", "Permission denied"]);
    std::fs::set_permissions(&outs, std::fs::Permissions::from_mode(0o755)).unwrap();
    intact("read-only folder");

    // A full disk: files may not grow past 4 KiB (SIGXFSZ ignored, so writes fail EFBIG).
    let o = render_limited(&s, &out, |c| {
        // SAFETY: only async-signal-safe calls between fork and exec.
        unsafe {
            c.pre_exec(|| {
                libc::signal(libc::SIGXFSZ, libc::SIG_IGN);
                let lim = libc::rlimit {
                    rlim_cur: 4096,
                    rlim_max: 4096,
                };
                if libc::setrlimit(libc::RLIMIT_FSIZE, &lim) != 0 {
                    return Err(std::io::Error::last_os_error());
                }
                Ok(())
            });
        }
    });
    failed(&o, "full disk", &["img", "too large"]);
    intact("full disk");

    // A folder where the output file should be.
    let taken = outs.join("taken.exr");
    std::fs::create_dir(&taken).unwrap();
    let o = render_limited(&s, &taken, |_| {});
    failed(&o, "a folder in the way", &["taken.exr", "directory"]);
    std::fs::remove_dir(&taken).unwrap();
    intact("a folder in the way");
}

/// Eight tasks of one farm render share a cache folder and a part folder, started
/// together; three are killed mid-run (SIGKILL: no clean-up at all). No process ever
/// trusts a torn or foreign file: the survivors finish, the killed ones finish when run
/// again (from their last checkpoint), the cache ends fresh and the merge equals one
/// render. Four processes writing one output path leave a complete image.
#[test]
fn processes_sharing_cache_parts_and_outputs() {
    let repo = Path::new(env!("CARGO_MANIFEST_DIR"));
    let dir = common::temp_dir("rel", "shared");
    let shot = dir.join("shot");
    std::fs::create_dir_all(&shot).unwrap();
    std::fs::create_dir_all(dir.join("common")).unwrap();
    common::write_floor(&dir.join("common"));
    for f in ["manta_smoke_0016.vdb", "smoke.toml"] {
        std::fs::copy(repo.join("scenes/mantaflow").join(f), shot.join(f)).unwrap();
    }
    let scene = shot.join("smoke.toml");
    let cache = dir.join("cache");
    let fast = [
        "--size",
        "40x32",
        "--light-paths",
        "4000",
        "--device",
        "cpu",
        "--threads",
        "1",
    ];
    let task = |k: u32| -> Command {
        let mut c = ppb();
        c.arg("render")
            .arg(&scene)
            .args([
                "--frames",
                "16",
                "--passes",
                "240",
                "--passes-per-task",
                "30",
            ])
            .args(["--task-index", &k.to_string(), "--checkpoint", "3", "-q"])
            .arg("--cache-dir")
            .arg(&cache)
            .arg("-o")
            .arg(dir.join("out/s.####.exr"))
            .args(fast)
            .stdout(Stdio::null())
            .stderr(Stdio::piped());
        c
    };
    let t0 = Instant::now();
    let mut children: Vec<Child> = (0..8).map(|k| task(k).spawn().unwrap()).collect();
    // Kill three once their tasks have checkpointed (so they die mid-render, some
    // possibly mid-write of a part).
    for k in [1usize, 4, 6] {
        let part = dir.join(format!(
            "out/s.0016.passes-{}-{}.ppbpart",
            k * 30,
            k * 30 + 30
        ));
        while !part.exists() && t0.elapsed() < Duration::from_secs(120) {
            std::thread::sleep(Duration::from_millis(5));
        }
        children[k].kill().unwrap();
    }
    for (k, c) in children.into_iter().enumerate() {
        let o = c.wait_with_output().unwrap();
        if ![1, 4, 6].contains(&k) {
            assert!(o.status.success(), "task {k}: {}", stderr(&o));
        }
    }
    // The kills landed mid-render: a killed task's part holds only some of its passes.
    let partial = [1u32, 4, 6]
        .iter()
        .filter(|&&k| {
            let part = dir.join(format!(
                "out/s.0016.passes-{}-{}.ppbpart",
                k * 30,
                k * 30 + 30
            ));
            ppb::farm::Part::read(&part).is_ok_and(|p| !p.header.complete())
        })
        .count();
    assert!(partial >= 1, "no task was killed mid-render");
    for k in [1, 4, 6] {
        let o = task(k).output().unwrap();
        assert!(o.status.success(), "task {k} again: {}", stderr(&o));
    }
    eprintln!(
        "8 tasks, 3 killed and rerun: {:.1} s",
        t0.elapsed().as_secs_f64()
    );
    let o = ppb()
        .args(["merge", "-q", "-o"])
        .arg(dir.join("out/s.####.exr"))
        .arg("--frames")
        .arg("16")
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    let merged = ppb::output::read_exr(&dir.join("out/s.0016.exr")).unwrap();
    let one = dir.join("one.exr");
    let o = ppb()
        .arg("render")
        .arg(&scene)
        .args(["--frames", "16", "--passes", "240", "-q", "-o"])
        .arg(&one)
        .arg("--cache-dir")
        .arg(&cache)
        .args(fast)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    let bits = |i: &ppb::output::Image| -> Vec<u32> {
        i.pixels.iter().flatten().map(|x| x.to_bits()).collect()
    };
    assert_eq!(bits(&merged), bits(&ppb::output::read_exr(&one).unwrap()));
    // The cache ends valid: the octree written under contention loads.
    let check = ppb()
        .arg("render")
        .arg(&scene)
        .args(["--frames", "16", "--passes", "1", "-o"])
        .arg(dir.join("check.exr"))
        .arg("--cache-dir")
        .arg(&cache)
        .args(fast)
        .output()
        .unwrap();
    assert!(
        stderr(&check).contains("loaded from cache"),
        "{}",
        stderr(&check)
    );

    // Four renders of one output path at once: whichever rename lands last, the file
    // is a whole image.
    let same = dir.join("same.exr");
    let four: Vec<Child> = (0..4)
        .map(|i| {
            ppb()
                .arg("render")
                .arg(&scene)
                .args(["--frames", "16", "--passes", "2", "-q", "--seed"])
                .arg((i + 1).to_string())
                .arg("-o")
                .arg(&same)
                .arg("--cache-dir")
                .arg(&cache)
                .args(fast)
                .spawn()
                .unwrap()
        })
        .collect();
    for c in four {
        assert!(c.wait_with_output().unwrap().status.success());
    }
    let img = ppb::output::read_exr(&same).unwrap();
    assert_eq!((img.width, img.height), (40, 32));
}
