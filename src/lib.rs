//! ppb: progressive photon beams with adaptive free-path sampling.
//!
//! Data flow, one module per stage: [`scene`] import -> [`media`] (each grid owning its
//! [`majorant`] octree) -> [`transport`] (light tracing into beams and photons, camera
//! paths and transmittance) -> [`estimate`] (beam and photon radiance estimates on the CPU
//! or, through [`gpu`], on the GPU) -> [`film`] (progressive average) -> [`output`]
//! (EXR/PNG). [`pass`] traces one pass of that chain as [`plan`] defines it; [`session`]
//! is the one loop that accumulates passes, which every command drives.
pub mod bsdf;
pub mod compare;
pub mod error;
pub mod estimate;
pub mod farm;
pub mod film;
pub mod geometry;
pub mod gpu;
pub mod majorant;
pub mod media;
pub mod output;
pub mod pass;
pub mod plan;
pub mod sampling;
pub mod scene;
pub mod session;
pub mod settings;
pub mod transport;
pub mod watch;
