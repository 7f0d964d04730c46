//! Reuse of loaded assets across reloads of a scene file: `ppb watch` re-reads the scene on
//! every save, and a light or camera edit must not re-parse a VDB or a glTF.
//!
//! Entries are keyed by what was asked (path, grid name, procedural parameters) and checked
//! against a blake3 of the bytes of every file the asset was built from, so an edited,
//! truncated or replaced file is always loaded again; only the hashing reads it.
use std::collections::{HashMap, HashSet};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use super::Imported;
use crate::error::{Error, Result};
use crate::media::grid::Grid;

/// blake3 of the files' bytes in order (with their paths, so a swap is a change).
pub fn hash_files(files: &[PathBuf]) -> Result<[u8; 32]> {
    let mut h = blake3::Hasher::new();
    for f in files {
        let bytes = std::fs::read(f).map_err(|e| Error::io(f, e))?;
        h.update(f.as_os_str().as_encoded_bytes());
        h.update(&(bytes.len() as u64).to_le_bytes());
        h.update(&bytes);
    }
    Ok(*h.finalize().as_bytes())
}

struct ImportEntry {
    /// Hash of the imported file, taken before it was parsed: an edit during the parse
    /// then shows as a change on the next load instead of being cached as seen.
    main: [u8; 32],
    /// Its sidecars (.bin, .mtl, layers, VDBs) and their hash.
    sidecars: Vec<PathBuf>,
    side: [u8; 32],
    imported: Imported,
}

/// Loaded imports and grids of earlier loads, plus what the latest load had to (re)load.
#[derive(Default)]
pub struct AssetCache {
    imports: HashMap<PathBuf, ImportEntry>,
    grids: HashMap<String, ([u8; 32], Arc<Grid>)>,
    used_imports: HashSet<PathBuf>,
    used_grids: HashSet<String>,
    loaded: Vec<String>,
}

impl AssetCache {
    pub fn new() -> Self {
        Self::default()
    }

    /// Starts a scene load: forgets what the previous load reported.
    pub fn begin(&mut self) {
        self.used_imports.clear();
        self.used_grids.clear();
        self.loaded.clear();
    }

    /// After a successful load: drops assets the scene no longer uses. A failed load keeps
    /// them all, so fixing the file reuses what the last good scene had.
    pub fn prune(&mut self) {
        let (ui, ug) = (&self.used_imports, &self.used_grids);
        self.imports.retain(|k, _| ui.contains(k));
        self.grids.retain(|k, _| ug.contains(k));
    }

    /// Assets the latest load read from disk instead of reusing (one description each).
    pub fn loaded(&self) -> &[String] {
        &self.loaded
    }

    /// An import (OBJ, glTF, USD): reused when it and its sidecars hash as before.
    pub fn import(
        &mut self,
        path: &Path,
        load: impl FnOnce() -> Result<Imported>,
    ) -> Result<Imported> {
        self.used_imports.insert(path.to_path_buf());
        let main = hash_files(&[path.to_path_buf()])?;
        if let Some(e) = self.imports.get(path) {
            if e.main == main && hash_files(&e.sidecars).ok() == Some(e.side) {
                return Ok(e.imported.clone());
            }
        }
        let imported = load()?;
        let sidecars: Vec<PathBuf> = imported
            .files
            .iter()
            .filter(|f| f.is_file())
            .cloned()
            .collect();
        let side = hash_files(&sidecars)?;
        self.loaded.push(path.display().to_string());
        let entry = ImportEntry {
            main,
            sidecars,
            side,
            imported: imported.clone(),
        };
        self.imports.insert(path.to_path_buf(), entry);
        Ok(imported)
    }

    /// A grid identified by `key` (file and grid name, or procedural parameters) whose
    /// inputs hash to `hash`: reused when the hash matches, else built by `load`.
    pub fn grid(
        &mut self,
        key: &str,
        hash: [u8; 32],
        load: impl FnOnce() -> Result<Grid>,
    ) -> Result<Arc<Grid>> {
        self.used_grids.insert(key.to_string());
        if let Some((h, g)) = self.grids.get(key) {
            if *h == hash {
                return Ok(g.clone());
            }
        }
        let g = Arc::new(load()?);
        self.loaded.push(key.to_string());
        self.grids.insert(key.to_string(), (hash, g.clone()));
        Ok(g)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::toml::load_cached;

    const FLOOR: &str = "v -3 0 -3\nv 3 0 -3\nv 3 0 3\nv -3 0 3\nf 1 4 3\nf 1 3 2\n";

    fn scene(light: f32) -> String {
        format!(
            "[camera]\norigin = [0, 1.5, 5]\ntarget = [0, 0.8, 0]\nvfov = 40\n\
             [[mesh]]\npath = \"floor.obj\"\n\
             [[light]]\ntype = \"point\"\nposition = [0, 2.6, 0]\nintensity = [{light}, 1, 1]\n\
             [[medium]]\ntype = \"grid\"\npath = \"density.vdb\"\ndensity_scale = 8.0\nalbedo = [0.9, 0.9, 0.9]\n"
        )
    }

    #[test]
    fn reloads_only_changed_assets() {
        let dir = std::env::temp_dir().join(format!("ppb-assets-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let vdb =
            Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/conformance/smoke-grid/density.vdb");
        std::fs::copy(&vdb, dir.join("density.vdb")).unwrap();
        std::fs::write(dir.join("floor.obj"), FLOOR).unwrap();
        let path = dir.join("scene.toml");
        std::fs::write(&path, scene(1.0)).unwrap();
        let mut cache = AssetCache::new();
        let first = load_cached(&path, &mut cache).unwrap();
        assert_eq!(cache.loaded().len(), 2, "{:?}", cache.loaded());

        // A light edit reuses both: the same grid allocation, nothing read anew.
        std::fs::write(&path, scene(2.0)).unwrap();
        let second = load_cached(&path, &mut cache).unwrap();
        assert!(cache.loaded().is_empty(), "{:?}", cache.loaded());
        assert!(Arc::ptr_eq(
            &first.scene.grid_media[0].grid,
            &second.scene.grid_media[0].grid
        ));

        // An edited OBJ is read again, the grid is still reused.
        std::fs::write(dir.join("floor.obj"), format!("{FLOOR}# edited\n")).unwrap();
        load_cached(&path, &mut cache).unwrap();
        assert_eq!(cache.loaded().len(), 1);
        assert!(
            cache.loaded()[0].ends_with("floor.obj"),
            "{:?}",
            cache.loaded()
        );

        // A truncated VDB fails the load; the cache keeps the good grid for when it is fixed.
        let bytes = std::fs::read(&vdb).unwrap();
        std::fs::write(dir.join("density.vdb"), &bytes[..bytes.len() / 2]).unwrap();
        assert!(load_cached(&path, &mut cache).is_err());
        std::fs::write(dir.join("density.vdb"), &bytes).unwrap();
        let fixed = load_cached(&path, &mut cache).unwrap();
        assert!(cache.loaded().is_empty(), "{:?}", cache.loaded());
        assert!(Arc::ptr_eq(
            &first.scene.grid_media[0].grid,
            &fixed.scene.grid_media[0].grid
        ));
        std::fs::remove_dir_all(&dir).ok();
    }
}
