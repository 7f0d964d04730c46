//! The reusable parts of `ppb watch`: which files a scene depends on ([`deps`]), what an
//! edit changed ([`diff`]) and octree reuse across reloads ([`octrees`]). The loop, the
//! status line and the window live in the binary.
pub mod deps;
pub mod diff;
pub mod octrees;
