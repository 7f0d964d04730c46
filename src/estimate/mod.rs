//! Radiance estimates from one pass's light records: beams along camera segments (eq. 2)
//! and photons at diffuse camera hits (progressive photon mapping), with the radius
//! schedule of eq. 3.
pub mod beams;
pub mod cpu;
pub mod eq2;
pub mod photons;
pub mod radius;
pub mod splat;
