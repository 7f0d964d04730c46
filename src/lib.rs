//! ppb: progressive photon beams with adaptive free-path sampling.
//!
//! Data flow: [`scene`] import -> [`media`] (each grid owning its [`majorant`] octree) ->
//! [`transport`] (light tracing into beams and photons, camera paths and their
//! transmittance, direct light) -> [`estimate`] (beams and photons into radiance, on the
//! CPU or through [`gpu`] on the GPU, one trait) -> [`film`] (progressive sums) ->
//! [`output`] (EXR/PNG). [`plan`] says what pass i is, [`pass`] traces it, and
//! [`session`] is the one loop that accumulates passes, which every command drives.
//!
//! Layers, lowest first; a module imports only the ones before it (`tests/layering.rs`
//! reads every `crate::` path and fails on one that points up): `error`, `core`,
//! `sampling`, `film`, `output`, `compare`, `majorant`, `media`, `settings`, `scene`,
//! `geometry`, `bsdf`, `transport`, `estimate`, `plan`, `gpu`, `pass`, `session`, `farm`,
//! `watch`. The binary (src/app) sits on top of them all.
pub mod bsdf;
pub mod compare;
pub mod core;
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
