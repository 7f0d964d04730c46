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

/// What the file readers' byte parsers return: the value or what was wrong, to be wrapped
/// with the file's name.
pub type Parse<T> = std::result::Result<T, String>;
pub use homogeneous::{Media, MediumDesc};
pub use phase::Phase;
