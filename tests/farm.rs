//! Rendering on a farm, end to end through the `ppb` binary: frame sequences, tasks and
//! part files, the exact merge, resuming after a signal, progress lines, exit codes, the
//! EXR header, and the job files run for real by Slurm and OpenJD and checked (and run
//! index by index) for Kubernetes. The engine tests skip when the engine is missing,
//! unless PPB_REQUIRE_FARM=1 (CI, which installs them) makes that a failure.
mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

fn ppb() -> Command {
    Command::new(env!("CARGO_BIN_EXE_ppb"))
}

/// Small and fast: every render of these tests.
const FAST: [&str; 6] = [
    "--size",
    "32x24",
    "--light-paths",
    "3000",
    "--device",
    "cpu",
];

/// A folder inside the build's temp folder (so the scene and the outputs share the
/// repository as their common folder) with a two-frame Mantaflow sequence scene.
fn sequence(name: &str) -> (PathBuf, PathBuf) {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("farm-{name}"));
    let _ = std::fs::remove_dir_all(&dir);
    let shot = dir.join("shot");
    std::fs::create_dir_all(&shot).unwrap();
    std::fs::create_dir_all(dir.join("common")).unwrap();
    let repo = Path::new(env!("CARGO_MANIFEST_DIR"));
    for f in ["manta_smoke_0016.vdb", "manta_smoke_0032.vdb", "smoke.toml"] {
        std::fs::copy(repo.join("scenes/mantaflow").join(f), shot.join(f)).unwrap();
    }
    common::write_floor(&dir.join("common"));
    (dir.clone(), shot.join("smoke.toml"))
}

fn run(cmd: &mut Command) -> Output {
    let o = cmd.output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!err.contains("panicked"), "panic: {err}");
    o
}

fn ok(cmd: &mut Command) -> Output {
    let o = run(cmd);
    assert!(
        o.status.success(),
        "{cmd:?}: {:?}\n{}",
        o.status,
        String::from_utf8_lossy(&o.stderr)
    );
    o
}

fn code(o: &Output) -> i32 {
    o.status.code().unwrap_or(-1)
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into()
}

/// The pixels of an EXR as bits.
fn bits(p: &Path) -> Vec<u32> {
    let img = ppb::output::read_exr(p).unwrap_or_else(|e| panic!("{e}"));
    img.pixels.iter().flatten().map(|x| x.to_bits()).collect()
}

/// One machine's render of `passes` passes of frame 16, the reference of the merges.
fn single(scene: &Path, out: &Path, passes: u32) -> Vec<u32> {
    ok(ppb()
        .arg("render")
        .arg(scene)
        .args([
            "--frames",
            "16",
            "--passes",
            &passes.to_string(),
            "-q",
            "-o",
        ])
        .arg(out)
        .args(FAST));
    bits(Path::new(&ppb::core::frames::with_frame(
        &out.to_string_lossy(),
        16,
    )))
}

/// Three tasks of frame 16 merge to the bits of one render; a task stopped by SIGTERM
/// keeps its passes (exit 143), a second run continues it, and a finished task is skipped.
#[test]
fn tasks_merge_bit_for_bit_and_resume_after_a_signal() {
    let (dir, scene) = sequence("merge");
    let want = single(&scene, &dir.join("one/s.####.exr"), 7);
    let out = dir.join("parts/s.####.exr");
    let task = |k: u32| {
        let mut c = ppb();
        c.arg("render")
            .arg(&scene)
            .args([
                "--frames",
                "16,32",
                "--passes",
                "7",
                "--passes-per-task",
                "3",
            ])
            .args(["--task-index", &k.to_string(), "-q", "-o"])
            .arg(&out)
            .args(FAST);
        c
    };
    for k in 0..3 {
        ok(&mut task(k));
    }
    let part = dir.join("parts/s.0016.passes-3-6.ppbpart");
    let before = std::fs::read(&part).unwrap();
    // Task 1 again: its part is complete, so nothing is rendered or rewritten.
    let again = ok(task(1).args(["--progress", "bar"]));
    assert_eq!(stderr(&again), "");
    assert_eq!(std::fs::read(&part).unwrap(), before);
    ok(ppb()
        .args(["merge", "--frames", "16", "-q", "-o"])
        .arg(&out));
    assert_eq!(bits(&dir.join("parts/s.0016.exr")), want);
    // The parts carry both half-films, so the merge estimates the same error as one render.
    let estimate = |p: &Path| {
        let text = ppb::output::read_exr_text(p).unwrap();
        let e = text.into_iter().find(|(k, _)| k == "ppb/estimated_rel_l1");
        e.expect("an error estimate in the header").1
    };
    assert_eq!(
        estimate(&dir.join("parts/s.0016.exr")),
        estimate(&dir.join("one/s.0016.exr"))
    );

    // A long task interrupted after its first checkpoint, then finished by a second run.
    let long = dir.join("long/s.exr");
    let args = |c: &mut Command| {
        c.arg("render")
            .arg(&scene)
            .args([
                "--frames",
                "16",
                "--passes",
                "4000",
                "--pass-range",
                "0..4000",
            ])
            .args(["--checkpoint", "1", "--progress", "none", "-o"])
            .arg(&long)
            .args(FAST);
    };
    let mut c = ppb();
    args(&mut c);
    let child = c.stderr(Stdio::piped()).spawn().unwrap();
    let part = dir.join("long/s.passes-0-4000.ppbpart");
    let t0 = Instant::now();
    while !part.exists() && t0.elapsed() < Duration::from_secs(60) {
        std::thread::sleep(Duration::from_millis(20));
    }
    // SAFETY: signalling our own child.
    unsafe { libc::kill(child.id() as i32, libc::SIGTERM) };
    let o = child.wait_with_output().unwrap();
    assert_eq!(code(&o), 143, "{}", stderr(&o));
    assert!(stderr(&o).contains("interrupted"), "{}", stderr(&o));
    let p = ppb::farm::Part::read(&part).unwrap();
    assert!(
        p.header.done > 0 && p.header.done < 4000,
        "{}",
        p.header.done
    );
    // Merging a partial part is refused, naming it.
    let o = run(ppb()
        .args(["merge", "-q", "-o"])
        .arg(dir.join("long/m.exr"))
        .arg(&part));
    assert_eq!(code(&o), 2);
    assert!(stderr(&o).contains("partial"), "{}", stderr(&o));
    // Continuing a partial part: the part of a finished 0..3 task, relabelled as 3
    // passes done of a 0..7 task, is what an interruption after pass 3 leaves (a pass
    // depends on its index alone); the 0..7 task continues from pass 4.
    let short = dir.join("short/s.exr");
    let shorter = |range: &str| {
        let mut c = ppb();
        c.arg("render")
            .arg(&scene)
            .args(["--frames", "16", "--passes", "7", "--pass-range", range])
            .args(["--progress", "none", "-o"])
            .arg(&short)
            .args(FAST);
        c
    };
    ok(&mut shorter("0..3"));
    let done3 = ppb::farm::Part::read(&dir.join("short/s.passes-0-3.ppbpart")).unwrap();
    let mut h = done3.header.clone();
    h.range = ppb::farm::PassRange { start: 0, end: 7 };
    ppb::farm::Part::write(&dir.join("short/s.passes-0-7.ppbpart"), &h, &done3.film).unwrap();
    let o = ok(&mut shorter("0..7"));
    assert!(
        stderr(&o).contains("resuming after passes 0..3"),
        "{}",
        stderr(&o)
    );
    std::fs::remove_file(dir.join("short/s.passes-0-3.ppbpart")).unwrap();
    ok(ppb()
        .args(["merge", "-q", "-o"])
        .arg(&short)
        .arg(dir.join("short/s.passes-0-7.ppbpart")));
    assert_eq!(bits(&short), want, "a resumed task must equal one render");
}

/// Gaps, overlaps and parts of another scene are refused with the files named, exit 2.
#[test]
fn merge_refuses_gaps_overlaps_and_foreign_parts() {
    let (dir, scene) = sequence("refuse");
    let part = |range: &str, seed: &str| {
        ok(ppb()
            .arg("render")
            .arg(&scene)
            .args(["--frames", "16", "--passes", "4", "--pass-range", range])
            .args(["--seed", seed, "-q", "--part-dir"])
            .arg(dir.join("parts"))
            .arg("-o")
            .arg(dir.join(format!("seed{seed}/s.exr")))
            .args(FAST));
        let r = range.replace("..", "-");
        dir.join(format!("parts/s.passes-{r}.ppbpart"))
    };
    let a = part("0..2", "1");
    let b = part("2..4", "1");
    let merge = |parts: &[&PathBuf]| {
        let o = run(ppb()
            .args(["merge", "-q", "-o"])
            .arg(dir.join("m.exr"))
            .args(parts));
        assert_eq!(code(&o), 2, "{}", stderr(&o));
        assert!(!dir.join("m.exr").exists());
        stderr(&o)
    };
    assert!(merge(&[&b]).contains("passes 0..2 are missing"));
    assert!(merge(&[&a]).contains("passes 2..4 are missing"));
    let c = part("1..3", "1");
    assert!(merge(&[&a, &b, &c]).contains("overlaps"));
    std::fs::rename(&a, dir.join("a1.ppbpart")).unwrap();
    let a2 = part("0..2", "2");
    let e = merge(&[&a2, &b]);
    assert!(
        e.contains("do not belong to one render") && e.contains("settings"),
        "{e}"
    );
    std::fs::write(&a2, b"PPBPART2 but cut").unwrap();
    assert!(merge(&[&a2, &b]).contains("not a valid ppb part file"));
    // The right two merge.
    ok(ppb()
        .args(["merge", "-q", "-o"])
        .arg(dir.join("m.exr"))
        .arg(dir.join("a1.ppbpart"))
        .arg(&b));
}

/// `--frames` renders one image per frame from the grid sequence; a missing frame is an
/// error naming its file before any work starts; the header carries the frame, the frame
/// rate, the camera and ppb's attributes.
#[test]
fn frames_render_a_sequence_with_its_header() {
    let (dir, scene) = sequence("frames");
    let out = dir.join("out/smoke.####.exr");
    let o = run(ppb()
        .arg("render")
        .arg(&scene)
        .args(["--frames", "16,32,48", "-q", "--passes", "1", "-o"])
        .arg(&out)
        .args(FAST));
    assert_eq!(code(&o), 2);
    let e = stderr(&o);
    assert!(
        e.contains("frame 48")
            && e.contains("manta_smoke_0048.vdb")
            && e.contains("medium[0].path"),
        "{e}"
    );
    assert!(!dir.join("out").exists(), "no work before the check");
    let o = run(ppb()
        .arg("render")
        .arg(&scene)
        .args(["-q", "--passes", "1"])
        .args(FAST));
    assert!(stderr(&o).contains("--frames"), "{}", stderr(&o));
    ok(ppb()
        .arg("render")
        .arg(&scene)
        .args([
            "--frames", "16,32", "--fps", "25", "-q", "--passes", "2", "-o",
        ])
        .arg(&out)
        .args(FAST));
    let (a, b) = (
        bits(&dir.join("out/smoke.0016.exr")),
        bits(&dir.join("out/smoke.0032.exr")),
    );
    assert_ne!(a, b, "each frame reads its own grid");
    assert!(dir.join("out/smoke.0032.png").exists());
    let meta = exr::meta::MetaData::read_from_file(dir.join("out/smoke.0032.exr"), false).unwrap();
    let h = &meta.headers[0].own_attributes;
    assert_eq!(h.frames_per_second, Some((25, 1)));
    assert!(h.world_to_camera.is_some() && h.world_to_normalized_device.is_some());
    assert!(h.capture_date.is_some() && h.utc_offset == Some(0.0) && h.comments.is_some());
    let text = ppb::output::read_exr_text(&dir.join("out/smoke.0032.exr")).unwrap();
    let get = |k: &str| {
        text.iter()
            .find(|(n, _)| n == k)
            .map(|(_, v)| v.clone())
            .unwrap_or_else(|| panic!("{k} missing from {text:?}"))
    };
    assert_eq!(get("ppb/frame"), "32");
    assert_eq!(get("ppb/passes"), "2");
    assert_eq!(get("ppb/pass_range"), "0..2");
    assert_eq!(get("ppb/seed"), "1");
    assert_eq!(get("ppb/version"), env!("CARGO_PKG_VERSION"));
    assert_eq!(get("ppb/scene_hash").len(), 64);
    assert!(get("ppb/render_seconds").parse::<f64>().is_ok());
}

/// `ppb plan` lists the same tasks `render --task-index` runs; the progress formats print
/// what a farm manager parses; exit codes: 2 for bad input, 1 when the render fails.
#[test]
fn plan_progress_and_exit_codes() {
    let (dir, scene) = sequence("plan");
    let o = ok(ppb().arg("plan").arg(&scene).args([
        "--frames",
        "16,32",
        "--passes",
        "5",
        "--passes-per-task",
        "2",
        "--json",
    ]));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["tasks"], 6);
    assert_eq!(v["list"][4]["frame"], 32);
    assert_eq!(v["list"][4]["passes"]["start"], 2);
    assert_eq!(v["list"][4]["passes"]["end"], 4);
    let o = run(ppb()
        .arg("plan")
        .arg(&scene)
        .args(["--frames", "16-17", "--passes", "5"]));
    assert_eq!(code(&o), 2);
    assert!(stderr(&o).contains("manta_smoke_0017.vdb"));

    let progress = |kind: &str| {
        let o = ok(ppb()
            .arg("render")
            .arg(&scene)
            .args(["--frames", "16", "--passes", "4", "--progress", kind, "-o"])
            .arg(dir.join(format!("{kind}.exr")))
            .args(FAST));
        String::from_utf8(o.stdout).unwrap()
    };
    let alf = progress("alf");
    assert_eq!(alf.lines().last(), Some("ALF_PROGRESS 100%"));
    assert_eq!(alf.lines().count(), 4, "{alf}");
    let ojd = progress("openjd");
    assert_eq!(ojd.lines().next(), Some("openjd_progress: 25.0"));
    let json = progress("json");
    let last: serde_json::Value = serde_json::from_str(json.lines().last().unwrap()).unwrap();
    assert_eq!(
        (last["pass"].as_u64(), last["frame"].as_u64()),
        (Some(4), Some(16))
    );
    assert_eq!(last["fraction"].as_f64(), Some(1.0));
    assert!(last["eta_s"].as_f64().is_some());

    // An output path that is a folder: the render runs, its write fails: exit 1.
    std::fs::create_dir_all(dir.join("taken.exr")).unwrap();
    let o = run(ppb()
        .arg("render")
        .arg(&scene)
        .args(["--frames", "16", "--passes", "1", "-q", "-o"])
        .arg(dir.join("taken.exr"))
        .args(FAST));
    assert_eq!(code(&o), 1, "{}", stderr(&o));
    let o = run(ppb()
        .arg("render")
        .arg(&scene)
        .args([
            "--frames",
            "16",
            "--task-index",
            "9",
            "--passes-per-task",
            "2",
            "--passes",
            "4",
        ])
        .args(FAST));
    assert_eq!(code(&o), 2);
    assert!(stderr(&o).contains("tasks 0..=1"), "{}", stderr(&o));
}

/// Whether a farm tool is here (for Slurm: a cluster that answers); without it the test
/// is skipped, unless CI requires it.
fn have(tool: &str, test: &str) -> bool {
    let probe = match tool {
        "sbatch" => "sinfo -h >/dev/null 2>&1".to_string(),
        t => format!("command -v {t}"),
    };
    let found = Command::new("sh")
        .args(["-c", &probe])
        .output()
        .is_ok_and(|o| o.status.success());
    if !found {
        if std::env::var("PPB_REQUIRE_FARM").as_deref() == Ok("1") {
            panic!("{test}: PPB_REQUIRE_FARM=1 but {tool} is missing");
        }
        eprintln!("{test}: skipped ({tool} not found)");
    }
    found
}

/// `ppb farm` job files for frames 16 and 32 in tasks of 2 of 5 passes.
fn farm(engine: &str, dir: &Path, scene: &Path, extra: &[&str]) -> PathBuf {
    let jobs = dir.join(engine);
    ok(ppb()
        .args(["farm", engine])
        .arg(scene)
        .args([
            "--frames",
            "16,32",
            "--passes",
            "5",
            "--passes-per-task",
            "2",
            "-o",
        ])
        .arg(jobs.join("out/smoke.####.exr"))
        .arg("--jobs")
        .arg(&jobs)
        .args(extra)
        .arg("--")
        .args(FAST));
    jobs
}

/// An engine test's set-up, or None (skipped) without `tool`: the folder, the scene, one
/// machine's bits of frame 16 and the folder of the job files.
fn setup(tool: &str, engine: &str, test: &str) -> Option<(PathBuf, PathBuf, Vec<u32>, PathBuf)> {
    if !have(tool, test) {
        return None;
    }
    let (dir, scene) = sequence(engine);
    let want = single(&scene, &dir.join("one/s.####.exr"), 5);
    let jobs = farm(engine, &dir, &scene, &[]);
    Some((dir, scene, want, jobs))
}

/// A real Slurm array of 6 tasks and its merge: the frames equal one machine's renders bit
/// for bit; with a task made to fail, submit.sh exits non-zero and the merge never runs.
#[test]
fn slurm_array_and_merge() {
    let Some((dir, scene, want, jobs)) = setup("sbatch", "slurm", "slurm_array_and_merge") else {
        return;
    };
    let t0 = Instant::now();
    let o = ok(Command::new("bash").arg(jobs.join("submit.sh")));
    eprintln!(
        "slurm: 6 tasks and a merge in {:.1} s",
        t0.elapsed().as_secs_f64()
    );
    assert!(String::from_utf8_lossy(&o.stdout).contains("merge: COMPLETED"));
    assert_eq!(bits(&jobs.join("out/smoke.0016.exr")), want);
    assert!(jobs.join("out/smoke.0032.exr").exists());

    // A ppb that fails task 3 (and would tell if the merge ran).
    let wrapper = dir.join("failing-ppb.sh");
    std::fs::write(
        &wrapper,
        format!(
            "#!/bin/sh\n[ \"$SLURM_ARRAY_TASK_ID\" = 3 ] && exit 3\n[ \"$1\" = merge ] && touch {}\nexec {} \"$@\"\n",
            dir.join("merge-ran").display(),
            env!("CARGO_BIN_EXE_ppb")
        ),
    )
    .unwrap();
    ok(Command::new("chmod").arg("+x").arg(&wrapper));
    let failing = dir.join("failing");
    std::fs::create_dir_all(&failing).unwrap();
    let jobs = farm(
        "slurm",
        &failing,
        &scene,
        &["--ppb", &wrapper.to_string_lossy()],
    );
    let o = run(Command::new("bash").arg(jobs.join("submit.sh")));
    assert_ne!(code(&o), 0, "{}", String::from_utf8_lossy(&o.stdout));
    assert!(!dir.join("merge-ran").exists(), "the merge must not run");
    assert!(!jobs.join("out/smoke.0016.exr").exists());
}

/// The OpenJD template passes `openjd check` and `openjd run` runs all its tasks, then
/// the merge, to the single-machine bits.
#[test]
fn openjd_template_runs() {
    let Some((_, _, want, jobs)) = setup("openjd", "openjd", "openjd_template_runs") else {
        return;
    };
    let template = jobs.join("job.template.yaml");
    ok(Command::new("openjd").arg("check").arg(&template));
    let t0 = Instant::now();
    let o = ok(Command::new("openjd").arg("run").arg(&template));
    eprintln!(
        "openjd: 6 tasks and a merge in {:.1} s",
        t0.elapsed().as_secs_f64()
    );
    assert!(String::from_utf8_lossy(&o.stdout).contains("openjd_progress: 100.0"));
    assert_eq!(bits(&jobs.join("out/smoke.0016.exr")), want);
    assert!(jobs.join("out/smoke.0032.exr").exists());
}

/// The Kubernetes Jobs validate strictly against Kubernetes 1.33; running each index's
/// container command here with JOB_COMPLETION_INDEX set, then the merge's, gives the
/// single-machine bits.
#[test]
fn k8s_jobs_validate_and_run_by_index() {
    let Some((dir, _, want, jobs)) = setup(
        "kubernetes-validate",
        "k8s",
        "k8s_jobs_validate_and_run_by_index",
    ) else {
        return;
    };
    let (render, merge) = (jobs.join("render-job.yaml"), jobs.join("merge-job.yaml"));
    ok(Command::new("kubernetes-validate")
        .args(["--strict", "-k", "1.33.0"])
        .arg(&render)
        .arg(&merge));
    // The fields the schema leaves open, and each Job's container command, read with
    // PyYAML (kubernetes-validate's own YAML reader).
    let read = r#"
import sys, json, yaml
job = yaml.safe_load(open(sys.argv[1]))
spec = job["spec"]; pod = spec["template"]["spec"]
assert pod["restartPolicy"] in ("Never", "OnFailure")
assert spec.get("completionMode", "Indexed") in ("Indexed", "NonIndexed")
print(json.dumps({"n": spec.get("completions", 1), "cmd": pod["containers"][0]["command"],
  "dir": pod["containers"][0]["workingDir"], "mount": pod["containers"][0]["volumeMounts"][0]["mountPath"]}))
"#;
    let job = |p: &Path| -> serde_json::Value {
        let o = ok(Command::new("python3").args(["-c", read]).arg(p));
        serde_json::from_slice(&o.stdout).unwrap()
    };
    let (r, m) = (job(&render), job(&merge));
    assert_eq!(r["n"], 6);
    // The deepest folder holding the scene, its assets and the outputs is mounted.
    assert_eq!(Path::new(r["mount"].as_str().unwrap()), dir);
    let bin = Path::new(env!("CARGO_BIN_EXE_ppb")).parent().unwrap();
    let path = format!(
        "{}:{}",
        bin.display(),
        std::env::var("PATH").unwrap_or_default()
    );
    let exec = |v: &serde_json::Value, index: Option<u32>| {
        let cmd: Vec<String> = serde_json::from_value(v["cmd"].clone()).unwrap();
        let mut c = Command::new(&cmd[0]);
        c.args(&cmd[1..])
            .current_dir(v["dir"].as_str().unwrap())
            .env("PATH", &path);
        if let Some(k) = index {
            c.env("JOB_COMPLETION_INDEX", k.to_string());
        }
        ok(&mut c);
    };
    for k in 0..6 {
        exec(&r, Some(k));
    }
    exec(&m, None);
    assert_eq!(bits(&jobs.join("out/smoke.0016.exr")), want);
}

/// The frame token inside a USD stage: a sublayer named per frame and an OpenVDBAsset
/// path, both with ####, resolve to the frame's files.
#[test]
fn frames_reach_usd_layers_and_assets() {
    let (dir, _) = sequence("usd");
    let shot = dir.join("shot");
    let repo = Path::new(env!("CARGO_MANIFEST_DIR"));
    let vdb48 = "manta_smoke_0048.vdb";
    std::fs::copy(repo.join("scenes/mantaflow").join(vdb48), shot.join(vdb48)).unwrap();
    for f in [16, 32] {
        std::fs::write(
            shot.join(format!("light.{f:04}.usda")),
            format!(
                "#usda 1.0\n(\n    upAxis = \"Y\"\n)\n\ndef DistantLight \"Sun\"\n{{\n    float inputs:intensity = {}\n    float3 xformOp:rotateXYZ = (-60, 20, 0)\n    uniform token[] xformOpOrder = [\"xformOp:rotateXYZ\"]\n}}\n",
                f / 16
            ),
        )
        .unwrap();
    }
    std::fs::write(
        shot.join("stage.usda"),
        r#"#usda 1.0
(
    subLayers = [@./light.####.usda@]
    metersPerUnit = 1
    upAxis = "Z"
)

def Volume "Smoke"
{
    custom rel field:density = </Smoke/density>
    float ppb:densityScale = 20

    def OpenVDBAsset "density"
    {
        token fieldName = "density"
        asset filePath = @./manta_smoke_####.vdb@
    }
}
"#,
    )
    .unwrap();
    std::fs::write(
        shot.join("stage.ppb.toml"),
        "[render]\npasses = 1\n\n[camera]\norigin = [0, 1.2, 4.2]\ntarget = [0, 0.9, 0]\nup = [0, 1, 0]\nvfov = 40\n",
    )
    .unwrap();
    let out = dir.join("out/usd.####.exr");
    // Frame 48 has its grid but no light layer: refused before any frame renders.
    let o = run(ppb()
        .arg("render")
        .arg(shot.join("stage.usda"))
        .args(["--frames", "16,32,48", "-q", "-o"])
        .arg(&out)
        .args(FAST));
    assert_eq!(code(&o), 2, "{}", stderr(&o));
    assert!(stderr(&o).contains("frame 48"), "{}", stderr(&o));
    assert!(stderr(&o).contains("light.0048.usda"), "{}", stderr(&o));
    assert!(!dir.join("out").exists());
    ok(ppb()
        .arg("render")
        .arg(shot.join("stage.usda"))
        .args(["--frames", "16,32", "-q", "-o"])
        .arg(&out)
        .args(FAST));
    let mean = |f: u32| -> f64 {
        let p = ppb::core::frames::with_frame(&out.to_string_lossy(), f);
        let img = ppb::output::read_exr(Path::new(&p)).unwrap();
        img.pixels.iter().flatten().map(|&x| x as f64).sum::<f64>() / img.pixels.len() as f64
    };
    let (a, b) = (mean(16), mean(32));
    // Frame 32's sun is twice as bright, and its smoke another grid.
    assert!(a > 0.0 && b > 1.3 * a, "{a} {b}");
    // Without --frames the token names no file: one clear error.
    let o = run(ppb()
        .arg("render")
        .arg(shot.join("stage.usda"))
        .args(["-q", "-o"])
        .arg(dir.join("none.exr"))
        .args(FAST));
    assert_eq!(code(&o), 2, "{}", stderr(&o));
    assert!(stderr(&o).contains("####"), "{}", stderr(&o));
}
