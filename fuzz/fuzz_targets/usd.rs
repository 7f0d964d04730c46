#![no_main]
//! USD: `.usda` when the input starts with `#usda`, `.usdz` when it is a zip, else `.usdc`.
//! The stage is written to `<scratch>/u/s/`, with the plume VDB the seed stages name at
//! `../smoke_plume.vdb`. read_usd catches the openusd crate's panics itself, so the default panic hook is put
//! back (libfuzzer-sys's hook would abort on a panic that is caught and reported).
use libfuzzer_sys::fuzz_target;

#[path = "common.rs"]
mod common;

const PLUME: &[u8] = include_bytes!("../../tests/data/usd/smoke_plume.vdb");

fuzz_target!(init: {
    let _ = std::panic::take_hook();
    let dir = common::scratch_file("keep", b"").with_file_name("u");
    std::fs::create_dir_all(dir.join("s")).expect("stage folder");
    std::fs::write(dir.join("smoke_plume.vdb"), PLUME).expect("plume");
}, |data: &[u8]| {
    let name = if data.starts_with(b"#usda") {
        "fuzz.usda"
    } else if data.starts_with(b"PK") {
        "fuzz.usdz"
    } else {
        "fuzz.usdc"
    };
    let path = common::scratch_file("keep", b"").with_file_name("u").join("s").join(name);
    std::fs::write(&path, data).expect("stage");
    let r = ppb::scene::usd::read_usd(&path, &ppb::scene::files::Files::new());
    common::report(name, &r);
});
