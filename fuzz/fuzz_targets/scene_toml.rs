#![no_main]
//! The TOML scene file, parsed as `<scratch>/s/a/b/scene.toml`, next to the assets the
//! seed scenes name (`density.vdb`, `sphere.obj`, `../common/floor.obj`,
//! `../../common/floor.obj`, `../../conformance/smoke-grid/density.vdb`), so that a
//! mutated scene gets past its imports.
//!
//! A procedural noise medium is a generator whose cost is set by its `resolution`
//! (allowed up to 1024, i.e. 10^9 voxels, by design): scenes asking for more than 32 are
//! skipped, or every such input would be a slow unit, not a bug.
use libfuzzer_sys::fuzz_target;
use std::path::PathBuf;
use std::sync::OnceLock;

#[path = "common.rs"]
mod common;

const FLOOR: &[u8] = include_bytes!("../../scenes/common/floor.obj");
const DENSITY: &[u8] = include_bytes!("../../scenes/conformance/cloud-hg/density.vdb");

static SCENE: OnceLock<PathBuf> = OnceLock::new();

fn setup() -> PathBuf {
    let root = common::scratch_file("keep", b"").with_file_name("s");
    for (rel, bytes) in [
        ("common/floor.obj", FLOOR),
        ("a/common/floor.obj", FLOOR),
        ("a/b/sphere.obj", FLOOR),
        ("a/b/density.vdb", DENSITY),
        ("conformance/smoke-grid/density.vdb", DENSITY),
    ] {
        let p = root.join(rel);
        std::fs::create_dir_all(p.parent().expect("parent")).expect("asset folder");
        std::fs::write(&p, bytes).expect("asset");
    }
    root.join("a/b/scene.toml")
}

fn too_costly(text: &str) -> bool {
    let Ok(doc) = text.parse::<toml::Table>() else {
        return false;
    };
    let media = doc.get("medium").and_then(|m| m.as_array());
    media.into_iter().flatten().any(|m| {
        m.get("resolution")
            .and_then(|r| r.as_integer())
            .is_some_and(|r| r > 32)
            || (m.get("preset").is_some() && m.get("resolution").is_none())
    })
}

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if too_costly(text) {
        return;
    }
    let path = SCENE.get_or_init(setup);
    let r = ppb::scene::toml::parse(path, text);
    common::report("scene", &r);
});
