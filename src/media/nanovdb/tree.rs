//! The grid buffer of a float grid: GridData (672 bytes), TreeData (64), then the root,
//! upper (32^3), lower (16^3) internal nodes and 8^3 leaves, each level contiguous.
//! Nodes refer to children by signed byte offsets from themselves; the walk checks that
//! each offset lands on a distinct node of the right level, so a damaged buffer cannot
//! make it loop, alias nodes or read outside the buffer.
use std::collections::HashSet;

use glam::{DAffine3, DMat3, IVec3};

use super::bytes::{offset, Bytes, Parse};
use super::{version, Codec, GridClass, GridMetaData, GridType, MAGIC_GRID, MAGIC_NUMB};
use crate::media::grid::{Grid, GridBuilder, Leaf, Tile};

const GRID_DATA: u64 = 672;
const TREE_DATA: u64 = 64;
/// GridData and TreeData: the smallest possible grid buffer.
pub(super) const MIN_GRID_BYTES: u64 = GRID_DATA + TREE_DATA;
const GRID_NAME: u64 = 40;
const GRID_NAME_BYTES: u64 = 256;
/// Map::mMatD (row-major 3x3 acting on column vectors) and Map::mVecD.
const MAP_MATRIX: u64 = 296 + 88;
const MAP_TRANSLATION: u64 = 296 + 232;
const WORLD_BBOX: u64 = 560;
const VOXEL_SIZE: u64 = 608;
const GRID_CLASS: u64 = 632;
const GRID_TYPE: u64 = 636;
/// RootData<float>: bbox, table size and five float stats, padded to 32 bytes.
const ROOT_HEADER: u64 = 64;
/// Root tile: u64 key, i64 child offset, u32 state, f32 value, padded to 32 bytes.
const ROOT_TILE: u64 = 32;
const LEAF_MASK: u64 = 16;
const LEAF_VALUES: u64 = 96;
const LEAF_BYTES: u64 = LEAF_VALUES + 512 * 4;

/// An internal node level: bbox and flags (32 bytes), value and child masks, four float
/// stats, then (32-byte aligned) one 8-byte entry per child slot: a child offset or a value.
struct NodeKind {
    log2_dim: u32,
    /// log2 of the edge, in voxels, of one child slot.
    child_log2: u32,
    table: u64,
    bytes: u64,
    child: Option<&'static NodeKind>,
}

impl NodeKind {
    const fn new(log2_dim: u32, child_log2: u32, child: Option<&'static NodeKind>) -> Self {
        let mask_bytes = 1u64 << (3 * log2_dim - 3);
        let table = (32 + 2 * mask_bytes + 16).div_ceil(32) * 32;
        NodeKind {
            log2_dim,
            child_log2,
            table,
            bytes: table + 8 * (1 << (3 * log2_dim)),
            child,
        }
    }

    fn mask_words(&self) -> u64 {
        1 << (3 * self.log2_dim - 6)
    }
}

static LOWER: NodeKind = NodeKind::new(4, 3, None);
static UPPER: NodeKind = NodeKind::new(5, 7, Some(&LOWER));
const ROOT_TILE_LOG2: u32 = 12;
/// The grid's leaf lookup table is dense over the leaves' bounding box (4 bytes per 8^3
/// slot); a tree spread wider than this (512 MiB of table) is refused rather than built.
const MAX_LEAF_SLOTS: u64 = 1 << 27;
/// Below [`MAX_LEAF_SLOTS`], the table may also not outgrow the buffer by more than
/// 4 slots per byte (16 table bytes per buffer byte), with this floor for small grids:
/// a few leaves far apart would otherwise cost up to 512 MiB for a buffer of kilobytes.
const MIN_LEAF_SLOTS: u64 = 1 << 22;

struct TreeData {
    /// Byte offsets from the tree to the first leaf, lower, upper node and the root.
    offsets: [u64; 4],
    /// Leaf, lower and upper node counts.
    counts: [u32; 3],
    active_tiles: [u32; 3],
    active_voxels: u64,
}

impl TreeData {
    fn read(b: Bytes) -> Parse<TreeData> {
        let t = GRID_DATA;
        Ok(TreeData {
            offsets: [b.u64(t)?, b.u64(t + 8)?, b.u64(t + 16)?, b.u64(t + 24)?],
            counts: [b.u32(t + 32)?, b.u32(t + 36)?, b.u32(t + 40)?],
            active_tiles: [b.u32(t + 44)?, b.u32(t + 48)?, b.u32(t + 52)?],
            active_voxels: b.u64(t + 56)?,
        })
    }

    /// Byte position of the root, checked to lie inside the buffer.
    fn root(&self, b: Bytes) -> Parse<u64> {
        let root = GRID_DATA.saturating_add(self.offsets[3]);
        b.slice(root, ROOT_HEADER)
            .map_err(|m| format!("root node: {m}"))?;
        Ok(root)
    }
}

/// What a bare grid buffer says about itself (files without segment metadata).
pub(super) fn info(buf: &[u8]) -> Parse<GridMetaData> {
    let b = Bytes(buf);
    let tree = TreeData::read(b)?;
    let root = tree.root(b)?;
    Ok(GridMetaData {
        name: b.c_str(GRID_NAME, GRID_NAME_BYTES)?,
        grid_type: GridType(b.u32(GRID_TYPE)?),
        grid_class: GridClass(b.u32(GRID_CLASS)?),
        version: version(b.u32(16)?)?,
        codec: Codec::None,
        grid_bytes: b.len(),
        file_bytes: b.len(),
        active_voxels: tree.active_voxels,
        index_bbox: (b.ivec3(root)?, b.ivec3(root + 12)?),
        world_bbox: (b.dvec3(WORLD_BBOX)?, b.dvec3(WORLD_BBOX + 24)?),
        voxel_size: b.dvec3(VOXEL_SIZE)?,
        node_counts: tree.counts,
        active_tiles: tree.active_tiles,
    })
}

/// Builds the [`Grid`] of a float grid buffer described by `info`.
pub(super) fn load_float(buf: &[u8], info: &GridMetaData) -> Parse<Grid> {
    let b = Bytes(buf);
    check_header(b, info)?;
    let tree = TreeData::read(b)?;
    let root = tree.root(b)?;
    check_checksum(b, root)?;
    let background = b.f32(root + 28)?;
    let mut builder = GridBuilder::new(info.name.clone(), background, index_to_world(b)?);
    // The header's leaf count, bounded by what the buffer can hold (a corrupt count must not
    // reserve more than a small multiple of the file).
    builder.reserve_leaves((info.node_counts[0] as usize).min(buf.len() / 256));
    let mut walk = Walk::new(b, &tree, builder)?;
    walk.root(root)?;
    walk.finish(&tree)
}

fn check_header(b: Bytes, info: &GridMetaData) -> Parse<()> {
    let magic = b.u64(0)?;
    if magic != MAGIC_NUMB && magic != MAGIC_GRID {
        return Err(format!("bad grid magic {magic:#018x}"));
    }
    version(b.u32(16)?)?;
    let size = b.u64(32)?;
    if size != b.len() {
        return Err(format!(
            "grid header says {size} bytes, the buffer has {}",
            b.len()
        ));
    }
    let grid_type = GridType(b.u32(GRID_TYPE)?);
    if grid_type != GridType::FLOAT || grid_type != info.grid_type {
        return Err(format!(
            "grid buffer has type {grid_type}, the file says {}",
            info.grid_type
        ));
    }
    Ok(())
}

/// Verifies the CRC-32 NanoVDB keeps of the buffer's head (bytes 16.. of GridData onwards)
/// when one was written. Before 32.6 the head runs to the end of the root's tile table,
/// from 32.6 on it ends after TreeData; either is accepted.
fn check_checksum(b: Bytes, root: u64) -> Parse<()> {
    let sum = b.u64(8)?;
    let head = sum as u32;
    if sum == u64::MAX || head == u32::MAX {
        return Ok(());
    }
    let crc = |end: u64| -> Parse<u32> {
        let mut c = flate2::Crc::new();
        c.update(b.slice(16, end.saturating_sub(16))?);
        Ok(c.sum())
    };
    let tiles = b.u32(root + 24)? as u64;
    let root_end = root + ROOT_HEADER + tiles * ROOT_TILE;
    if crc(MIN_GRID_BYTES)? == head || crc(root_end)? == head {
        return Ok(());
    }
    Err(format!(
        "grid header checksum mismatch (stored {head:#010x})"
    ))
}

fn index_to_world(b: Bytes) -> Parse<DAffine3> {
    let mut m = [0.0; 9];
    for (i, v) in m.iter_mut().enumerate() {
        *v = b.f64(MAP_MATRIX + 8 * i as u64)?;
    }
    let matrix = DMat3::from_cols_array(&m).transpose();
    let translation = b.dvec3(MAP_TRANSLATION)?;
    let invertible = matrix.determinant().is_normal() && matrix.inverse().is_finite();
    if !(invertible && translation.is_finite()) {
        return Err(format!(
            "index-to-world map {m:?} + {translation} is not invertible"
        ));
    }
    Ok(DAffine3::from_mat3_translation(matrix, translation))
}

/// The contiguous block of nodes of one level, and which of them the walk has reached.
struct Region {
    kind: &'static str,
    start: u64,
    bytes: u64,
    seen: Vec<bool>,
}

impl Region {
    fn new(b: Bytes, kind: &'static str, offset: u64, count: u32, bytes: u64) -> Parse<Region> {
        let start = GRID_DATA.saturating_add(offset);
        if count > 0 {
            b.slice(start, count as u64 * bytes)
                .map_err(|m| format!("{count} {kind} nodes: {m}"))?;
        }
        Ok(Region {
            kind,
            start,
            bytes,
            seen: vec![false; count as usize],
        })
    }

    /// Marks the node at byte `pos`, which must start a node of this level not seen before.
    fn claim(&mut self, pos: u64) -> Parse<()> {
        let rel = pos.checked_sub(self.start);
        let slot = rel
            .filter(|r| r.is_multiple_of(self.bytes))
            .map(|r| r / self.bytes)
            .and_then(|i| usize::try_from(i).ok())
            .and_then(|i| self.seen.get_mut(i));
        match slot {
            Some(seen) if !*seen => {
                *seen = true;
                Ok(())
            }
            _ => Err(format!(
                "child pointer to byte {pos} is not a new {} node",
                self.kind
            )),
        }
    }

    fn check_all_seen(&self) -> Parse<()> {
        let missed = self.seen.iter().filter(|&&s| !s).count();
        if missed > 0 {
            return Err(format!(
                "{missed} of {} {} nodes are not reachable from the root",
                self.seen.len(),
                self.kind
            ));
        }
        Ok(())
    }
}

/// Depth-first walk from the root that feeds leaves and tiles to the builder.
struct Walk<'a> {
    b: Bytes<'a>,
    upper: Region,
    lower: Region,
    leaves: Region,
    builder: GridBuilder,
    active: u64,
    /// Bounding box of the leaves, in leaf units.
    leaf_bounds: (IVec3, IVec3),
}

impl<'a> Walk<'a> {
    fn new(b: Bytes<'a>, tree: &TreeData, builder: GridBuilder) -> Parse<Self> {
        let [leaf, lower, upper, _] = tree.offsets;
        let [nleaf, nlower, nupper] = tree.counts;
        Ok(Walk {
            b,
            upper: Region::new(b, "upper", upper, nupper, UPPER.bytes)?,
            lower: Region::new(b, "lower", lower, nlower, LOWER.bytes)?,
            leaves: Region::new(b, "leaf", leaf, nleaf, LEAF_BYTES)?,
            builder,
            active: 0,
            leaf_bounds: (IVec3::MAX, IVec3::MIN),
        })
    }

    fn root(&mut self, root: u64) -> Parse<()> {
        let count = self.b.u32(root + 24)? as u64;
        self.b
            .slice(root + ROOT_HEADER, count * ROOT_TILE)
            .map_err(|m| format!("root table of {count} tiles: {m}"))?;
        let mut keys = HashSet::new();
        for i in 0..count {
            let t = root + ROOT_HEADER + i * ROOT_TILE;
            let key = self.b.u64(t)?;
            let origin = key_origin(key);
            // Keys that differ only in bits the origin ignores are repeats too.
            if !keys.insert(origin) {
                return Err(format!(
                    "root tile {i} repeats key {key:#x} (origin {origin})"
                ));
            }
            let child = self.b.i64(t + 8)?;
            if child != 0 {
                let pos = offset(root, child)?;
                self.upper.claim(pos)?;
                self.internal(pos, origin, &UPPER)?;
            } else {
                let active = self.b.u32(t + 16)? != 0;
                self.tile(origin, ROOT_TILE_LOG2, self.b.f32(t + 20)?, active);
            }
        }
        Ok(())
    }

    fn internal(&mut self, pos: u64, origin: IVec3, kind: &'static NodeKind) -> Parse<()> {
        check_node_origin(self.b, pos, origin, kind.log2_dim + kind.child_log2)?;
        let words = kind.mask_words();
        let values = self.b.words(pos + 32, words)?;
        let children = self.b.words(pos + 32 + 8 * words, words)?;
        let bit = |mask: &[u64], n: usize| mask[n / 64] >> (n % 64) & 1 == 1;
        let log2 = kind.log2_dim;
        let last = (1usize << log2) - 1;
        for n in 0..1usize << (3 * log2) {
            let entry = pos + kind.table + 8 * n as u64;
            let local = IVec3::new(
                (n >> (2 * log2)) as i32,
                ((n >> log2) & last) as i32,
                (n & last) as i32,
            );
            let at = origin + (local << kind.child_log2 as i32);
            if bit(&children, n) {
                let child = offset(pos, self.b.i64(entry)?)?;
                self.child(child, at, kind)?;
            } else {
                self.tile(at, kind.child_log2, self.b.f32(entry)?, bit(&values, n));
            }
        }
        Ok(())
    }

    fn child(&mut self, pos: u64, origin: IVec3, parent: &'static NodeKind) -> Parse<()> {
        match parent.child {
            Some(kind) => {
                self.lower.claim(pos)?;
                self.internal(pos, origin, kind)
            }
            None => {
                self.leaves.claim(pos)?;
                self.leaf(pos, origin)
            }
        }
    }

    fn leaf(&mut self, pos: u64, origin: IVec3) -> Parse<()> {
        let stored = self.b.ivec3(pos)? & IVec3::splat(!7);
        if stored != origin {
            return Err(format!(
                "leaf at byte {pos} has origin {stored}, its parent puts it at {origin}"
            ));
        }
        let mut leaf = Leaf {
            values: [0.0; 512],
            active: [0; 8],
        };
        let raw = self.b.slice(pos + LEAF_VALUES, 512 * 4)?;
        for (v, c) in leaf.values.iter_mut().zip(raw.chunks_exact(4)) {
            *v = f32::from_le_bytes([c[0], c[1], c[2], c[3]]);
        }
        leaf.active
            .copy_from_slice(&self.b.words(pos + LEAF_MASK, 8)?);
        self.active += leaf
            .active
            .iter()
            .map(|w| w.count_ones() as u64)
            .sum::<u64>();
        let key = origin >> 3;
        self.leaf_bounds = (self.leaf_bounds.0.min(key), self.leaf_bounds.1.max(key));
        self.builder.leaf(origin, leaf);
        Ok(())
    }

    /// A constant cube of edge `1 << log2`; inactive background tiles carry no information.
    fn tile(&mut self, origin: IVec3, log2: u32, value: f32, active: bool) {
        if active {
            self.active = self.active.saturating_add(1u64 << (3 * log2));
        }
        if active || value != self.builder.background {
            let max = origin + IVec3::splat((1 << log2) - 1);
            self.builder.tile(Tile {
                min: origin,
                max,
                value,
                active,
            });
        }
    }

    fn finish(self, tree: &TreeData) -> Parse<Grid> {
        self.upper.check_all_seen()?;
        self.lower.check_all_seen()?;
        self.leaves.check_all_seen()?;
        if self.active != tree.active_voxels {
            return Err(format!(
                "{} active voxels in the tree, its header says {}",
                self.active, tree.active_voxels
            ));
        }
        check_leaf_spread(self.leaf_bounds, self.b.len())?;
        Ok(self.builder.finish())
    }
}

/// An internal node's bbox starts inside the node (NanoVDB derives the origin from it);
/// an empty bbox (a node without active values) says nothing.
fn check_node_origin(b: Bytes, pos: u64, origin: IVec3, log2_span: u32) -> Parse<()> {
    let (min, max) = (b.ivec3(pos)?, b.ivec3(pos + 12)?);
    let stored = min & IVec3::splat(!((1 << log2_span) - 1));
    if min.cmple(max).all() && stored != origin {
        return Err(format!(
            "node at byte {pos} has origin {stored}, its parent puts it at {origin}"
        ));
    }
    Ok(())
}

fn check_leaf_spread((lo, hi): (IVec3, IVec3), buffer_len: u64) -> Parse<()> {
    if lo.cmpgt(hi).any() {
        return Ok(());
    }
    let d = (hi.as_i64vec3() - lo.as_i64vec3()) + 1;
    let slots = (d.x as u64)
        .saturating_mul(d.y as u64)
        .saturating_mul(d.z as u64);
    let limit = MAX_LEAF_SLOTS.min(MIN_LEAF_SLOTS.max(buffer_len.saturating_mul(4)));
    if slots > limit {
        return Err(format!(
            "leaves spread over {} x {} x {} leaf slots, too sparse to load (limit {limit} for a {buffer_len}-byte grid)",
            d.x, d.y, d.z
        ));
    }
    Ok(())
}

/// Origin of a root tile from its key: the three coordinates shifted down by 12 bits,
/// packed 21 bits each as x|y|z from the high end (NanoVDB's single 64-bit root key).
fn key_origin(key: u64) -> IVec3 {
    let part =
        |shift: u32| (((key >> shift) & 0x1f_ffff) as u32).wrapping_shl(ROOT_TILE_LOG2) as i32;
    IVec3::new(part(42), part(21), part(0))
}
