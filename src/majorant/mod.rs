//! Majorants for free-path sampling: one octree of local majorants per density-grid
//! medium ([`octree`]), baked once and cached on disk ([`cache`]).
pub mod cache;
mod field;
pub mod octree;

pub use field::Field;
pub use octree::{LeafBounds, Node, Octree, DEFAULT_MAX_DEPTH};

/// Which free-path sampler light paths and camera transmittance use.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Mode {
    /// Delta tracking per octree leaf (the paper's method; the default).
    Adaptive,
    /// Delta tracking with one global majorant (the paper's baseline).
    Woodcock,
}
