#![no_main]
//! Farm part files. A blake3 hash of the whole body guards them, which random bytes never
//! match, so the harness appends the right hash to the input (the body) unless the first
//! byte is 0xFF (then the input is the whole file as is).
use libfuzzer_sys::fuzz_target;

#[path = "common.rs"]
mod common;

fuzz_target!(|data: &[u8]| {
    let file = if data.first() == Some(&0xFF) {
        data[1..].to_vec()
    } else {
        let mut f = data.to_vec();
        f.extend_from_slice(blake3::hash(data).as_bytes());
        f
    };
    let path = common::scratch_file("fuzz.part", &file);
    common::report("part", &ppb::farm::Part::read(&path));
});
