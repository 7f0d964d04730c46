//! NanoVDB (`.nvdb`) reader: lists the grids of a file and loads float grids into a [`Grid`].
//!
//! Both on-disk layouts NanoVDB has written are read: files of segments (a 16-byte header,
//! then per grid a 176-byte metadata record and its name, then the grid buffers, each raw,
//! zlib- or blosc-compressed), with the file magic `NanoVDB0` (before 32.6) or `NanoVDB2`,
//! and raw grid buffers (`NanoVDB1`, from 32.6 on). Only major version 32 is accepted; the
//! float grid buffer layout is the same in 32.4 and 32.9 (both are in the test data), only
//! the magic numbers and the extent of the header checksum differ.
//!
//! The whole file is untrusted: every size and offset is checked before it is used, a
//! decompressed size must be reachable by its codec from the bytes stored, and the tree is
//! walked with each node claimed at most once, so a damaged file is an `Error::format`.
mod blosc;
mod bytes;
mod codec;
mod file;
mod tree;

use std::fmt;
use std::path::Path;

use glam::{DVec3, IVec3};

use crate::error::{Error, Result};
use crate::media::grid::Grid;

/// NanoVDB's `GridType` enum value.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct GridType(pub u32);

impl GridType {
    pub const FLOAT: GridType = GridType(1);
    pub const VEC3F: GridType = GridType(6);

    /// The name `nanovdb_print` shows.
    pub fn name(self) -> &'static str {
        const NAMES: [&str; 27] = [
            "?",
            "float",
            "double",
            "int16",
            "int32",
            "int64",
            "Vec3f",
            "Vec3d",
            "Mask",
            "Half",
            "uint32",
            "bool",
            "RGBA8",
            "Float4",
            "Float8",
            "Float16",
            "FloatN",
            "Vec4f",
            "Vec4d",
            "Index",
            "OnIndex",
            "IndexMask",
            "OnIndexMask",
            "PointIndex",
            "Vec3u8",
            "Vec3u16",
            "uint8",
        ];
        NAMES.get(self.0 as usize).copied().unwrap_or("unknown")
    }
}

impl fmt::Display for GridType {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} (type {})", self.name(), self.0)
    }
}

/// NanoVDB's `GridClass` enum value.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct GridClass(pub u32);

impl GridClass {
    pub const UNKNOWN: GridClass = GridClass(0);
    pub const LEVEL_SET: GridClass = GridClass(1);
    pub const FOG_VOLUME: GridClass = GridClass(2);

    pub fn name(self) -> &'static str {
        const NAMES: [&str; 10] = [
            "unknown",
            "level set",
            "fog volume",
            "staggered",
            "point index",
            "point data",
            "topology",
            "voxel volume",
            "index grid",
            "tensor grid",
        ];
        NAMES.get(self.0 as usize).copied().unwrap_or("invalid")
    }
}

/// How a grid buffer is stored in the file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Codec {
    None,
    Zip,
    Blosc,
}

/// NanoVDB library version that wrote a segment or grid (major.minor.patch).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Version {
    pub major: u32,
    pub minor: u32,
    pub patch: u32,
}

impl Version {
    fn from_packed(v: u32) -> Version {
        Version {
            major: v >> 21,
            minor: (v >> 10) & 0x7ff,
            patch: v & 0x3ff,
        }
    }
}

impl fmt::Display for Version {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}.{}.{}", self.major, self.minor, self.patch)
    }
}

/// What a file says about one grid, without decoding it.
#[derive(Clone, Debug, PartialEq)]
pub struct GridMetaData {
    pub name: String,
    pub grid_type: GridType,
    pub grid_class: GridClass,
    pub version: Version,
    pub codec: Codec,
    /// Size of the decoded grid buffer.
    pub grid_bytes: u64,
    /// Size of the grid as stored in the file.
    pub file_bytes: u64,
    pub active_voxels: u64,
    /// Inclusive index bounding box of the active voxels.
    pub index_bbox: (IVec3, IVec3),
    /// World bounding box (NanoVDB's: the max side includes the last voxel's extent).
    pub world_bbox: (DVec3, DVec3),
    pub voxel_size: DVec3,
    /// Leaf, lower and upper internal node counts.
    pub node_counts: [u32; 3],
    /// Active tiles in lower, upper internal nodes and the root.
    pub active_tiles: [u32; 3],
}

/// Every grid in the file, in file order.
pub fn list_grids(path: &Path) -> Result<Vec<GridMetaData>> {
    let data = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    list_grids_from(path, &data)
}

/// [`list_grids`] of a file already read: `data` is its bytes, `path` names it in errors.
pub fn list_grids_from(path: &Path, data: &[u8]) -> Result<Vec<GridMetaData>> {
    let entries = file::entries(bytes::Bytes(data)).map_err(|m| Error::format(path, m))?;
    Ok(entries.into_iter().map(|e| e.info).collect())
}

/// Loads the first float grid called `name`.
pub fn load_grid(path: &Path, name: &str) -> Result<Grid> {
    let data = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    load_grid_from(path, &data, name)
}

/// [`load_grid`] from a file already read: `data` is its bytes, `path` names it in errors.
pub fn load_grid_from(path: &Path, data: &[u8], name: &str) -> Result<Grid> {
    let entries = file::entries(bytes::Bytes(data)).map_err(|m| Error::format(path, m))?;
    let Some(entry) = entries.iter().find(|e| e.info.name == name) else {
        let names: Vec<&str> = entries.iter().map(|e| e.info.name.as_str()).collect();
        let msg = format!("no grid \"{name}\" (grids in file: {})", names.join(", "));
        return Err(Error::field(path, "grid", msg));
    };
    let info = &entry.info;
    if info.grid_type != GridType::FLOAT {
        let msg = format!(
            "grid \"{name}\" has type {}; only float grids can be loaded",
            info.grid_type
        );
        return Err(Error::field(path, "grid", msg));
    }
    let in_grid = |m: String| Error::format(path, format!("grid \"{name}\": {m}"));
    let stored = bytes::Bytes(data)
        .slice(entry.offset, info.file_bytes)
        .map_err(in_grid)?;
    let buffer = codec::decode(stored, info.codec, info.grid_bytes).map_err(in_grid)?;
    tree::load_float(&buffer, info).map_err(in_grid)
}
/// The magic numbers of a segment header and of a grid buffer.
const MAGIC_NUMB: u64 = u64::from_le_bytes(*b"NanoVDB0");
const MAGIC_GRID: u64 = u64::from_le_bytes(*b"NanoVDB1");

fn version(packed: u32) -> bytes::Parse<Version> {
    let v = Version::from_packed(packed);
    if v.major != 32 {
        return Err(format!(
            "NanoVDB version {v} is not supported (major version 32 is)"
        ));
    }
    Ok(v)
}
