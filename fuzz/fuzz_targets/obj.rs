#![no_main]
//! OBJ and its .mtl: the input is `<obj text>` then, after the first NUL byte, the text of
//! the .mtl that `mtllib fuzz.mtl` names (no NUL: no .mtl file).
use libfuzzer_sys::fuzz_target;

#[path = "common.rs"]
mod common;

fuzz_target!(|data: &[u8]| {
    let (obj, mtl) = match data.iter().position(|&b| b == 0) {
        Some(i) => (&data[..i], Some(&data[i + 1..])),
        None => (data, None),
    };
    let mtl_path = common::scratch_file("fuzz.mtl", mtl.unwrap_or(b""));
    if mtl.is_none() {
        let _ = std::fs::remove_file(&mtl_path);
    }
    let path = common::scratch_file("fuzz.obj", obj);
    let r = ppb::scene::obj::read_obj(&path, &ppb::scene::files::Files::new());
    common::report("obj", &r);
});
