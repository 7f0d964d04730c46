//! What `ppb watch`'s render worker and its window share: the messages the worker hears
//! and the latest frame the window shows.
use std::path::PathBuf;
use std::sync::{Arc, Mutex};

/// What the worker hears: file changes, window requests.
pub enum Msg {
    /// Paths that changed in a watched folder (not yet filtered).
    Files(Vec<PathBuf>),
    /// The watcher itself failed (e.g. a watched folder vanished).
    WatchError(String),
    /// Write a snapshot of the current image with this exposure.
    Snapshot { exposure: f32 },
}

/// The latest image and what the window title shows.
#[derive(Clone, Default)]
pub struct Frame {
    pub width: u32,
    pub height: u32,
    pub pixels: Vec<[f32; 3]>,
    pub passes: u32,
    pub seconds: f64,
    pub exposure: f32,
    pub scene: String,
    /// Where the beam estimate runs ("cpu" or the adapter).
    pub device: String,
    pub error: Option<String>,
    /// Bumped on every new image, so the window uploads only when it changed.
    pub serial: u64,
}

pub type SharedFrame = Arc<Mutex<Frame>>;
