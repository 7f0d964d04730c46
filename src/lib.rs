//! ppb: progressive photon beams with adaptive free-path sampling.
//!
//! Data flow, one module per stage: [`scene`] import -> [`media`] -> [`transport`] (light
//! tracing into beams and photons; camera paths) -> [`estimate`] (beam and photon radiance
//! estimates, radius schedule) -> [`film`] (progressive average) -> [`output`] (EXR/PNG).
pub mod error;
pub mod media;
pub mod scene;
