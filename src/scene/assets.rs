//! Reuse of loaded assets across reloads of a scene file: `ppb watch` re-reads the scene on
//! every save, and a light or camera edit must not re-parse a VDB or a glTF.
//!
//! Entries are keyed by what was asked (path, grid name, procedural parameters) and checked
//! against a blake3 of the bytes of every file the asset was built from, so an edited,
//! truncated or replaced file is always loaded again. Files go through [`Files`]: each is
//! read at most once per load (the bytes hashed are the bytes parsed), and a file whose
//! length and modification time are unchanged since an earlier load is not read at all
//! to be hashed (see [`super::files`] for the racy-timestamp rule).
use std::collections::{HashMap, HashSet};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use super::files::Files;
use super::Imported;
use crate::error::Result;
use crate::media::grid::Grid;

struct ImportEntry {
    /// Hash of the bytes of the imported file that were parsed.
    main: [u8; 32],
    /// Its sidecars (.bin, .mtl, layers, VDBs), each with its hash.
    sidecars: Vec<(PathBuf, [u8; 32])>,
    imported: Imported,
}

/// Loaded imports and grids of earlier loads, plus what the latest load had to (re)load.
#[derive(Default)]
pub struct AssetCache {
    files: Files,
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
        self.files.begin();
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
        self.files.end(true);
    }

    /// Ends a load that failed: frees the bytes it read, keeps every cached asset.
    pub fn abandon(&mut self) {
        self.files.end(false);
    }

    /// Assets the latest load read from disk instead of reusing (one description each).
    pub fn loaded(&self) -> &[String] {
        &self.loaded
    }

    /// Files the latest load read from disk, in order, by canonical path: each at most
    /// once; a file reused unchanged (same length and modification time) not at all.
    pub fn files_read(&self) -> Vec<PathBuf> {
        self.files.files_read()
    }

    /// The reader of this load's files.
    pub fn files(&self) -> &Files {
        &self.files
    }

    /// An import (OBJ, glTF, USD): reused when it and its sidecars hash as before, else
    /// built by `load`, which reads its files through the given [`Files`].
    pub fn import(
        &mut self,
        path: &Path,
        load: impl FnOnce(&Files) -> Result<Imported>,
    ) -> Result<Imported> {
        self.used_imports.insert(path.to_path_buf());
        let main = self.files.hash(path)?;
        if let Some(e) = self.imports.get(path) {
            let files = &self.files;
            let same = |(p, h): &(PathBuf, [u8; 32])| files.hash(p).ok() == Some(*h);
            if e.main == main && e.sidecars.iter().all(same) {
                return Ok(e.imported.clone());
            }
        }
        let imported = load(&self.files)?;
        // The bytes parsed (read in this load, so no file is read again here).
        let main = self.files.hash(path)?;
        let mut sidecars = Vec::new();
        for f in imported.files.iter().filter(|f| f.is_file()) {
            sidecars.push((f.clone(), self.files.hash(f)?));
        }
        self.loaded.push(path.display().to_string());
        let entry = ImportEntry {
            main,
            sidecars,
            imported: imported.clone(),
        };
        self.imports.insert(path.to_path_buf(), entry);
        Ok(imported)
    }

    /// Grid `name` of the grid file at `path`, parsed from the file's bytes by `parse`:
    /// reused when the file hashes as before. Also returns the blake3 state after the
    /// file's bytes, for keys over the bytes and more (the octree cache key).
    pub fn grid_file(
        &mut self,
        path: &Path,
        name: &str,
        parse: impl FnOnce(Arc<Vec<u8>>) -> Result<Grid>,
    ) -> Result<(Arc<Grid>, blake3::Hasher)> {
        let key = format!("{} [{name}]", path.display());
        self.used_grids.insert(key.clone());
        let state = self.files.hasher(path)?;
        if let Some((h, g)) = self.grids.get(&key) {
            if h == state.finalize().as_bytes() {
                return Ok((g.clone(), state));
            }
        }
        let bytes = self.files.read(path)?;
        // Of the bytes read: the same as `state` unless the file changed unseen.
        let state = self.files.hasher(path)?;
        let g = Arc::new(parse(bytes)?);
        self.loaded.push(key.clone());
        self.grids
            .insert(key, (*state.finalize().as_bytes(), g.clone()));
        Ok((g, state))
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

    /// Backdates a file's modification time past the racy window of [`Files`] (each call
    /// gives a new time, as a real edit would).
    fn settle(p: &Path) {
        let old = std::time::SystemTime::now() - std::time::Duration::from_secs(60);
        let f = std::fs::File::options().write(true).open(p).unwrap();
        f.set_modified(old).unwrap();
    }

    fn names(paths: &[PathBuf]) -> Vec<String> {
        let mut v: Vec<String> = paths
            .iter()
            .map(|p| p.file_name().unwrap().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    }

    /// `ppb watch` reloads: a file whose length and modification time are unchanged is
    /// neither read nor hashed again; a changed one is read (once), and only re-parsed
    /// when its bytes differ.
    #[test]
    fn reload_reads_only_files_whose_size_or_time_changed() {
        let dir = std::env::temp_dir().join(format!("ppb-assets-memo-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let vdb =
            Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/conformance/smoke-grid/density.vdb");
        std::fs::copy(&vdb, dir.join("density.vdb")).unwrap();
        let obj = format!("mtllib floor.mtl\nusemtl grey\n{FLOOR}");
        std::fs::write(dir.join("floor.obj"), &obj).unwrap();
        std::fs::write(dir.join("floor.mtl"), "newmtl grey\nKd 0.5 0.5 0.5\n").unwrap();
        let path = dir.join("scene.toml");
        std::fs::write(&path, scene(1.0)).unwrap();
        for f in ["density.vdb", "floor.obj", "floor.mtl", "scene.toml"] {
            settle(&dir.join(f));
        }
        let mut cache = AssetCache::new();
        let first = load_cached(&path, &mut cache).unwrap();
        assert_eq!(
            names(&cache.files_read()),
            ["density.vdb", "floor.mtl", "floor.obj", "scene.toml"]
        );

        // A light edit: only the scene file is read; the OBJ, its .mtl and the VDB are
        // known unchanged by their length and time.
        std::fs::write(&path, scene(2.0)).unwrap();
        let second = load_cached(&path, &mut cache).unwrap();
        assert_eq!(names(&cache.files_read()), ["scene.toml"]);
        assert!(cache.loaded().is_empty(), "{:?}", cache.loaded());
        assert!(Arc::ptr_eq(
            &first.scene.grid_media[0].grid,
            &second.scene.grid_media[0].grid
        ));
        assert_eq!(
            first.scene.grid_media[0].source_hash,
            second.scene.grid_media[0].source_hash
        );

        // An edited OBJ is read and parsed (its .mtl read with it for the parse).
        std::fs::write(dir.join("floor.obj"), format!("{obj}# edited\n")).unwrap();
        settle(&dir.join("floor.obj"));
        load_cached(&path, &mut cache).unwrap();
        assert_eq!(
            names(&cache.files_read()),
            ["floor.mtl", "floor.obj", "scene.toml"]
        );
        assert_eq!(
            names(&cache.loaded().iter().map(PathBuf::from).collect::<Vec<_>>()),
            ["floor.obj"]
        );

        // The VDB rewritten with the same bytes: its new time makes it read (once) and
        // hashed, but the hash is the same, so the grid is not parsed again.
        let bytes = std::fs::read(dir.join("density.vdb")).unwrap();
        std::fs::write(dir.join("density.vdb"), &bytes).unwrap();
        settle(&dir.join("density.vdb"));
        let third = load_cached(&path, &mut cache).unwrap();
        assert_eq!(names(&cache.files_read()), ["density.vdb", "scene.toml"]);
        assert!(cache.loaded().is_empty(), "{:?}", cache.loaded());
        assert!(Arc::ptr_eq(
            &first.scene.grid_media[0].grid,
            &third.scene.grid_media[0].grid
        ));
        std::fs::remove_dir_all(&dir).ok();
    }
}
