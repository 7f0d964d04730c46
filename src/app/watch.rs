//! `ppb watch`: re-renders progressively whenever the scene or a file it references changes.
//!
//! Threads: notify's debouncer delivers file events, the window (if any) delivers key
//! presses, both as [`Msg`] to the render worker, which owns the scene and runs the passes;
//! between two passes it applies pending reloads. A reload that fails (syntax error,
//! missing or truncated asset) is reported and the last good scene keeps rendering.
use anyhow::{Context, Result};
use clap::Args;
use notify::RecursiveMode;
use notify_debouncer_full::{new_debouncer, DebounceEventResult, Debouncer, RecommendedCache};
use std::io::{IsTerminal, Write};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::mpsc::{self, Receiver, RecvTimeoutError, Sender};
use std::sync::Arc;
use std::time::{Duration, Instant};

use ppb::error::Error as PpbError;
use ppb::gpu::Gpu;
use ppb::media::octrees;
use ppb::output::Image;
use ppb::pass::Tracer;
use ppb::plan::Ramp;
use ppb::scene::assets::AssetCache;
use ppb::scene::toml::{self as scene_toml, SceneFile};
use ppb::session::{Flow, Session};
use ppb::settings::RenderSettings;
use ppb::watch::{deps, diff::Changes};

use super::live::{Msg, SharedFrame};
use super::{window, Machine, OutputMeta, Overrides};

#[derive(Args)]
pub struct WatchArgs {
    /// Scene file (.toml, or a USD stage with an optional .ppb.toml sidecar).
    pub scene: PathBuf,
    /// Output EXR; a PNG preview is written beside it. Default: <scene stem>.exr in the
    /// current folder.
    #[arg(short, long)]
    pub output: Option<PathBuf>,
    /// Show the image live in a window (title: passes, time, the beam estimate's device,
    /// exposure, last error; keys: + and - change the exposure, S saves a snapshot, Esc or
    /// Q quits).
    #[arg(long)]
    pub window: bool,
    /// Passes per (re)start, overriding [render].passes; 0 refines forever.
    #[arg(long)]
    pub passes: Option<u32>,
    /// Trace all light paths from the first pass after a reload (default: the ramp: the
    /// first pass traces 1/8 of them, and each next pass twice as many while a pass takes
    /// under 0.15 s, so the preview restarts quickly and passes stay short).
    #[arg(long)]
    pub no_ramp: bool,
    /// Rewrite the EXR/PNG every K passes ("8") or S seconds ("2s"); the first pass after
    /// every reload and the last pass are always written.
    #[arg(long, value_parser = parse_checkpoint, default_value = "1s")]
    pub checkpoint: Checkpoint,
    #[command(flatten)]
    pub over: Overrides,
    #[command(flatten)]
    pub machine: Machine,
    /// No status line (event lines such as reloads and errors are still printed).
    #[arg(short, long)]
    pub quiet: bool,
}

/// When to rewrite the outputs while refining.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Checkpoint {
    Passes(u32),
    Seconds(f64),
}

fn parse_checkpoint(s: &str) -> std::result::Result<Checkpoint, String> {
    let bad = || format!("expected passes (\"8\") or seconds (\"2s\", \"0.5s\"), got \"{s}\"");
    match s.strip_suffix('s') {
        Some(secs) => match secs.parse::<f64>() {
            Ok(x) if x.is_finite() && x > 0.0 => Ok(Checkpoint::Seconds(x)),
            _ => Err(bad()),
        },
        None => match s.parse::<u32>() {
            Ok(k) if k > 0 => Ok(Checkpoint::Passes(k)),
            _ => Err(bad()),
        },
    }
}

pub fn watch(args: WatchArgs) -> Result<ExitCode> {
    super::set_threads(args.machine.threads)?;
    let out = super::output_path(&args.scene, args.output.as_ref())?;
    let gpu = super::open_device(args.machine.device, false)?;
    let (tx, rx) = mpsc::channel();
    let shared: SharedFrame = Arc::default();
    let mut ui = None;
    if args.window {
        match window::Window::open(shared.clone(), tx.clone()) {
            Ok(w) => ui = Some(w),
            Err(e) => eprintln!("error: --window: {e:#}; rendering to the files only"),
        }
    }
    let wake = ui.as_ref().map(|w| w.waker());
    let worker = {
        let tx = tx.clone();
        let shared = shared.clone();
        std::thread::Builder::new()
            .name("render".into())
            .spawn(move || Worker::new(args, out, gpu, tx, shared, wake).run(rx))
            .context("starting the render thread")?
    };
    if let Some(w) = ui {
        match w.run() {
            // Closing the window ends the session; outputs on disk are always complete.
            Ok(()) => return Ok(ExitCode::SUCCESS),
            Err(e) => eprintln!("error: --window: {e:#}; rendering to the files only"),
        }
    }
    worker
        .join()
        .map_err(|_| anyhow::anyhow!("the render thread panicked"))??;
    Ok(ExitCode::SUCCESS)
}

/// The scene being rendered and its session.
struct Current {
    file: SceneFile,
    settings: RenderSettings,
    session: Session,
}

/// The render thread: owns the scene, the accumulation, the watcher and the status line.
struct Worker {
    args: WatchArgs,
    out: PathBuf,
    cache_dir: PathBuf,
    assets: AssetCache,
    trees: octrees::OctreeStore,
    /// The beam estimate's GPU (None: the CPU), shared by every reload's session.
    gpu: Option<Gpu>,
    current: Option<Current>,
    generation: u32,
    /// When the change behind the current generation was seen.
    changed_at: Instant,
    gen_start: Instant,
    last_write: Instant,
    written_at_pass: u32,
    watched: Vec<PathBuf>,
    folders: Vec<PathBuf>,
    debouncer: Option<Debouncer<notify::RecommendedWatcher, RecommendedCache>>,
    tx: Sender<Msg>,
    shared: SharedFrame,
    wake: Option<Box<dyn Fn() + Send>>,
    status: Status,
    snapshots: u32,
    /// Timings behind the latest preview line: seen-to-renderer, last pass.
    reload_seconds: f64,
    pass_seconds: f64,
    pass_paths: usize,
}

/// The one-line terminal status: redrawn in place on a terminal, absent otherwise.
struct Status {
    tty: bool,
    scene: String,
    last_reload: String,
    last_error: Option<String>,
    /// The image's estimated rel_l1 per pixel at the last write (None before 4 passes).
    estimate: Option<f64>,
    line: String,
    /// When the line was last drawn: redraws are limited to 10 per second.
    drawn: Option<Instant>,
}

impl Status {
    /// An event line (reload, error, octree): printed above the status line.
    fn log(&mut self, msg: &str) {
        let mut err = std::io::stderr().lock();
        if self.tty {
            let _ = write!(err, "\r\x1b[K{msg}\n{}", self.line);
        } else {
            let _ = writeln!(err, "{msg}");
        }
        let _ = err.flush();
    }

    fn show(&mut self, line: String) {
        if self
            .drawn
            .is_some_and(|t| t.elapsed() < Duration::from_millis(100))
        {
            return;
        }
        self.drawn = Some(Instant::now());
        self.line = line;
        if self.tty {
            let mut err = std::io::stderr().lock();
            let _ = write!(err, "\r\x1b[K{}", self.line);
            let _ = err.flush();
        }
    }
}

impl Worker {
    fn new(
        args: WatchArgs,
        out: PathBuf,
        gpu: Option<Gpu>,
        tx: Sender<Msg>,
        shared: SharedFrame,
        wake: Option<Box<dyn Fn() + Send>>,
    ) -> Self {
        let now = Instant::now();
        let status = Status {
            tty: !args.quiet && std::io::stderr().is_terminal(),
            scene: args.scene.display().to_string(),
            last_reload: "none yet".into(),
            last_error: None,
            estimate: None,
            line: String::new(),
            drawn: None,
        };
        Worker {
            cache_dir: super::cache_dir_for(&args.scene, args.machine.cache_dir.as_ref()),
            watched: vec![deps::absolute(&args.scene)],
            args,
            out,
            assets: AssetCache::new(),
            trees: octrees::OctreeStore::new(),
            gpu,
            current: None,
            generation: 0,
            changed_at: now,
            gen_start: now,
            last_write: now,
            written_at_pass: 0,
            folders: Vec::new(),
            debouncer: None,
            tx,
            shared,
            wake,
            status,
            snapshots: 0,
            reload_seconds: 0.0,
            pass_seconds: 0.0,
            pass_paths: 0,
        }
    }

    fn run(mut self, rx: Receiver<Msg>) -> Result<()> {
        let tx = self.tx.clone();
        let debouncer = new_debouncer(
            Duration::from_millis(50),
            None,
            move |r: DebounceEventResult| {
                let _ = tx.send(match r {
                    Ok(events) => Msg::Files(
                        events
                            .into_iter()
                            .filter(|e| !e.kind.is_access())
                            .flat_map(|e| e.event.paths)
                            .collect(),
                    ),
                    Err(errors) => Msg::WatchError(
                        errors
                            .iter()
                            .map(|e| e.to_string())
                            .collect::<Vec<_>>()
                            .join("; "),
                    ),
                });
            },
        )
        .context("starting the file watcher")?;
        self.debouncer = Some(debouncer);
        self.update_watches();
        self.reload(&[]);
        loop {
            let idle = !self.refining();
            let first = if idle {
                match rx.recv_timeout(Duration::from_millis(500)) {
                    Ok(m) => Some(m),
                    Err(RecvTimeoutError::Timeout) => None,
                    Err(RecvTimeoutError::Disconnected) => return Ok(()),
                }
            } else {
                rx.try_recv().ok()
            };
            let mut touched = Vec::new();
            for msg in first.into_iter().chain(rx.try_iter()) {
                match msg {
                    Msg::Files(paths) => touched.extend(deps::touched(&self.watched, &paths)),
                    Msg::WatchError(e) => self.error(format!("file watcher: {e}")),
                    Msg::Snapshot { exposure } => self.snapshot(exposure),
                }
            }
            if !touched.is_empty() {
                touched.sort();
                touched.dedup();
                self.changed_at = Instant::now();
                self.reload(&touched);
            }
            if self.refining() {
                self.pass();
            } else {
                self.show_status();
            }
        }
    }

    fn budget(&self) -> u32 {
        let scene = self.current.as_ref().map_or(0, |c| c.settings.passes);
        self.args.passes.unwrap_or(scene)
    }

    fn refining(&self) -> bool {
        self.current.is_some() && (self.budget() == 0 || self.passes() < self.budget())
    }

    /// Passes in the current image.
    fn passes(&self) -> u32 {
        self.current.as_ref().map_or(0, |c| c.session.passes())
    }

    /// Reports an error once (a save seen twice gives the same error twice).
    fn error(&mut self, msg: String) {
        if self.status.last_error.as_ref() == Some(&msg) {
            return;
        }
        let then = if self.current.is_some() {
            "still rendering the last good scene"
        } else {
            "waiting for the file to be fixed"
        };
        self.status.log(&format!("error: {msg}; {then}"));
        self.status.last_error = Some(msg);
        self.publish_error();
    }

    /// Reloads the scene after `touched` changed (empty: the first load).
    fn reload(&mut self, touched: &[PathBuf]) {
        let names: Vec<String> = touched.iter().map(|p| short(p)).collect();
        let file = match scene_toml::load_cached(&self.args.scene, &mut self.assets) {
            Ok(f) => f,
            Err(e) => {
                // A missing asset is watched too, so creating it resumes rendering.
                if let PpbError::Io { path, .. } = &e {
                    let p = deps::absolute(path);
                    if !self.watched.contains(&p) {
                        self.watched.push(p);
                        self.update_watches();
                    }
                }
                return self.error(e.to_string());
            }
        };
        let loaded = self.assets.loaded().to_vec();
        for w in &file.warnings {
            self.status.log(&format!("warning: {w}"));
        }
        let settings = match self.args.over.apply(&file.settings) {
            Ok(s) => s,
            Err(e) => return self.error(format!("{e:#}")),
        };
        let changes = self
            .current
            .as_ref()
            .map(|c| Changes::between(&c.file.scene, &c.settings, &file.scene, &settings));
        if let (Some(c), Some(cur)) = (&changes, &mut self.current) {
            if !c.restart() {
                cur.settings.exposure = settings.exposure;
                cur.file = file;
                self.status.last_error = None;
                let what = format!("{}: {}; kept the image", names.join(", "), c.describe());
                self.status.log(&format!("reload: {what}"));
                self.status.last_reload = what;
                self.publish_error();
                if c.exposure {
                    match self.image() {
                        Some(Ok(img)) => self.write_outputs("exposure", &img),
                        Some(Err(e)) => self.error(format!("reading the image: {e}")),
                        None => {}
                    }
                }
                return;
            }
        }
        let session = match self.session(&file, &settings) {
            Ok(s) => s,
            Err(e) => return self.error(e.to_string()),
        };
        let reused = session.1;
        let session = session.0;
        self.generation += 1;
        let what = match &changes {
            None => format!("loaded {}", short(&self.args.scene)),
            Some(c) => summary(&names, c, &loaded, reused),
        };
        self.status
            .log(&format!("reload {}: {what}", self.generation));
        self.status.last_reload = what;
        self.status.last_error = None;
        self.status.estimate = None;
        self.current = Some(Current {
            file,
            settings,
            session,
        });
        self.reload_seconds = self.changed_at.elapsed().as_secs_f64();
        self.watched = deps::files(&self.current.as_ref().expect("just set").file);
        self.update_watches();
        self.gen_start = Instant::now();
        self.written_at_pass = 0;
        self.publish_error();
    }

    /// A session for the scene (octrees kept, cached or built, every non-kept one logged)
    /// and how many octrees were kept from the previous scene.
    fn session(
        &mut self,
        file: &SceneFile,
        settings: &RenderSettings,
    ) -> ppb::error::Result<(Session, usize)> {
        let mut lines = Vec::new();
        let mut reused = 0;
        let media = self.trees.media(
            &file.scene.media,
            &file.scene.grid_media,
            settings.octree_depth,
            Some(&self.cache_dir),
            |i, g, origin| match origin {
                octrees::Origin::Reused => reused += 1,
                _ => lines.push(octrees::describe(i, g, origin)),
            },
        );
        for l in &lines {
            self.status.log(l);
        }
        let tracer = Tracer::with_media(&file.scene, settings.clone(), media?)?;
        let ramp = if self.args.no_ramp {
            Ramp::Off
        } else {
            Ramp::Doubling
        };
        Ok((
            Session::open(
                tracer,
                self.gpu.clone(),
                self.args.machine.gpu_primary,
                self.args.machine.gpu_tr,
            )?
            .with_ramp(ramp),
            reused,
        ))
    }

    /// Watches the folders of the watched files, and no others.
    fn update_watches(&mut self) {
        let want = deps::folders(&self.watched);
        let Some(d) = self.debouncer.as_mut() else {
            return;
        };
        let mut failed = Vec::new();
        for f in self.folders.iter().filter(|f| !want.contains(f)) {
            let _ = d.unwatch(f);
        }
        for f in want.iter().filter(|f| !self.folders.contains(f)) {
            if let Err(e) = d.watch(f, RecursiveMode::NonRecursive) {
                failed.push(format!("cannot watch {}: {e}", f.display()));
            }
        }
        self.folders = want;
        for e in failed {
            self.status.log(&format!("warning: {e}"));
        }
    }

    fn pass(&mut self) {
        let Some(cur) = &mut self.current else {
            return;
        };
        let i = cur.session.passes() + 1;
        let mut last = (0, 0.0);
        let r = cur.session.run([i], |_, done| {
            last = (done.plan.light_paths, done.seconds);
            Ok::<_, ppb::error::Error>(Flow::Continue)
        });
        if let Err(e) = r {
            self.current = None;
            return self.error(format!("pass {i}: {e}"));
        }
        (self.pass_paths, self.pass_seconds) = last;
        let due = match self.args.checkpoint {
            Checkpoint::Passes(k) => i - self.written_at_pass >= k,
            Checkpoint::Seconds(s) => self.last_write.elapsed().as_secs_f64() >= s,
        };
        let last = self.budget() != 0 && i >= self.budget();
        let write = self.written_at_pass == 0 || due || last;
        // One image per pass serves both the files and the window (a read-back on the GPU).
        if write || self.wake.is_some() {
            let img = match self.image() {
                Some(Ok(img)) => img,
                Some(Err(e)) => return self.error(format!("reading the image: {e}")),
                None => return,
            };
            if write {
                self.status.estimate = self.current.as_mut().and_then(|c| {
                    let e = c.session.error_estimate().ok().flatten();
                    e.map(|e| e.pixel)
                });
                let first = self.written_at_pass == 0;
                self.write_outputs(if first { "first pass" } else { "checkpoint" }, &img);
            }
            self.publish(img);
        }
        if last {
            self.status.log(&format!(
                "{} passes done in {:.1} s, {} written; watching for changes",
                i,
                self.seconds(),
                self.out.display()
            ));
        }
        self.show_status();
    }

    fn seconds(&self) -> f64 {
        self.gen_start.elapsed().as_secs_f64()
    }

    /// The current image (None before a scene's first pass).
    fn image(&mut self) -> Option<ppb::error::Result<Image>> {
        let cur = self.current.as_mut()?;
        (cur.session.passes() > 0).then(|| cur.session.image())
    }

    /// `img` written to `path` with `exposure` (and `extra` header lines); returns its
    /// passes.
    fn write_image(
        &self,
        path: &Path,
        img: &Image,
        exposure: f32,
        extra: &[(String, String)],
    ) -> Result<u32> {
        let Some(cur) = &self.current else {
            anyhow::bail!("no image yet");
        };
        let settings = RenderSettings {
            exposure,
            ..cur.settings.clone()
        };
        let meta = OutputMeta {
            scene: &self.args.scene,
            settings: &settings,
            kernel: cur.session.tracer().view().kernel,
            passes: cur.session.passes(),
            seconds: self.seconds(),
            extra,
        };
        super::write_outputs(path, img, &meta)?;
        Ok(meta.passes)
    }

    /// Rewrites the EXR and PNG with `img` (atomically); the first write of a generation
    /// is logged with the time since the change was seen.
    fn write_outputs(&mut self, why: &str, img: &Image) {
        let Some(cur) = &self.current else {
            return;
        };
        let exposure = cur.settings.exposure;
        let mut extra = vec![("ppb/reload".to_string(), self.generation.to_string())];
        if let Some(e) = self.status.estimate {
            extra.push(("ppb/estimated_rel_l1".to_string(), format!("{e:.6}")));
        }
        let r = self.write_image(&self.out, img, exposure, &extra);
        self.last_write = Instant::now();
        if let Err(e) = r {
            return self.error(format!("writing {}: {e:#}", self.out.display()));
        }
        if self.written_at_pass == 0 && why == "first pass" {
            self.status.log(&format!(
                "preview {} rewritten: reload {}, pass 1, {:.3} s after the change was seen \
                 (reload {:.3} s, pass {:.3} s with {} light paths)",
                self.out.display(),
                self.generation,
                self.changed_at.elapsed().as_secs_f64(),
                self.reload_seconds,
                self.pass_seconds,
                self.pass_paths,
            ));
        }
        self.written_at_pass = self.passes();
    }

    /// Writes `<out>-snapshot-N.exr/.png` with the window's exposure.
    fn snapshot(&mut self, exposure: f32) {
        let img = match self.image() {
            Some(Ok(img)) => img,
            Some(Err(e)) => return self.error(format!("snapshot: {e}")),
            None => return self.error("snapshot: no image yet".into()),
        };
        self.snapshots += 1;
        let stem = self.out.file_stem().unwrap_or_default().to_string_lossy();
        let path = self
            .out
            .with_file_name(format!("{stem}-snapshot-{}.exr", self.snapshots));
        match self.write_image(&path, &img, exposure, &[]) {
            Ok(passes) => self
                .status
                .log(&format!("snapshot {} ({passes} passes)", path.display(),)),
            Err(e) => self.error(format!("snapshot {}: {e:#}", path.display())),
        }
    }

    fn show_status(&mut self) {
        if !self.status.tty {
            return;
        }
        let secs = self.seconds();
        let pps = self.passes() as f64 / secs.max(1e-9);
        let budget = match self.budget() {
            0 => String::new(),
            b => format!("/{b}"),
        };
        let err = match &self.status.last_error {
            Some(e) => format!(" | error: {e}"),
            None => String::new(),
        };
        let estimate = match self.status.estimate {
            Some(e) => format!(" | error ~{:.2} %", e * 100.0),
            None => String::new(),
        };
        let line = format!(
            "{} | pass {}{budget}{estimate} | {pps:.2} passes/s | reload {} {:.0} s ago: {}{err}",
            self.status.scene,
            self.passes(),
            self.generation,
            self.changed_at.elapsed().as_secs_f64(),
            self.status.last_reload
        );
        let width = terminal_width();
        let line: String = line.chars().take(width.saturating_sub(1)).collect();
        self.status.show(line);
    }

    /// Hands the current image to the window.
    fn publish(&mut self, img: Image) {
        let (Some(cur), Some(wake)) = (&self.current, &self.wake) else {
            return;
        };
        if let Ok(mut f) = self.shared.lock() {
            f.width = img.width as u32;
            f.height = img.height as u32;
            f.pixels = img.pixels;
            f.passes = cur.session.passes();
            f.device = cur.session.device();
            f.seconds = self.gen_start.elapsed().as_secs_f64();
            f.exposure = cur.settings.exposure;
            f.scene = self.status.scene.clone();
            f.error = self.status.last_error.clone();
            f.serial += 1;
        }
        wake();
    }

    /// Hands the window the latest error and exposure (no new image).
    fn publish_error(&mut self) {
        let exposure = self.current.as_ref().map(|c| c.settings.exposure);
        if let Ok(mut f) = self.shared.lock() {
            f.error = self.status.last_error.clone();
            f.exposure = exposure.unwrap_or(f.exposure);
            f.serial += 1;
        }
        if let Some(w) = &self.wake {
            w();
        }
    }
}

/// "files: what changed; read assets; N octree(s) reused" for a reload's log line.
fn summary(touched: &[String], c: &Changes, loaded: &[String], reused: usize) -> String {
    let assets = if loaded.is_empty() {
        "no assets".to_string()
    } else {
        let names: Vec<String> = loaded.iter().map(|l| short(Path::new(l))).collect();
        names.join(", ")
    };
    format!(
        "{}: {}; read {assets}; {reused} octree(s) reused",
        touched.join(", "),
        c.describe()
    )
}

/// The file name alone, for short messages.
fn short(p: &Path) -> String {
    p.file_name()
        .map_or_else(|| p.display().to_string(), |n| n.to_string_lossy().into())
}

/// Columns of the terminal (COLUMNS, else 100), so the status line never wraps.
fn terminal_width() -> usize {
    std::env::var("COLUMNS")
        .ok()
        .and_then(|c| c.parse().ok())
        .unwrap_or(100)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn checkpoint_parses_passes_and_seconds() {
        assert_eq!(parse_checkpoint("8"), Ok(Checkpoint::Passes(8)));
        assert_eq!(parse_checkpoint("0.5s"), Ok(Checkpoint::Seconds(0.5)));
        assert!(parse_checkpoint("0").is_err());
        assert!(parse_checkpoint("-1s").is_err());
        assert!(parse_checkpoint("fast").is_err());
    }
}
