//! Majorants for free-path sampling: one octree of local majorants per density-grid
//! medium ([`octree`]), baked once and cached on disk ([`cache`]).
pub mod cache;
pub mod octree;

pub use octree::{LeafBounds, Node, Octree};
