//! Homogeneous media: axis-aligned boxes of constant coefficients, index-matched. How
//! overlapping boxes and grids combine is [`super::Media`]'s business.
use glam::Vec3;

use super::Phase;
use crate::core::Rgb;

#[derive(Clone, Debug, PartialEq)]
pub struct MediumDesc {
    /// Axis-aligned box [min, max] the medium fills (m).
    pub bounds: [Vec3; 2],
    /// Extinction coefficient (1/m), grey.
    pub sigma_t: f32,
    /// Single-scattering albedo sigma_s / sigma_t per channel.
    pub albedo: Rgb,
    pub phase: Phase,
}
