//! Files written whole or not at all: a temp file beside the target, renamed into place,
//! so a reader (or a later run after a kill) never sees a partial output, cache or part.
use std::path::{Path, PathBuf};

use crate::error::{Error, Result};

fn temp_path(path: &Path) -> PathBuf {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy())
        .unwrap_or_default();
    path.with_file_name(format!(".{name}.{}.tmp", std::process::id()))
}

/// How old a temp file of [`write_atomic`] must be before [`sweep_temps`] removes it: no
/// write takes this long, so its writer was killed (or its machine died).
pub const STALE_TEMP: std::time::Duration = std::time::Duration::from_secs(3600);

/// Removes the temp files killed writers left in `dir` (older than `age`); another
/// process's write in flight is younger and is left alone. Best effort.
pub fn sweep_temps(dir: &Path, age: std::time::Duration) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    let now = std::time::SystemTime::now();
    for e in entries.flatten() {
        let name = e.file_name();
        let name = name.to_string_lossy();
        if !(name.starts_with('.') && name.ends_with(".tmp")) {
            continue;
        }
        let old = e
            .metadata()
            .and_then(|m| m.modified())
            .is_ok_and(|t| now.duration_since(t).is_ok_and(|d| d >= age));
        if old {
            let _ = std::fs::remove_file(e.path());
        }
    }
}

/// Writes via `write` into a temp file beside `path`, then renames it over `path`.
pub fn write_atomic(path: &Path, write: impl FnOnce(&Path) -> Result<()>) -> Result<()> {
    let tmp = temp_path(path);
    if let Err(e) = write(&tmp) {
        let _ = std::fs::remove_file(&tmp);
        return Err(e);
    }
    std::fs::rename(&tmp, path).map_err(|e| {
        let _ = std::fs::remove_file(&tmp);
        Error::io(path, e)
    })
}
