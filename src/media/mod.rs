//! Participating media: what the scene file describes ([`MediumDesc`]) and the combined
//! extinction field the transport code samples ([`Media`]).
pub mod blosc;
pub mod grid;
pub mod heterogeneous;
pub mod homogeneous;
pub mod nanovdb;
pub mod openvdb;
pub mod phase;
pub mod procedural;

pub use heterogeneous::{GridMedium, Heterogeneous};
pub use homogeneous::{Media, MediumDesc};
pub use phase::Phase;
