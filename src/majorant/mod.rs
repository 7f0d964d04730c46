//! Majorants for free-path sampling: one octree of local majorants per density-grid
//! medium ([`octree`]), baked once and cached on disk ([`cache`]), and where its light can
//! reach a beam's kernel ([`occupancy`]).
pub mod cache;
mod field;
pub mod occupancy;
pub mod octree;

pub use field::Field;
pub use occupancy::Occupancy;
pub use octree::{LeafBounds, Node, Octree, DEFAULT_MAX_DEPTH};

/// Which free-path sampler light paths and camera transmittance use.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Mode {
    /// Delta tracking per octree leaf (the paper's method; the default).
    Adaptive,
    /// Delta tracking with one global majorant (the paper's baseline).
    Woodcock,
}
