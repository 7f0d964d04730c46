//! Grid files (.vdb, .nvdb) as one kind of input: the format from [`Format`], the
//! bytes read once, then listing and loading from those bytes.
use std::path::{Path, PathBuf};
use std::sync::Arc;

use super::files::Files;
use super::format::Format;
use crate::error::Result;
use crate::media::grid::Grid;
use crate::media::{nanovdb, openvdb};

/// One grid of a file as `ppb info` lists it.
#[derive(Clone, Debug, PartialEq)]
pub struct GridEntry {
    pub name: String,
    /// Value type and storage, e.g. "Tree_float_5_4_3 (class fog volume)" or
    /// "float (Blosc)".
    pub kind: String,
    /// Whether [`GridFile::load`] can load it (scalar float grids).
    pub loadable: bool,
}

/// A .vdb or .nvdb file read into memory.
pub struct GridFile {
    path: PathBuf,
    format: Format,
    bytes: Arc<Vec<u8>>,
}

impl GridFile {
    /// Reads the grid file at `path`; an error names it when its extension is not .vdb or
    /// .nvdb or it cannot be read.
    pub fn open(path: &Path) -> Result<GridFile> {
        GridFile::read(path, &Files::new())
    }

    /// [`GridFile::open`] through a load's [`Files`] (read once, hashed as read).
    pub fn read(path: &Path, files: &Files) -> Result<GridFile> {
        let format = Format::of_kind(path, &Format::GRIDS)?;
        Ok(GridFile {
            path: path.to_path_buf(),
            format,
            bytes: files.read(path)?,
        })
    }

    /// Grid file bytes already read; `path` names the file (and its format) in errors.
    pub fn from_bytes(path: &Path, bytes: Arc<Vec<u8>>) -> Result<GridFile> {
        let format = Format::of_kind(path, &Format::GRIDS)?;
        Ok(GridFile {
            path: path.to_path_buf(),
            format,
            bytes,
        })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    pub fn format(&self) -> Format {
        self.format
    }

    /// The file's grids in file order.
    pub fn grids(&self) -> Result<Vec<GridEntry>> {
        Ok(match self.format {
            Format::NanoVdb => nanovdb::list_grids_from(&self.path, &self.bytes)?
                .into_iter()
                .map(|g| GridEntry {
                    loadable: g.grid_type == nanovdb::GridType::FLOAT,
                    kind: format!("{} ({:?})", g.grid_type.name(), g.codec),
                    name: g.name,
                })
                .collect(),
            _ => openvdb::list_grids_from(&self.path, &self.bytes)?
                .into_iter()
                .map(|g| {
                    let half = if g.half { ", saved as half" } else { "" };
                    GridEntry {
                        loadable: g.value_type == "Tree_float_5_4_3",
                        kind: format!("{} (class {}{half})", g.value_type, g.class),
                        name: g.name,
                    }
                })
                .collect(),
        })
    }

    /// Loads the float grid called `name`.
    pub fn load(&self, name: &str) -> Result<Grid> {
        match self.format {
            Format::NanoVdb => nanovdb::load_grid_from(&self.path, &self.bytes, name),
            _ => openvdb::load_grid_from(&self.path, &self.bytes, name),
        }
    }
}

/// Loads grid `name` from the .vdb or .nvdb file at `path`.
pub fn load_grid(path: &Path, name: &str) -> Result<Grid> {
    GridFile::open(path)?.load(name)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lists_and_loads_from_one_read() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR"));
        let vdb = root.join("scenes/conformance/smoke-grid/density.vdb");
        let files = Files::new();
        files.begin();
        let f = GridFile::read(&vdb, &files).unwrap();
        let grids = f.grids().unwrap();
        let g = grids.iter().find(|g| g.loadable).expect("a float grid");
        let grid = f.load(&g.name).unwrap();
        assert!(grid.active_voxels() > 0);
        assert_eq!(files.files_read().len(), 1);
        let e = load_grid(&root.join("Cargo.toml"), "density")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("Cargo.toml: expected a .vdb or .nvdb file"),
            "{e}"
        );
    }
}
