#![no_main]
//! glTF: the input is a .glb when it starts with the binary magic, else a .gltf (whose
//! external buffer, if any, is `fuzz.bin`: the test scene's buffer, written once into the
//! scratch folder).
use libfuzzer_sys::fuzz_target;

#[path = "common.rs"]
mod common;

const BIN: &[u8] = include_bytes!("../../tests/data/scene/glass_scene.bin");

fuzz_target!(init: {
    common::scratch_file("fuzz.bin", BIN);
}, |data: &[u8]| {
    let name = if data.starts_with(b"glTF") { "fuzz.glb" } else { "fuzz.gltf" };
    let path = common::scratch_file(name, data);
    let r = ppb::scene::gltf::read_gltf(&path, &ppb::scene::files::Files::new());
    common::report(name, &r);
});
