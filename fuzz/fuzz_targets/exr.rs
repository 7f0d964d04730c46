#![no_main]
//! EXR images as `ppb compare` reads them (pixels, and the text attributes).
use libfuzzer_sys::fuzz_target;

#[path = "common.rs"]
mod common;

fuzz_target!(|data: &[u8]| {
    let path = common::scratch_file("fuzz.exr", data);
    common::report("exr", &ppb::output::read_exr(&path));
    let _ = ppb::output::read_exr_text(&path);
});
