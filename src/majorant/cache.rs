//! The baked octree cache: one file per grid medium, named after its key.
//!
//! Key: blake3 of the format version, the build settings and the medium's source hash
//! (the grid file's bytes, grid name, density scale, transform; or a procedural medium's
//! parameters). File: a 96-byte header (magic, version, node count, key, blake3 checksum
//! of the payload) followed by the nodes as stored in memory. A file whose header,
//! version, size, key or checksum does not match is reported and rebuilt, never trusted;
//! writes go to a temp file that is renamed into place.
use std::path::{Path, PathBuf};

use super::octree::{Node, Octree};
use super::Field;
use crate::core::fs::write_atomic;
use crate::error::{Error, Result};

const MAGIC: &[u8; 8] = b"PPBOCTR\0";
/// Bump when the node layout or the build algorithm changes.
pub const FORMAT_VERSION: u32 = 2;
const HEADER: usize = 8 + 4 + 4 + 8 + 32 + 32 + 8;

/// What a cache lookup found.
#[derive(Debug, Clone, PartialEq)]
pub enum Status {
    Fresh,
    Missing,
    /// Present but unusable, with the reason.
    Invalid(String),
}

/// Names the bounds computation, so trees baked by an older builder are rebuilt.
const BUILDER: &[u8] = b"bounds from voxel blocks, exact below 4 voxels";

/// The cache key of a medium's octree under these build settings.
pub fn key(g: &impl Field, max_depth: u32) -> [u8; 32] {
    let mut h = blake3::Hasher::new();
    h.update(MAGIC);
    h.update(&FORMAT_VERSION.to_le_bytes());
    h.update(&super::octree::depth_for(g, max_depth).to_le_bytes());
    h.update(&super::octree::PYRAMID_BUDGET_BYTES.to_le_bytes());
    h.update(BUILDER);
    h.update(&super::octree::STEP_COST.to_le_bytes());
    h.update(&super::octree::TENTATIVE_COST.to_le_bytes());
    h.update(&g.source_hash());
    *h.finalize().as_bytes()
}

pub fn path_for(dir: &Path, key: &[u8; 32]) -> PathBuf {
    let hex: String = key[..16].iter().map(|b| format!("{b:02x}")).collect();
    dir.join(format!("octree-{hex}.bin"))
}

fn encode(tree: &Octree, key: &[u8; 32]) -> Vec<u8> {
    let payload: &[u8] = bytemuck::cast_slice(&tree.nodes);
    let mut out = Vec::with_capacity(HEADER + payload.len());
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&FORMAT_VERSION.to_le_bytes());
    out.extend_from_slice(&(std::mem::size_of::<Node>() as u32).to_le_bytes());
    out.extend_from_slice(&(tree.nodes.len() as u64).to_le_bytes());
    out.extend_from_slice(key);
    out.extend_from_slice(blake3::hash(payload).as_bytes());
    out.extend_from_slice(&0u64.to_le_bytes());
    out.extend_from_slice(payload);
    out
}

/// Decodes and validates a cache file's bytes against the expected key.
pub fn decode(bytes: &[u8], key: &[u8; 32]) -> std::result::Result<Octree, String> {
    if bytes.len() < HEADER {
        return Err(format!(
            "truncated: {} bytes, header needs {HEADER}",
            bytes.len()
        ));
    }
    if &bytes[..8] != MAGIC {
        return Err("not a ppb octree cache (bad magic)".into());
    }
    let u32_at = |o: usize| u32::from_le_bytes(bytes[o..o + 4].try_into().expect("4 bytes"));
    let version = u32_at(8);
    if version != FORMAT_VERSION {
        return Err(format!(
            "format version {version}, expected {FORMAT_VERSION}"
        ));
    }
    if u32_at(12) as usize != std::mem::size_of::<Node>() {
        return Err("node size differs".into());
    }
    let count = u64::from_le_bytes(bytes[16..24].try_into().expect("8 bytes"));
    if &bytes[24..56] != key {
        return Err("built from other inputs (key differs)".into());
    }
    let payload = &bytes[HEADER..];
    let expect_len = (count as u128) * std::mem::size_of::<Node>() as u128;
    if payload.len() as u128 != expect_len || count == 0 {
        return Err(format!(
            "size mismatch: {} payload bytes for {count} nodes",
            payload.len()
        ));
    }
    if blake3::hash(payload).as_bytes() != &bytes[56..88] {
        return Err("checksum mismatch (corrupt file)".into());
    }
    let nodes: Vec<Node> = bytemuck::pod_collect_to_vec(payload);
    // Children come after their parent, so a tree read back cannot loop.
    let bad_child = |(i, n): (usize, &Node)| {
        n.first_child != 0
            && (n.first_child as usize <= i || n.first_child as usize + 8 > nodes.len())
    };
    if nodes.iter().enumerate().any(bad_child) {
        return Err("child index out of range".into());
    }
    if nodes.iter().any(|n| n.depth > 8) {
        return Err("node deeper than 8 levels".into());
    }
    Ok(Octree::from_nodes(nodes))
}

/// Looks the medium's octree up in `dir`.
pub fn load(dir: &Path, g: &impl Field, max_depth: u32) -> (Status, Option<Octree>) {
    let k = key(g, max_depth);
    let path = path_for(dir, &k);
    match std::fs::read(&path) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => (Status::Missing, None),
        Err(e) => (Status::Invalid(format!("{}: {e}", path.display())), None),
        Ok(bytes) => match decode(&bytes, &k) {
            Ok(t) => (Status::Fresh, Some(t)),
            Err(why) => (Status::Invalid(format!("{}: {why}", path.display())), None),
        },
    }
}

/// Writes the octree atomically into `dir` (created if needed); returns the file path.
pub fn store(dir: &Path, g: &impl Field, max_depth: u32, tree: &Octree) -> Result<PathBuf> {
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    crate::core::fs::sweep_temps(dir, crate::core::fs::STALE_TEMP);
    let k = key(g, max_depth);
    let path = path_for(dir, &k);
    let bytes = encode(tree, &k);
    write_atomic(&path, |tmp| {
        std::fs::write(tmp, &bytes).map_err(|e| Error::io(tmp, e))
    })?;
    Ok(path)
}
