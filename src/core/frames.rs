//! Frame lists (`1-240,300`) and the frame token: a run of `#` in a path is the frame
//! number zero-padded to the run's length (`shot.####.exr` -> `shot.0012.exr`), as in
//! Houdini's and Nuke's sequence names.
use std::fmt;
use std::path::{Path, PathBuf};

use crate::error::{Error, Result};

/// Frames in ascending order, each once.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FrameList(Vec<u32>);

/// Largest frame list accepted (a bound on what `--frames` can allocate).
pub const MAX_FRAMES: usize = 1_000_000;

impl FrameList {
    /// Parses `1-240,300` (ranges inclusive, comma-separated).
    pub fn parse(s: &str) -> Result<Self> {
        let bad = |msg: String| Error::Other(format!("--frames {s:?}: {msg}"));
        let mut frames = Vec::new();
        for item in s.split(',').map(str::trim) {
            let num = |t: &str| {
                t.trim().parse::<u32>().map_err(|_| {
                    bad(format!(
                        "expected a frame number or a range like 1-240, got {item:?}"
                    ))
                })
            };
            let (a, b) = match item.split_once('-') {
                Some((a, b)) => (num(a)?, num(b)?),
                None => (num(item)?, num(item)?),
            };
            if a > b {
                return Err(bad(format!("range {item} ends before it starts")));
            }
            if frames.len() + (b - a) as usize >= MAX_FRAMES {
                return Err(bad(format!("more than {MAX_FRAMES} frames")));
            }
            frames.extend(a..=b);
        }
        frames.sort_unstable();
        frames.dedup();
        Ok(FrameList(frames))
    }

    pub fn frames(&self) -> &[u32] {
        &self.0
    }
}

impl fmt::Display for FrameList {
    /// The shortest list of ranges: `1-3,7`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let mut runs: Vec<(u32, u32)> = Vec::new();
        for &x in &self.0 {
            match runs.last_mut() {
                Some((_, b)) if *b + 1 == x => *b = x,
                _ => runs.push((x, x)),
            }
        }
        let parts: Vec<String> = runs
            .iter()
            .map(|&(a, b)| {
                if a == b {
                    a.to_string()
                } else {
                    format!("{a}-{b}")
                }
            })
            .collect();
        f.write_str(&parts.join(","))
    }
}

/// Whether `s` carries a frame token.
pub fn has_token(s: &str) -> bool {
    s.contains('#')
}

/// `s` with every run of `#` replaced by `frame`, zero-padded to the run's length (a
/// longer number is written whole).
pub fn with_frame(s: &str, frame: u32) -> String {
    let mut out = String::with_capacity(s.len() + 4);
    let mut chars = s.chars().peekable();
    while let Some(c) = chars.next() {
        if c != '#' {
            out.push(c);
            continue;
        }
        let mut width = 1;
        while chars.next_if_eq(&'#').is_some() {
            width += 1;
        }
        out.push_str(&format!("{frame:0width$}"));
    }
    out
}

/// `path` with its frame token replaced by `frame`; unchanged without a frame or a token.
/// The one place a path is put at a frame (scene files, their assets, outputs).
pub fn at_frame(path: &Path, frame: Option<u32>) -> PathBuf {
    let s = path.to_string_lossy();
    match frame {
        Some(f) if has_token(&s) => PathBuf::from(with_frame(&s, f)),
        _ => path.to_path_buf(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_lists_and_tokens() {
        let f = FrameList::parse("7, 1-3,2").unwrap();
        assert_eq!(f.frames(), [1, 2, 3, 7]);
        assert_eq!(f.to_string(), "1-3,7");
        for bad in ["", "a", "3-1", "1-", "-2", "1-5000000"] {
            assert!(FrameList::parse(bad).is_err(), "{bad}");
        }
        assert_eq!(with_frame("out/shot.####.exr", 12), "out/shot.0012.exr");
        assert_eq!(with_frame("a#/b##.vdb", 123), "a123/b123.vdb");
        assert_eq!(with_frame("plain.vdb", 5), "plain.vdb");
        assert!(has_token("x.#.vdb") && !has_token("x.vdb"));
        assert_eq!(
            at_frame(Path::new("a/#.vdb"), Some(3)),
            Path::new("a/3.vdb")
        );
        assert_eq!(at_frame(Path::new("a/#.vdb"), None), Path::new("a/#.vdb"));
    }
}
