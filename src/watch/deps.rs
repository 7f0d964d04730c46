//! The files a loaded scene depends on and the folders to watch for them. Editors save by
//! writing a temp file and renaming it over the original, which replaces the inode a file
//! watch would hold, so the folders are watched and events filtered by file name.
use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use crate::scene::toml::SceneFile;

/// Every file the scene read: the scene file, imports and their sidecars (.bin, .mtl,
/// USD layers, VDB assets), grid files; absolute where they can be, without duplicates.
pub fn files(file: &SceneFile) -> Vec<PathBuf> {
    let mut seen = BTreeSet::new();
    let mut out = Vec::new();
    let mut all = vec![file.path.clone()];
    if crate::scene::Format::detect(&file.path) == Some(crate::scene::Format::Usd) {
        all.push(usd_sidecar(&file.path));
    }
    all.extend(file.sources.iter().cloned());
    for p in all {
        let p = absolute(&p);
        if seen.insert(p.clone()) {
            out.push(p);
        }
    }
    out
}

/// The `shot.ppb.toml` beside `shot.usda`: watched even before it exists.
fn usd_sidecar(stage: &Path) -> PathBuf {
    let stem = stage.file_stem().unwrap_or_default().to_string_lossy();
    stage.with_file_name(format!("{stem}.ppb.toml"))
}

/// `p` made absolute and lexically normalised (`a/../b` -> `b`), so watcher event paths,
/// which are absolute, compare equal to it.
pub fn absolute(p: &Path) -> PathBuf {
    let joined = if p.is_absolute() {
        p.to_path_buf()
    } else {
        std::env::current_dir().unwrap_or_default().join(p)
    };
    let mut out = PathBuf::new();
    for c in joined.components() {
        match c {
            std::path::Component::ParentDir => {
                out.pop();
            }
            std::path::Component::CurDir => {}
            other => out.push(other.as_os_str()),
        }
    }
    out
}

/// The distinct folders holding `files`.
pub fn folders(files: &[PathBuf]) -> Vec<PathBuf> {
    let set: BTreeSet<PathBuf> = files
        .iter()
        .filter_map(|f| f.parent().map(Path::to_path_buf))
        .collect();
    set.into_iter().collect()
}

/// The watched files among `paths` (event paths): what a change touched.
pub fn touched(watched: &[PathBuf], paths: &[PathBuf]) -> Vec<PathBuf> {
    let mut out: Vec<PathBuf> = Vec::new();
    for p in paths {
        let p = absolute(p);
        if watched.contains(&p) && !out.contains(&p) {
            out.push(p);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lists_sidecars_of_imports() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/scene");
        let text = "[camera]\norigin = [0, 1, 5]\ntarget = [0, 0, 0]\nvfov = 40\n\
                    [[import]]\npath = \"glass_scene.gltf\"\n[[mesh]]\npath = \"glass_scene.obj\"\n\
                    [[light]]\ntype = \"point\"\nposition = [0, 2, 0]\nintensity = [1, 1, 1]\n";
        let file = crate::scene::toml::parse(&dir.join("watched.toml"), text).unwrap();
        let names: Vec<String> = files(&file)
            .iter()
            .map(|p| p.file_name().unwrap().to_string_lossy().into_owned())
            .collect();
        assert_eq!(
            names,
            [
                "watched.toml",
                "glass_scene.gltf",
                "glass_scene.bin",
                "glass_scene.obj",
                "glass_scene.mtl"
            ]
        );
        assert_eq!(folders(&files(&file)), vec![absolute(&dir)]);
    }

    #[test]
    fn normalises_and_filters() {
        let a = absolute(Path::new("/s/conf/fog/../../common/floor.obj"));
        assert_eq!(a, PathBuf::from("/s/common/floor.obj"));
        let watched = vec![a.clone(), PathBuf::from("/s/conf/fog/scene.toml")];
        assert_eq!(
            folders(&watched),
            vec![PathBuf::from("/s/common"), PathBuf::from("/s/conf/fog")]
        );
        let ev = vec![
            PathBuf::from("/s/conf/fog/.scene.toml.swp"),
            PathBuf::from("/s/conf/fog/scene.toml"),
            PathBuf::from("/s/conf/fog/./scene.toml"),
        ];
        assert_eq!(
            touched(&watched, &ev),
            vec![PathBuf::from("/s/conf/fog/scene.toml")]
        );
    }
}
