//! The reusable parts of `ppb watch`: which files a scene depends on ([`deps`]) and what an
//! edit changed ([`diff`]). Octree reuse across reloads is the media builder's
//! (`media::octrees`); the loop, the status line and the window live in the binary.
pub mod deps;
pub mod diff;
