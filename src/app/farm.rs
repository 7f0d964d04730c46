//! `ppb farm`: the job files that let Slurm, OpenJD or Kubernetes run a render's tasks
//! and the merge (ppb schedules nothing itself), and the task flags `plan`, `farm` and
//! `render` share.
use anyhow::{Context, Result};
use clap::{Args, ValueEnum};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use ppb::farm::Tasks;
use ppb::scene::toml as scene_toml;

use super::render::frame_list;

/// The flags that define a render's tasks (the same on `plan`, `farm` and `render`).
#[derive(Args, Clone, Debug)]
pub struct TaskFlags {
    /// Scene file; a run of # in it (and in the paths it names) is the frame number.
    pub scene: PathBuf,
    /// Frames, e.g. 1-240,300 (default: a still).
    #[arg(long, value_name = "LIST")]
    pub frames: Option<String>,
    /// Passes per frame (default: the scene's [render].passes).
    #[arg(long)]
    pub passes: Option<u32>,
    /// Passes per task (default: all of a frame's passes, one task per frame).
    #[arg(long, value_name = "P")]
    pub passes_per_task: Option<u32>,
}

impl TaskFlags {
    /// The tasks, after checking every frame's files.
    pub(super) fn tasks(&self) -> Result<(Vec<u32>, Tasks)> {
        let frames = frame_list(self.frames.as_deref())?;
        if !frames.is_empty() {
            scene_toml::check_frames(&self.scene, &frames)?;
        }
        let passes = match self.passes {
            Some(p) => p,
            None => {
                super::load_frame(&self.scene, frames.first().copied())?
                    .settings
                    .passes
            }
        };
        let per = self.passes_per_task.unwrap_or(passes);
        Ok((frames.clone(), Tasks::new(&frames, passes, per)?))
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum Engine {
    /// Slurm: a job array and a merge job with --dependency=afterok.
    Slurm,
    /// Open Job Description (AWS Deadline Cloud): a render step and a merge step.
    Openjd,
    /// Kubernetes: an Indexed Job and a merge Job.
    K8s,
}

#[derive(Args)]
pub struct FarmArgs {
    /// The engine to write job files for.
    #[arg(value_enum)]
    pub engine: Engine,
    #[command(flatten)]
    pub tasks: TaskFlags,
    /// Output EXR of every frame, with a run of # for the frame number (default:
    /// <scene stem>.####.exr, or <scene stem>.exr for a still, beside the job files).
    #[arg(short, long)]
    pub output: Option<PathBuf>,
    /// Folder for the job files (created).
    #[arg(long, default_value = "farm")]
    pub jobs: PathBuf,
    /// The ppb the tasks run (default: this executable; on Kubernetes, `ppb` in the image).
    #[arg(long)]
    pub ppb: Option<PathBuf>,
    /// Kubernetes: the container image with ppb on its PATH.
    #[arg(long, default_value = "ppb:latest")]
    pub image: String,
    /// Kubernetes: the PersistentVolumeClaim holding the deepest folder that contains the
    /// scene and the outputs, mounted at that folder's absolute path here, so every path
    /// in the job stays valid.
    #[arg(long, default_value = "ppb-project")]
    pub claim: String,
    /// More `ppb render` flags for every task, after `--` (e.g. -- --device cpu --threads 8).
    #[arg(last = true)]
    pub render_args: Vec<String>,
}

/// The absolute form of `p`, `.` and `..` resolved by name (the file need not exist).
fn absolute(p: &Path) -> Result<PathBuf> {
    use std::path::Component;
    let abs = std::path::absolute(p).with_context(|| format!("resolving {}", p.display()))?;
    let mut out = PathBuf::new();
    for c in abs.components() {
        match c {
            Component::ParentDir => {
                out.pop();
            }
            Component::CurDir => {}
            c => out.push(c),
        }
    }
    Ok(out)
}

/// The commands of a farm render, as argument lists.
struct Commands {
    /// `ppb render` of one task, without the task index flag.
    render: Vec<String>,
    merge: Vec<String>,
    count: u32,
    /// The deepest folder holding the scene and the outputs (what a container mounts).
    shared: PathBuf,
}

/// The deepest folder that holds both `a` and `b`.
fn common_folder(a: &Path, b: &Path) -> PathBuf {
    a.ancestors()
        .find(|d| b.starts_with(d))
        .unwrap_or(Path::new("/"))
        .to_path_buf()
}

fn commands(args: &FarmArgs, ppb: String) -> Result<Commands> {
    let (frames, tasks) = args.tasks.tasks()?;
    let scene = absolute(&args.tasks.scene)?;
    let output = match &args.output {
        Some(o) => absolute(o)?,
        None => {
            let stem = scene.file_stem().unwrap_or_default().to_string_lossy();
            let stem = stem.replace('#', "");
            let stem = stem.trim_end_matches(['.', '_']).to_string();
            let name = if frames.is_empty() {
                format!("{stem}.exr")
            } else {
                format!("{stem}.####.exr")
            };
            absolute(&args.jobs.join(name))?
        }
    };
    let s = |x: &Path| x.display().to_string();
    let mut render = vec![ppb.clone(), "render".into(), s(&scene)];
    let mut merge = vec![ppb, "merge".into()];
    if let Some(f) = &args.tasks.frames {
        let list = ppb::core::frames::FrameList::parse(f)?.to_string();
        render.extend(["--frames".into(), list.clone()]);
        merge.extend(["--frames".into(), list]);
    }
    render.extend([
        "--passes".into(),
        tasks.passes.to_string(),
        "--passes-per-task".into(),
        tasks.passes_per_task.to_string(),
        "-o".into(),
        s(&output),
    ]);
    render.extend(args.render_args.iter().cloned());
    merge.extend(["-o".into(), s(&output)]);
    let parent = |p: &Path| p.parent().unwrap_or(Path::new("/")).to_path_buf();
    let first = super::load_frame(&scene, frames.first().copied())?;
    let mut shared = parent(&output);
    for src in &first.sources {
        shared = common_folder(&shared, &parent(&absolute(src)?));
    }
    Ok(Commands {
        render,
        merge,
        count: tasks.count(),
        shared,
    })
}

/// `s` quoted for a POSIX shell.
fn sh(s: &str) -> String {
    if !s.is_empty()
        && s.chars()
            .all(|c| c.is_ascii_alphanumeric() || "-_./=:,+#@%".contains(c))
    {
        return s.to_string();
    }
    format!("'{}'", s.replace('\'', r"'\''"))
}

fn sh_line(args: &[String]) -> String {
    args.iter().map(|a| sh(a)).collect::<Vec<_>>().join(" ")
}

/// `s` as a YAML (JSON) double-quoted scalar.
fn yaml(s: &str) -> String {
    serde_json::to_string(s).unwrap_or_default()
}

fn yaml_list(args: &[String]) -> String {
    format!(
        "[{}]",
        args.iter().map(|a| yaml(a)).collect::<Vec<_>>().join(", ")
    )
}

pub fn farm(args: FarmArgs) -> Result<ExitCode> {
    std::fs::create_dir_all(&args.jobs)
        .with_context(|| format!("creating {}", args.jobs.display()))?;
    let ppb = match (&args.ppb, args.engine) {
        (Some(p), _) => absolute(p)?.display().to_string(),
        (None, Engine::K8s) => "ppb".to_string(),
        (None, _) => std::env::current_exe()
            .context("finding this executable (give --ppb)")?
            .display()
            .to_string(),
    };
    let c = commands(&args, ppb)?;
    let jobs = absolute(&args.jobs)?;
    let files = match args.engine {
        Engine::Slurm => slurm(&c, &jobs),
        Engine::Openjd => openjd(&c),
        Engine::K8s => k8s(&c, &args, &jobs)?,
    };
    for (name, text, exec) in &files {
        let path = args.jobs.join(name);
        ppb::core::fs::write_atomic(&path, |tmp| {
            std::fs::write(tmp, text).map_err(|e| ppb::error::Error::io(tmp, e))?;
            set_executable(tmp, *exec).map_err(|e| ppb::error::Error::io(tmp, e))
        })?;
        println!("{}", path.display());
    }
    eprintln!("{} tasks, then a merge", c.count);
    Ok(ExitCode::SUCCESS)
}

#[cfg(unix)]
fn set_executable(p: &Path, exec: bool) -> std::io::Result<()> {
    use std::os::unix::fs::PermissionsExt;
    let mode = if exec { 0o755 } else { 0o644 };
    std::fs::set_permissions(p, std::fs::Permissions::from_mode(mode))
}

#[cfg(not(unix))]
fn set_executable(_: &Path, _: bool) -> std::io::Result<()> {
    Ok(())
}

/// A job file: name, text, executable.
type JobFile = (&'static str, String, bool);

/// render.sbatch (the array), merge.sbatch and submit.sh, which submits both and waits:
/// it exits non-zero when a task fails, and the merge then never runs.
fn slurm(c: &Commands, jobs: &Path) -> Vec<JobFile> {
    let logs = jobs.join("logs");
    let mut render = String::new();
    let _ = writeln!(render, "#!/bin/bash");
    let _ = writeln!(render, "#SBATCH --job-name=ppb-render");
    let _ = writeln!(render, "#SBATCH --array=0-{}", c.count - 1);
    let _ = writeln!(
        render,
        "#SBATCH --output={}/render-%A_%a.log",
        logs.display()
    );
    let _ = writeln!(
        render,
        "# Task K renders `ppb plan`'s task K (frame and pass range)."
    );
    let mut task = c.render.clone();
    task.extend([
        "--task-index-env".into(),
        "SLURM_ARRAY_TASK_ID".into(),
        "--progress".into(),
        "alf".into(),
    ]);
    let _ = writeln!(render, "exec {}", sh_line(&task));
    let mut merge = String::new();
    let _ = writeln!(merge, "#!/bin/bash");
    let _ = writeln!(merge, "#SBATCH --job-name=ppb-merge");
    let _ = writeln!(merge, "#SBATCH --output={}/merge-%j.log", logs.display());
    let _ = writeln!(merge, "exec {}", sh_line(&c.merge));
    let submit = format!(
        r#"#!/bin/bash
# Submits the render array and its merge (afterok: only once every task succeeded), then
# waits for both. Exits 0 when the merge completed; when a task fails the merge is
# cancelled without running and this exits 1. The states are polled because `sbatch
# --wait` reports success for a job cancelled before it ran.
set -euo pipefail
cd "$(dirname "$0")"
mkdir -p {logs}
render=$(sbatch --parsable render.sbatch)
merge=$(sbatch --parsable --kill-on-invalid-dep=yes --dependency=afterok:"$render" merge.sbatch)
echo "render array $render, merge $merge"
# The distinct states of job $1 (every task of an array), once none is still to run.
settled() {{
  local states
  while states=$(scontrol -o show job "$1" | grep -o 'JobState=[A-Z_]*' | cut -d= -f2 | sort -u | tr '\n' ' ')
    [[ $states =~ PENDING|RUNNING|CONFIGURING|COMPLETING|SUSPENDED|REQUEUE|RESIZING|STAGE_OUT|SIGNALING ]]
  do sleep 0.5; done
  echo "$states"
}}
echo "render: $(settled "$render")"
state=$(settled "$merge")
echo "merge: $state"
[ "$state" = "COMPLETED " ]
"#,
        logs = sh(&logs.display().to_string())
    );
    vec![
        ("render.sbatch", render, false),
        ("merge.sbatch", merge, false),
        ("submit.sh", submit, true),
    ]
}

/// An OpenJD job template: the render step over the task index, the merge step after it.
fn openjd(c: &Commands) -> Vec<JobFile> {
    let mut task = c.render.clone();
    task.extend([
        "--task-index".into(),
        "{{Task.Param.Index}}".into(),
        "--progress".into(),
        "openjd".into(),
    ]);
    let step = |name: &str, args: &[String], extra: &str| {
        format!(
            "  - name: {name}\n{extra}    script:\n      actions:\n        onRun:\n          command: {}\n          args: {}\n",
            yaml(&args[0]),
            yaml_list(&args[1..])
        )
    };
    let space = format!(
        "    parameterSpace:\n      taskParameterDefinitions:\n        - name: Index\n          type: INT\n          range: \"0-{}\"\n",
        c.count - 1
    );
    let text = format!(
        "# Open Job Description template written by `ppb farm openjd`: `openjd run\n# job.template.yaml` runs every render task, then the merge; or submit it to AWS\n# Deadline Cloud.\nspecificationVersion: jobtemplate-2023-09\nname: ppb render\nsteps:\n{}{}",
        step("render", &task, &space),
        step(
            "merge",
            &c.merge,
            "    dependencies:\n      - dependsOn: render\n"
        )
    );
    vec![("job.template.yaml", text, false)]
}

/// A Kubernetes Indexed Job of the tasks and a merge Job, and submit.sh, which applies
/// the render job, waits for it and then runs the merge.
fn k8s(c: &Commands, args: &FarmArgs, jobs: &Path) -> Result<Vec<JobFile>> {
    let mount = c.shared.display().to_string();
    let mut task = c.render.clone();
    task.extend([
        "--task-index-env".into(),
        "JOB_COMPLETION_INDEX".into(),
        "--progress".into(),
        "json".into(),
    ]);
    let job = |name: &str, indexed: bool, cmd: &[String]| {
        let index = if indexed {
            format!(
                "  completionMode: Indexed\n  completions: {n}\n  parallelism: {p}\n  backoffLimitPerIndex: 1\n",
                n = c.count,
                p = c.count.min(64)
            )
        } else {
            "  backoffLimit: 1\n".to_string()
        };
        format!(
            "apiVersion: batch/v1\nkind: Job\nmetadata:\n  name: {name}\nspec:\n{index}  template:\n    spec:\n      restartPolicy: Never\n      containers:\n        - name: ppb\n          image: {image}\n          workingDir: {mount}\n          command: {cmd}\n          volumeMounts:\n            - name: project\n              mountPath: {mount}\n      volumes:\n        - name: project\n          persistentVolumeClaim:\n            claimName: {claim}\n",
            image = yaml(&args.image),
            mount = yaml(&mount),
            cmd = yaml_list(cmd),
            claim = yaml(&args.claim),
        )
    };
    let submit = r#"#!/bin/bash
# Runs the render tasks as an Indexed Job, then the merge once all of them succeeded
# (Kubernetes cannot make one Job wait for another). Exits 1 when a Job fails.
set -euo pipefail
cd "$(dirname "$0")"
# Waits until Job $1 completes (0) or fails (1).
finished() {
  local c
  while :; do
    c=$(kubectl get job "$1" -o jsonpath='{.status.conditions[?(@.status=="True")].type}')
    case "$c" in
      *Failed*) echo "job/$1 failed" >&2; return 1 ;;
      *Complete*) return 0 ;;
    esac
    sleep 5
  done
}
kubectl apply -f render-job.yaml
finished ppb-render
kubectl apply -f merge-job.yaml
finished ppb-merge
"#
    .to_string();
    let _ = jobs;
    Ok(vec![
        ("render-job.yaml", job("ppb-render", true, &task), false),
        ("merge-job.yaml", job("ppb-merge", false, &c.merge), false),
        ("submit.sh", submit, true),
    ])
}
