//! Progress of `ppb render` for a terminal (a bar) or a farm manager (lines it parses on
//! stdout), and SIGINT/SIGTERM, which end a render after the pass in flight.
use anyhow::{Context, Result};
use indicatif::{ProgressBar, ProgressStyle};
use std::io::Write;
use std::sync::atomic::{AtomicBool, AtomicI64, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum ProgressKind {
    Bar,
    Alf,
    Openjd,
    Json,
    None,
}

/// What a command's progress counts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Goal {
    /// Passes, in all.
    Passes(u64),
    /// Frames, each ending at a time budget or an error target: the caller says how far
    /// into its frame a pass is.
    Frames(u32),
}

/// Steps a frame counts under [`Goal::Frames`].
const FRAME_STEPS: u64 = 1000;

/// Progress over all the passes of a command (every frame of it).
pub struct Progress {
    kind: ProgressKind,
    bar: ProgressBar,
    /// Passes in all, or frames x [`FRAME_STEPS`].
    total: u64,
    done: AtomicU64,
    goal: Goal,
    start: Instant,
    /// Last whole percent printed (ALF lines only on change).
    last_percent: AtomicI64,
}

/// What a pass reports besides its index.
#[derive(Clone, Copy, Debug, Default)]
pub struct PassNote {
    /// How far into its frame the render is, under [`Goal::Frames`].
    pub in_frame: f64,
    /// The estimated error and its target, when the render has one.
    pub error: Option<(f64, f64)>,
}

impl Progress {
    pub fn new(kind: ProgressKind, goal: Goal) -> Self {
        let total = match goal {
            Goal::Frames(frames) => FRAME_STEPS * u64::from(frames.max(1)),
            Goal::Passes(p) => p.max(1),
        };
        let bar = match kind {
            ProgressKind::Bar => bar(total, goal),
            _ => ProgressBar::hidden(),
        };
        Progress {
            kind,
            bar,
            total,
            done: AtomicU64::new(0),
            goal,
            start: Instant::now(),
            last_percent: AtomicI64::new(-1),
        }
    }

    /// Counts passes done earlier (a resumed or skipped task).
    pub fn skip(&self, passes: u64) {
        if let Goal::Passes(_) = self.goal {
            self.done.fetch_add(passes, Ordering::Relaxed);
            self.bar.inc(passes);
        }
    }

    /// After pass `index` of `frame`.
    pub fn pass(&self, frame: Option<u32>, index: u32, note: PassNote) {
        let done = match self.goal {
            Goal::Frames(_) => {
                let frames_before = self.done.load(Ordering::Relaxed);
                frames_before + (note.in_frame.clamp(0.0, 1.0) * FRAME_STEPS as f64) as u64
            }
            Goal::Passes(_) => self.done.fetch_add(1, Ordering::Relaxed) + 1,
        };
        let fraction = (done as f64 / self.total as f64).min(1.0);
        let elapsed = self.start.elapsed().as_secs_f64();
        let eta = (fraction > 0.0).then(|| elapsed * (1.0 - fraction) / fraction);
        let mut out = std::io::stdout().lock();
        // A closed stdout must not fail the render: progress lines are best effort.
        let _ = match self.kind {
            ProgressKind::Bar => {
                self.bar.set_position(done);
                let error = note.error.map_or_else(String::new, |(e, t)| {
                    format!("  error ~{:.2} % (target {:.2} %)", e * 100.0, t * 100.0)
                });
                self.bar.set_message(match frame {
                    Some(f) => format!("frame {f} pass {index}{error}"),
                    None => format!("pass {index}{error}"),
                });
                Ok(())
            }
            ProgressKind::Alf => {
                let pct = (fraction * 100.0) as i64;
                if self.last_percent.swap(pct, Ordering::Relaxed) != pct {
                    writeln!(out, "ALF_PROGRESS {pct}%")
                } else {
                    Ok(())
                }
            }
            ProgressKind::Openjd => writeln!(out, "openjd_progress: {:.1}", fraction * 100.0),
            ProgressKind::Json => {
                let line = serde_json::json!({
                    "frame": frame,
                    "pass": index,
                    "done": done,
                    "total": self.total,
                    "fraction": fraction,
                    "elapsed_s": elapsed,
                    "eta_s": eta,
                    "estimated_rel_l1": note.error.map(|(e, _)| e),
                });
                writeln!(out, "{line}")
            }
            ProgressKind::None => Ok(()),
        }
        .and_then(|_| out.flush());
    }

    /// A frame ended: under [`Goal::Frames`] the next one starts a frame further.
    pub fn frame_done(&self) {
        if let Goal::Frames(_) = self.goal {
            self.done.fetch_add(FRAME_STEPS, Ordering::Relaxed);
        }
    }

    pub fn finish(&self) {
        self.bar.finish_and_clear();
    }
}

fn bar(len: u64, goal: Goal) -> ProgressBar {
    let template = match goal {
        Goal::Frames(_) => {
            "{spinner} [{elapsed_precise}] {bar:40} {percent:>3} %  ETA {eta}  {msg}"
        }
        Goal::Passes(_) => {
            "{spinner} [{elapsed_precise}] {bar:40} {pos}/{len} passes  {per_sec}  ETA {eta}  {msg}"
        }
    };
    let bar = ProgressBar::new(len);
    if let Ok(style) = ProgressStyle::with_template(template) {
        bar.set_style(style);
    }
    bar.enable_steady_tick(Duration::from_millis(250));
    bar
}

/// SIGINT and SIGTERM, noted instead of ending the process: the render stops after the
/// pass in flight and keeps its passes (a second SIGINT ends it at once).
pub struct Interrupt {
    int: Arc<AtomicBool>,
    term: Arc<AtomicBool>,
}

impl Interrupt {
    pub fn install() -> Result<Self> {
        use signal_hook::consts::{SIGINT, SIGTERM};
        use signal_hook::flag;
        let (int, term) = (
            Arc::new(AtomicBool::new(false)),
            Arc::new(AtomicBool::new(false)),
        );
        // Registered first, so it sees the flag as it was before this signal.
        flag::register_conditional_shutdown(SIGINT, 130, int.clone())
            .context("installing the SIGINT handler")?;
        flag::register(SIGINT, int.clone()).context("installing the SIGINT handler")?;
        flag::register(SIGTERM, term.clone()).context("installing the SIGTERM handler")?;
        Ok(Interrupt { int, term })
    }

    /// The exit code of the signal received, if any: 130 (SIGINT) or 143 (SIGTERM).
    pub fn signalled(&self) -> Option<u8> {
        if self.term.load(Ordering::Relaxed) {
            Some(143)
        } else if self.int.load(Ordering::Relaxed) {
            Some(130)
        } else {
            None
        }
    }
}
