//! The ground floor: types and rules every layer uses and none owns ([`Ray`] and its one
//! box test, [`Rgb`], atomic file writes, the frame token). Imports nothing of the crate
//! but [`crate::error`].
pub mod frames;
pub mod fs;
pub mod ray;

pub use ray::{ray_box, slab, Ray};

/// Linear RGB: radiance (W/(m^2 sr)), albedo or throughput per channel.
pub type Rgb = glam::Vec3;
