//! Reading of the files a scene load needs: each file is read from disk at most once per
//! load, and the bytes that are hashed (cache keys) are the bytes that are parsed.
//!
//! [`Files`] is a cheap handle (clones share one state) handed to every importer and to
//! the USD asset resolver. Within one load ([`Files::begin`] .. [`Files::end`]) a file's
//! bytes are kept after their first read, so a second use (the cache hash and then the
//! parse, a USD layer the reader opens twice, one VDB behind two media) reads nothing
//! more. Across loads (`ppb watch`) a memo of (length, modification time, hash) per file
//! lets [`Files::hash`] answer without reading a file whose length and modification time
//! are unchanged; [`Files::read`] always returns the file's current bytes.
//!
//! Racy timestamps: a file modified shortly before it was hashed could be modified again
//! within the file system's timestamp granularity without its modification time
//! changing, so a memo entry is trusted only when the file's modification time is at
//! least [`RACY_SECONDS`] older than the moment it was hashed. Such a file is hashed
//! once more on the next reload (hashed, never parsed again if its bytes are the same).
use std::collections::HashMap;
use std::io::Read;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, SystemTime};

use crate::core::frames;
use crate::error::{Error, Result};

/// How much older than its hashing a file's modification time must be for the memo to
/// vouch for it (covers coarse file system timestamps: FAT, HFS+, network mounts).
pub const RACY_SECONDS: u64 = 2;

/// Shared reader of a scene load's files; see the module documentation.
#[derive(Clone, Default)]
pub struct Files(Arc<Mutex<State>>);

#[derive(Default)]
struct State {
    /// Across loads: what each file hashed to at a given length and modification time.
    memo: HashMap<PathBuf, Stamp>,
    /// This load: files hashed or read (bytes kept when read).
    seen: HashMap<PathBuf, Seen>,
    /// This load: files read from disk, in order.
    read: Vec<PathBuf>,
    /// The frame this load renders: the frame token in USD asset paths becomes it.
    frame: Option<u32>,
}

#[derive(Clone)]
struct Stamp {
    len: u64,
    mtime: SystemTime,
    /// When the file was stat'ed before the read that produced `state`.
    at: SystemTime,
    state: blake3::Hasher,
}

struct Seen {
    bytes: Option<Arc<Vec<u8>>>,
    /// blake3 state after the file's bytes: finalize it for the file's hash, or continue
    /// it with more input for a key over the bytes and parameters.
    state: blake3::Hasher,
}

impl Stamp {
    fn vouches_for(&self, meta: &std::fs::Metadata) -> bool {
        let Ok(mtime) = meta.modified() else {
            return false;
        };
        let settled = self
            .at
            .duration_since(self.mtime)
            .is_ok_and(|d| d >= Duration::from_secs(RACY_SECONDS));
        settled && meta.len() == self.len && mtime == self.mtime
    }
}

/// The key of a file: its canonical path, so two spellings of one file share one read.
fn key(path: &Path) -> PathBuf {
    std::fs::canonicalize(path).unwrap_or_else(|_| path.to_path_buf())
}

impl Files {
    pub fn new() -> Self {
        Self::default()
    }

    /// Sets the frame of the loads that follow (None: paths as written).
    pub fn set_frame(&self, frame: Option<u32>) {
        self.state().frame = frame;
    }

    pub fn frame(&self) -> Option<u32> {
        self.state().frame
    }

    /// `path` with the frame token replaced by the load's frame, if it has one.
    pub fn at_frame(&self, path: &str) -> String {
        match self.frame() {
            Some(f) if frames::has_token(path) => frames::with_frame(path, f),
            _ => path.to_string(),
        }
    }

    fn state(&self) -> MutexGuard<'_, State> {
        // No code runs under the lock that can panic halfway through an update.
        self.0.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Starts a load: forgets the previous load's bytes and reads (the memo stays).
    pub fn begin(&self) {
        let mut s = self.state();
        s.seen.clear();
        s.read.clear();
    }

    /// Ends a load: drops the bytes it kept. After a successful load the memo keeps only
    /// the files this load used; a failed one keeps it all.
    pub fn end(&self, success: bool) {
        let mut s = self.state();
        if success {
            let State { memo, seen, .. } = &mut *s;
            memo.retain(|k, _| seen.contains_key(k));
        }
        for seen in s.seen.values_mut() {
            seen.bytes = None;
        }
    }

    /// Files read from disk since [`Files::begin`], in order, by canonical path.
    pub fn files_read(&self) -> Vec<PathBuf> {
        self.state().read.clone()
    }

    /// The file's bytes: read from disk on the first use in this load, shared after.
    pub fn read(&self, path: &Path) -> Result<Arc<Vec<u8>>> {
        let k = key(path);
        if let Some(b) = self.state().seen.get(&k).and_then(|s| s.bytes.clone()) {
            return Ok(b);
        }
        let at = SystemTime::now();
        let mut f = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
        let meta = f.metadata().map_err(|e| Error::io(path, e))?;
        let mut bytes = Vec::with_capacity(meta.len().min(1 << 30) as usize);
        f.read_to_end(&mut bytes).map_err(|e| Error::io(path, e))?;
        let mut state = blake3::Hasher::new();
        state.update(&bytes);
        let bytes = Arc::new(bytes);
        let mut s = self.state();
        match meta.modified() {
            Ok(mtime) if meta.len() == bytes.len() as u64 => {
                let stamp = Stamp {
                    len: meta.len(),
                    mtime,
                    at,
                    state: state.clone(),
                };
                s.memo.insert(k.clone(), stamp);
            }
            _ => {
                s.memo.remove(&k);
            }
        }
        s.read.push(k.clone());
        let seen = Seen {
            bytes: Some(bytes.clone()),
            state,
        };
        s.seen.insert(k, seen);
        Ok(bytes)
    }

    /// The file's bytes as text (the error of `std::fs::read_to_string` when not UTF-8).
    pub fn read_string(&self, path: &Path) -> Result<String> {
        let bytes = self.read(path)?;
        String::from_utf8(bytes.to_vec()).map_err(|_| {
            let e = std::io::Error::new(
                std::io::ErrorKind::InvalidData,
                "stream did not contain valid UTF-8",
            );
            Error::io(path, e)
        })
    }

    /// The blake3 state after the file's bytes (for keys over bytes and parameters):
    /// from this load, else from the memo when the file's length and modification time
    /// are as they were, else read from disk (and kept for a parse).
    pub fn hasher(&self, path: &Path) -> Result<blake3::Hasher> {
        let k = key(path);
        {
            let mut s = self.state();
            if let Some(seen) = s.seen.get(&k) {
                return Ok(seen.state.clone());
            }
            let meta = std::fs::metadata(path).map_err(|e| Error::io(path, e))?;
            if let Some(stamp) = s.memo.get(&k).filter(|m| m.vouches_for(&meta)) {
                let state = stamp.state.clone();
                let seen = Seen {
                    bytes: None,
                    state: state.clone(),
                };
                s.seen.insert(k, seen);
                return Ok(state);
            }
        }
        self.read(path)?;
        let s = self.state();
        Ok(s.seen[&k].state.clone())
    }

    /// blake3 of the file's bytes; see [`Files::hasher`].
    pub fn hash(&self, path: &Path) -> Result<[u8; 32]> {
        Ok(*self.hasher(path)?.finalize().as_bytes())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("ppb-files-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    /// Backdates a file's modification time past the racy window.
    fn settle(p: &Path) {
        let old = SystemTime::now() - Duration::from_secs(60);
        let f = std::fs::File::options().write(true).open(p).unwrap();
        f.set_modified(old).unwrap();
    }

    #[test]
    fn reads_once_per_load_and_hashes_the_bytes_read() {
        let dir = scratch("once");
        let p = dir.join("a.bin");
        std::fs::write(&p, b"abc").unwrap();
        let files = Files::new();
        files.begin();
        let h = files.hash(&p).unwrap();
        let b = files.read(&dir.join(".").join("a.bin")).unwrap();
        assert_eq!(&b[..], b"abc");
        assert_eq!(h, *blake3::hash(b"abc").as_bytes());
        assert_eq!(files.files_read(), vec![key(&p)]);
        files.end(true);
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn memo_skips_unchanged_settled_files_only() {
        let dir = scratch("memo");
        let p = dir.join("a.bin");
        std::fs::write(&p, b"abc").unwrap();
        let files = Files::new();
        // Fresh file: hashed, but too recent for the memo to vouch for it next time.
        files.begin();
        files.hash(&p).unwrap();
        files.end(true);
        files.begin();
        files.hash(&p).unwrap();
        assert_eq!(files.files_read().len(), 1, "recent file is hashed again");
        files.end(true);
        // Settled: the memo answers without a read.
        settle(&p);
        files.begin();
        files.hash(&p).unwrap();
        files.end(true);
        files.begin();
        assert_eq!(files.hash(&p).unwrap(), *blake3::hash(b"abc").as_bytes());
        assert!(files.files_read().is_empty());
        // A read still reads (the parse needs the bytes), once.
        files.read(&p).unwrap();
        files.read(&p).unwrap();
        assert_eq!(files.files_read().len(), 1);
        files.end(true);
        // Same length, new content, settled again: the changed time forces a read.
        std::fs::write(&p, b"xyz").unwrap();
        settle(&p);
        files.begin();
        assert_eq!(files.hash(&p).unwrap(), *blake3::hash(b"xyz").as_bytes());
        assert_eq!(files.files_read(), vec![key(&p)]);
        files.end(true);
        std::fs::remove_dir_all(&dir).ok();
    }
}
