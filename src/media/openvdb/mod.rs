//! OpenVDB (`.vdb`) reader: lists a file's grids and loads scalar float grids
//! (`Tree_float_5_4_3`, stored in full or half precision) as a [`Grid`].
//!
//! Layout, as OpenVDB's `io::File` writes it (format 222 and later, little-endian):
//! header (magic, format and library versions, grid-offsets flag, UUID), file metadata,
//! a grid count, then per grid a descriptor (unique name, tree type, instance parent, byte
//! offsets of the grid, of its leaf buffers and of its end) followed by the grid: its
//! compression flags, metadata, transform, tree topology and leaf buffers.
//!
//! The whole file is read into memory and every count and size is checked against the
//! bytes left before it is used: a truncated or corrupt file is an `Error::format` naming
//! what broke, never a panic or an allocation out of proportion to the file.
mod bytes;
mod transform;
mod tree;
mod values;

use crate::error::{Error, Result};
use crate::media::grid::{Grid, GridBuilder};
use bytes::{Parse, Reader};
use std::path::Path;
use tree::TreeReader;

const MAGIC: i64 = 0x5644_4220;
/// Node-mask compression (OpenVDB 3.0): the oldest layout this reader knows.
const MIN_VERSION: u32 = 222;
const HALF_SUFFIX: &str = "_HalfFloat";
/// Separates a grid name from the suffix that makes duplicate names unique.
const NAME_SEP: char = '\x1e';
const FLOAT_TREE: &str = "Tree_float_5_4_3";
const KNOWN_COMPRESSION: u32 =
    values::COMPRESS_ZIP | values::COMPRESS_ACTIVE_MASK | values::COMPRESS_BLOSC;

/// One grid of a file, as listed by [`list_grids`].
#[derive(Clone, Debug, PartialEq)]
pub struct GridDescriptor {
    /// The grid's name (without the suffix OpenVDB adds to duplicate names).
    pub name: String,
    /// The tree type as written, without the `_HalfFloat` suffix, e.g. `Tree_float_5_4_3`.
    pub value_type: String,
    /// The `class` metadata: "fog volume", "level set", "staggered" or "unknown".
    pub class: String,
    /// Whether the values are stored as 16-bit half floats.
    pub half: bool,
    /// Position in the file, from 0.
    pub index: usize,
}

struct Descriptor {
    unique_name: String,
    name: String,
    tree_type: String,
    half: bool,
    parent: String,
    grid_pos: u64,
    block_pos: u64,
    end_pos: u64,
}

/// Lists the grids of a `.vdb` file in file order.
pub fn list_grids(path: &Path) -> Result<Vec<GridDescriptor>> {
    let data = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    list_grids_from(path, &data)
}

/// [`list_grids`] of a file already read: `data` is its bytes, `path` names it in errors.
pub fn list_grids_from(path: &Path, data: &[u8]) -> Result<Vec<GridDescriptor>> {
    let descs = read_descriptors(data).map_err(|m| Error::format(path, m))?;
    descs
        .iter()
        .enumerate()
        .map(|(index, d)| {
            let mut r = Reader::new(data);
            let (_, class) = read_grid_start(&mut r, d)
                .map_err(|m| Error::format(path, format!("grid \"{}\": {m}", d.name)))?;
            Ok(GridDescriptor {
                name: d.name.clone(),
                value_type: d.tree_type.clone(),
                class,
                half: d.half,
                index,
            })
        })
        .collect()
}

/// Loads the scalar float grid called `name` (exact unique name first, then plain name).
pub fn load_grid(path: &Path, name: &str) -> Result<Grid> {
    let data = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    load_grid_from(path, &data, name)
}

/// [`load_grid`] from a file already read: `data` is its bytes, `path` names it in errors.
pub fn load_grid_from(path: &Path, data: &[u8], name: &str) -> Result<Grid> {
    let descs = read_descriptors(data).map_err(|m| Error::format(path, m))?;
    let desc = find(&descs, name).ok_or_else(|| no_grid(path, name, &descs))?;
    if desc.tree_type != FLOAT_TREE {
        return Err(Error::field(
            path,
            "grid",
            format!(
                "grid \"{}\" has type {}; only scalar float grids ({FLOAT_TREE}) can be loaded",
                desc.name, desc.tree_type
            ),
        ));
    }
    read_grid(data, &descs, desc)
        .map_err(|m| Error::format(path, format!("grid \"{}\": {m}", desc.name)))
}

fn no_grid(path: &Path, name: &str, descs: &[Descriptor]) -> Error {
    let names: Vec<&str> = descs.iter().map(|d| d.name.as_str()).collect();
    let names = if names.is_empty() {
        "none".to_string()
    } else {
        names.join(", ")
    };
    let msg = format!("no grid \"{name}\" (grids in file: {names})");
    Error::field(path, "grid", msg)
}

fn find<'d>(descs: &'d [Descriptor], name: &str) -> Option<&'d Descriptor> {
    descs
        .iter()
        .find(|d| d.unique_name == name)
        .or_else(|| descs.iter().find(|d| d.name == name))
}

/// Reads the header and file metadata, then walks the grid descriptors.
fn read_descriptors(data: &[u8]) -> Parse<Vec<Descriptor>> {
    let mut r = Reader::new(data);
    read_header(&mut r)?;
    read_metadata(&mut r, "file metadata")?;
    let count = r.i32("grid count")?;
    if count < 0 {
        return Err(format!("negative grid count {count}"));
    }
    let mut descs = Vec::new();
    for i in 0..count {
        let d = read_descriptor(&mut r).map_err(|e| format!("grid descriptor {i}: {e}"))?;
        r.seek(d.end_pos, "next grid descriptor")?;
        descs.push(d);
    }
    Ok(descs)
}

fn read_header(r: &mut Reader) -> Parse<()> {
    let magic = r.i64("magic number")?;
    if magic != MAGIC {
        return Err(format!("not an OpenVDB file (magic number {magic:#x})"));
    }
    let version = r.u32("file format version")?;
    if version < MIN_VERSION {
        return Err(format!(
            "file format version {version} is older than {MIN_VERSION} (OpenVDB 3.0); not supported"
        ));
    }
    r.u32("library major version")?;
    r.u32("library minor version")?;
    if r.u8("grid offsets flag")? == 0 {
        return Err("file has no grid offsets (written as a stream); not supported".into());
    }
    r.take(36, "UUID")?;
    Ok(())
}

fn read_descriptor(r: &mut Reader) -> Parse<Descriptor> {
    let unique_name = r.string("grid name")?;
    let written_type = r.string("grid type")?;
    let parent = r.string("instance parent name")?;
    let [grid_pos, block_pos, end_pos] = read_offsets(r, !parent.is_empty())?;
    let (tree_type, half) = match written_type.strip_suffix(HALF_SUFFIX) {
        Some(t) => (t.to_string(), true),
        None => (written_type, false),
    };
    Ok(Descriptor {
        name: unique_name.split(NAME_SEP).next().unwrap_or("").to_string(),
        unique_name,
        tree_type,
        half,
        parent,
        grid_pos,
        block_pos,
        end_pos,
    })
}

/// Grid, buffer and end offsets: in order, after the descriptor, within the file. An
/// instance has no buffers of its own (its buffer offset is 0).
fn read_offsets(r: &mut Reader, instance: bool) -> Parse<[u64; 3]> {
    let start = r.pos() as u64 + 24;
    let mut offsets = [0u64; 3];
    for (o, what) in offsets
        .iter_mut()
        .zip(["grid offset", "buffer offset", "end offset"])
    {
        let p = r.i64(what)?;
        *o = u64::try_from(p).map_err(|_| format!("negative {what} {p}"))?;
    }
    let [grid, block, end] = offsets;
    let ordered = start <= grid && grid <= end && (instance || (grid <= block && block <= end));
    if !ordered || end > r.len() as u64 {
        return Err(format!(
            "offsets grid {grid}, buffers {block}, end {end} are out of order or past the end ({} bytes)",
            r.len()
        ));
    }
    Ok(offsets)
}

/// Metadata map: count, then per entry name, type name, byte size and value bytes.
/// Returns the `class` string if present.
fn read_metadata(r: &mut Reader, what: &str) -> Parse<Option<String>> {
    let count = r.u32(what)? as u64;
    if count * 12 > r.remaining() as u64 {
        return Err(format!(
            "{what} claims {count} entries, more than the bytes left"
        ));
    }
    let mut class = None;
    for _ in 0..count {
        let name = r.string("metadata name")?;
        let type_name = r.string("metadata type")?;
        let size = r.u32("metadata size")? as usize;
        let value = r.take(size, "metadata value")?;
        if name == "class" && type_name == "string" {
            class = Some(String::from_utf8_lossy(value).into_owned());
        }
    }
    Ok(class)
}

/// Reads a grid's compression flags and metadata; returns (compression, class).
fn read_grid_start(r: &mut Reader, d: &Descriptor) -> Parse<(u32, String)> {
    r.seek(d.grid_pos, "grid")?;
    let compression = r.u32("compression flags")?;
    if compression & !KNOWN_COMPRESSION != 0 {
        return Err(format!("unknown compression flags {compression:#x}"));
    }
    let class = read_metadata(r, "grid metadata")?.unwrap_or_else(|| "unknown".into());
    Ok((compression, class))
}

/// Reads the grid's own metadata and transform, then the tree from its owner (the grid
/// itself, or its instance parent), checking that the parts end where the descriptor says.
fn read_grid(data: &[u8], descs: &[Descriptor], desc: &Descriptor) -> Parse<Grid> {
    let mut r = Reader::new(data);
    read_grid_start(&mut r, desc)?;
    let index_to_world = transform::read(&mut r)?;
    let tree_desc = tree_owner(descs, desc)?;
    let (compression, _) = read_grid_start(&mut r, tree_desc)?;
    transform::read(&mut r)?;
    let mut b = GridBuilder::new(desc.name.clone(), 0.0, index_to_world);
    let mut t = TreeReader::new(&mut r, compression, tree_desc.half);
    t.read_topology(&mut b)?;
    expect_at(t.reader(), tree_desc.block_pos, "the leaf buffers")?;
    t.read_buffers(&mut b)?;
    expect_at(t.reader(), tree_desc.end_pos, "the end of the grid")?;
    Ok(b.finish())
}

/// The descriptor whose tree `desc` uses: itself, or its instance parent.
fn tree_owner<'d>(descs: &'d [Descriptor], desc: &'d Descriptor) -> Parse<&'d Descriptor> {
    if desc.parent.is_empty() {
        return Ok(desc);
    }
    let parent = descs
        .iter()
        .find(|d| d.unique_name == desc.parent)
        .ok_or_else(|| format!("instance parent \"{}\" is not in the file", desc.parent))?;
    if !parent.parent.is_empty() || parent.tree_type != desc.tree_type || parent.half != desc.half {
        return Err(format!(
            "instance parent \"{}\" is itself an instance or has a different tree type",
            parent.name
        ));
    }
    Ok(parent)
}

fn expect_at(r: &Reader, pos: u64, what: &str) -> Parse<()> {
    if r.pos() as u64 != pos {
        return Err(format!(
            "tree data ends at byte {}, but the descriptor puts {what} at byte {pos}",
            r.pos()
        ));
    }
    Ok(())
}
