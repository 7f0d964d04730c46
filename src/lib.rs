//! ppb: progressive photon beams with adaptive free-path sampling.
//!
//! Data flow, one module per stage: [`scene`] import -> [`media`] -> [`transport`] (light
//! tracing into beams and photons, camera paths) -> [`estimate`] (beam and photon radiance
//! estimates, radius schedule) -> [`film`] (progressive average) -> [`output`] (EXR/PNG).
//! [`render`] runs one pass of that chain.
pub mod bsdf;
pub mod compare;
pub mod error;
pub mod estimate;
pub mod film;
pub mod geometry;
pub mod gpu;
pub mod majorant;
pub mod media;
pub mod output;
pub mod progressive;
pub mod render;
pub mod sampling;
pub mod scene;
pub mod settings;
pub mod transport;
pub mod watch;
