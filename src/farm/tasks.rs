//! The split of a render into tasks: frame-major, each frame's passes cut into ranges of
//! `passes_per_task`. Task k's frame and pass range are a pure function of the frame
//! list, the pass count and the task size, so any engine can run task k anywhere by
//! index alone (`SLURM_ARRAY_TASK_ID`, `JOB_COMPLETION_INDEX`, an OpenJD parameter).
use std::fmt;

use crate::error::{Error, Result};

/// A half-open range of passes counted from 0: `256..512` is the 257th to the 512th
/// pass (global pass indices 257..=512), so `0..256` and `256..512` tile.
#[derive(
    Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, serde::Serialize, serde::Deserialize,
)]
pub struct PassRange {
    pub start: u32,
    pub end: u32,
}

impl PassRange {
    /// Parses `A..B` with A < B.
    pub fn parse(s: &str) -> Result<Self> {
        let bad = || {
            Error::Other(format!(
                "--pass-range {s:?}: expected START..END with START < END, passes counted from 0 (e.g. 256..512)"
            ))
        };
        let (a, b) = s.split_once("..").ok_or_else(bad)?;
        let (start, end) = (
            a.trim().parse().map_err(|_| bad())?,
            b.trim().parse().map_err(|_| bad())?,
        );
        if start >= end {
            return Err(bad());
        }
        Ok(PassRange { start, end })
    }

    pub fn len(&self) -> u32 {
        self.end - self.start
    }

    pub fn is_empty(&self) -> bool {
        self.start >= self.end
    }

    /// The global (1-based) indices of its passes.
    pub fn indices(&self) -> std::ops::RangeInclusive<u32> {
        self.start + 1..=self.end
    }
}

impl fmt::Display for PassRange {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}..{}", self.start, self.end)
    }
}

/// The tasks of a render: every frame (None for a still) times the pass ranges.
#[derive(Clone, Debug, PartialEq)]
pub struct Tasks {
    pub frames: Vec<Option<u32>>,
    pub passes: u32,
    pub passes_per_task: u32,
}

/// One task: a frame's pass range.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct Task {
    pub index: u32,
    pub frame: Option<u32>,
    pub passes: PassRange,
}

impl Tasks {
    /// Tasks over `frames` (empty: a still) of `passes` passes each, `per_task` per task.
    pub fn new(frames: &[u32], passes: u32, per_task: u32) -> Result<Self> {
        if passes == 0 || per_task == 0 {
            return Err(Error::Other(format!(
                "passes ({passes}) and passes per task ({per_task}) must be positive"
            )));
        }
        let frames: Vec<Option<u32>> = if frames.is_empty() {
            vec![None]
        } else {
            frames.iter().map(|&f| Some(f)).collect()
        };
        let t = Tasks {
            frames,
            passes,
            passes_per_task: per_task,
        };
        if u32::try_from(t.frames.len() as u64 * t.per_frame() as u64).is_err() {
            return Err(Error::Other("more than 2^32 tasks".into()));
        }
        Ok(t)
    }

    /// Tasks per frame.
    pub fn per_frame(&self) -> u32 {
        self.passes.div_ceil(self.passes_per_task)
    }

    pub fn count(&self) -> u32 {
        self.frames.len() as u32 * self.per_frame()
    }

    /// Task `k`, or an error naming the valid indices.
    pub fn task(&self, k: u32) -> Result<Task> {
        if k >= self.count() {
            return Err(Error::Other(format!(
                "task index {k} is out of range: this render has tasks 0..={}",
                self.count() - 1
            )));
        }
        let (f, i) = (k / self.per_frame(), k % self.per_frame());
        let start = i * self.passes_per_task;
        Ok(Task {
            index: k,
            frame: self.frames[f as usize],
            passes: PassRange {
                start,
                end: (start + self.passes_per_task).min(self.passes),
            },
        })
    }

    pub fn all(&self) -> impl Iterator<Item = Task> + '_ {
        (0..self.count()).filter_map(|k| self.task(k).ok())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every frame's passes are covered once, in order, by consecutive task indices.
    #[test]
    fn tasks_tile_every_frame() {
        let t = Tasks::new(&[10, 11], 10, 4).unwrap();
        assert_eq!(t.count(), 6);
        let got: Vec<(Option<u32>, u32, u32)> = t
            .all()
            .map(|k| (k.frame, k.passes.start, k.passes.end))
            .collect();
        assert_eq!(
            got,
            [
                (Some(10), 0, 4),
                (Some(10), 4, 8),
                (Some(10), 8, 10),
                (Some(11), 0, 4),
                (Some(11), 4, 8),
                (Some(11), 8, 10)
            ]
        );
        assert!(t.task(6).is_err());
        let still = Tasks::new(&[], 8, 8).unwrap();
        assert_eq!(still.task(0).unwrap().frame, None);
        assert_eq!(still.task(0).unwrap().passes.indices(), 1..=8);
        assert!(Tasks::new(&[], 0, 1).is_err());
        assert_eq!(PassRange::parse("256..512").unwrap().len(), 256);
        for bad in ["5..5", "6..5", "1-2", "..3", "a..b"] {
            assert!(PassRange::parse(bad).is_err(), "{bad}");
        }
    }
}
