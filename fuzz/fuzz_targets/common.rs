//! Shared by the targets: a per-process scratch folder for loaders that read from disk,
//! and the read-back checks run on every grid a loader returns.
#![allow(dead_code)]
use std::path::PathBuf;

/// `<tmp>/ppb-fuzz-<pid>/<name>`, written with `data` (the folder is made once).
pub fn scratch_file(name: &str, data: &[u8]) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("ppb-fuzz-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("scratch folder");
    let p = dir.join(name);
    std::fs::write(&p, data).expect("scratch file");
    p
}

/// Everything a renderer asks of a freshly loaded grid must work on any grid a loader accepts.
pub fn exercise_grid(g: &ppb::media::grid::Grid) {
    use glam::{DVec3, IVec3};
    let _ = g.active_voxels();
    let bbox = g.active_bbox();
    let _ = g.active_stats();
    let _ = g.memory_bytes();
    let _ = g.leaf_table();
    let (lo, hi) = bbox.unwrap_or((IVec3::ZERO, IVec3::ZERO));
    for p in [lo, hi, (lo / 2 + hi / 2), IVec3::ZERO] {
        let _ = g.value(p);
        let _ = g.is_active(p);
        let _ = g.sample_index(p.as_dvec3() + DVec3::splat(0.5));
    }
}

/// With FUZZ_VERBOSE set, prints what a load returned (to check that seeds load).
pub fn report<T, E: std::fmt::Display>(what: &str, r: &Result<T, E>) {
    if std::env::var_os("FUZZ_VERBOSE").is_some() {
        match r {
            Ok(_) => eprintln!("{what}: ok"),
            Err(e) => eprintln!("{what}: error: {e}"),
        }
    }
}
