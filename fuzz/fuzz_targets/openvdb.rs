#![no_main]
//! OpenVDB: list the grids, then load each one by name and read it back.
use libfuzzer_sys::fuzz_target;
use std::path::Path;

#[path = "common.rs"]
mod common;

fuzz_target!(|data: &[u8]| {
    let path = Path::new("fuzz.vdb");
    let r = ppb::media::openvdb::list_grids_from(path, data);
    common::report("list", &r);
    let Ok(grids) = r else {
        let _ = ppb::media::openvdb::load_grid_from(path, data, "density");
        return;
    };
    for d in grids.iter().take(8) {
        let r = ppb::media::openvdb::load_grid_from(path, data, &d.name);
        common::report(&d.name, &r);
        if let Ok(g) = r {
            common::exercise_grid(&g);
        }
    }
});
