//! The `Tree_float_5_4_3` tree: the topology (root tiles and children, internal nodes with
//! child and value masks and their tile values, leaf value masks), then the leaf value
//! buffers in the same depth-first order.
use super::bytes::{bit, Parse, Reader};
use super::values::{read_node_values, Storage};
use crate::media::grid::{GridBuilder, Leaf, Tile};
use glam::IVec3;
use std::collections::HashSet;

/// log2 of the side of the root's children (upper internal nodes), in voxels.
const ROOT_CHILD_LOG2: i32 = 12;
/// Smallest possible encoding of a root child: its origin, an upper node's two 4096-byte
/// masks and one metadata byte.
const MIN_UPPER_NODE_BYTES: u64 = 12 + 2 * 4096 + 1;
const ROOT_TILE_BYTES: u64 = 12 + 4 + 1;

/// The leaf lookup table in [`crate::media::grid::Grid`] is dense over the leaves' bounding
/// box; this caps it (in slots) for files whose leaves are few but far apart.
const MIN_TABLE_SLOTS: u64 = 1 << 22;

struct PendingLeaf {
    origin: IVec3,
    mask: [u64; 8],
}

/// Reads one tree into a [`GridBuilder`]: [`Self::read_topology`] from the tree's start,
/// then [`Self::read_buffers`] from the first leaf buffer.
pub struct TreeReader<'r, 'a> {
    r: &'r mut Reader<'a>,
    storage: Storage,
    /// Leaves met in the topology, in buffer order.
    leaves: Vec<PendingLeaf>,
    tiles: usize,
    /// Bounds the tiles a corrupt file can make (tiles are merged, so real files have few).
    max_tiles: usize,
    /// Origins of the root's tiles and children met so far: the root is a map, so each
    /// origin appears once. Repeats would stack tiles over one region, and marking the
    /// leaf table under each of them is work the file's size does not bound.
    root_origins: HashSet<IVec3>,
}

impl<'r, 'a> TreeReader<'r, 'a> {
    pub fn new(r: &'r mut Reader<'a>, compression: u32, half: bool) -> Self {
        let max_tiles = 65_536 + r.len() / 8;
        TreeReader {
            r,
            storage: Storage {
                compression,
                half,
                background: 0.0,
            },
            leaves: Vec::new(),
            tiles: 0,
            max_tiles,
            root_origins: HashSet::new(),
        }
    }

    pub fn reader(&mut self) -> &mut Reader<'a> {
        self.r
    }

    /// Reads the topology, adding tiles to `b` and setting its background.
    pub fn read_topology(&mut self, b: &mut GridBuilder) -> Parse<()> {
        let buffers = self.r.i32("tree buffer count")?;
        if buffers != 1 {
            return Err(format!("tree has {buffers} buffers; only 1 is supported"));
        }
        let bg = self.r.f32("background")?;
        self.storage.background = bg;
        b.background = bg;
        let ntiles = self.r.u32("root tile count")?;
        let nchildren = self.r.u32("root child count")?;
        let need = ntiles as u64 * ROOT_TILE_BYTES + nchildren as u64 * MIN_UPPER_NODE_BYTES;
        if need > self.r.remaining() as u64 {
            return Err(format!(
                "root claims {ntiles} tiles and {nchildren} children, more than the {} bytes left",
                self.r.remaining()
            ));
        }
        for _ in 0..ntiles {
            self.read_root_tile(b)?;
        }
        for _ in 0..nchildren {
            let origin = self.root_origin("root child origin")?;
            self.read_internal(b, origin, 5)?;
        }
        check_leaf_table(&self.leaves, self.r.len())
    }

    fn root_origin(&mut self, what: &str) -> Parse<IVec3> {
        let at = self.r.pos();
        let o = IVec3::from(self.r.ivec3(what)?);
        if o & IVec3::splat((1 << ROOT_CHILD_LOG2) - 1) != IVec3::ZERO {
            return Err(format!(
                "{what} {o} at byte {at} is not a multiple of {}",
                1 << ROOT_CHILD_LOG2
            ));
        }
        if !self.root_origins.insert(o) {
            return Err(format!(
                "{what} {o} at byte {at} repeats an origin the root already has"
            ));
        }
        Ok(o)
    }

    fn read_root_tile(&mut self, b: &mut GridBuilder) -> Parse<()> {
        let origin = self.root_origin("root tile origin")?;
        let value = self.r.f32("root tile value")?;
        let active = self.r.u8("root tile state")? != 0;
        let size = IVec3::splat((1 << ROOT_CHILD_LOG2) - 1);
        self.add_tile(b, origin, origin + size, value, active)
    }

    fn add_tile(
        &mut self,
        b: &mut GridBuilder,
        min: IVec3,
        max: IVec3,
        value: f32,
        active: bool,
    ) -> Parse<()> {
        if !active && value == self.storage.background {
            return Ok(());
        }
        self.tiles += 1;
        if self.tiles > self.max_tiles {
            return Err(format!(
                "more than {} tiles, too many for a {}-byte file",
                self.max_tiles,
                self.r.len()
            ));
        }
        b.tile(Tile {
            min,
            max,
            value,
            active,
        });
        Ok(())
    }

    /// Reads an internal node with `2^log2` slots a side (5: upper, 4: lower).
    fn read_internal(&mut self, b: &mut GridBuilder, origin: IVec3, log2: i32) -> Parse<()> {
        let child_log2 = if log2 == 5 { 7 } else { 3 };
        let n = 1usize << (3 * log2);
        let child_mask = self.r.mask(n, "child mask")?;
        let value_mask = self.r.mask(n, "value mask")?;
        let values = read_node_values(self.r, &self.storage, &value_mask)
            .map_err(|e| format!("internal node at {origin}: {e}"))?;
        let slot = |i: usize| {
            let side = 1usize << log2;
            let (x, y, z) = (i / (side * side), (i / side) % side, i % side);
            origin + (IVec3::new(x as i32, y as i32, z as i32) << child_log2)
        };
        let bg = self.storage.background;
        let key = |i: usize| {
            let active = bit(&value_mask, i);
            let tile = !bit(&child_mask, i) && (active || values[i] != bg);
            tile.then(|| (values[i].to_bits(), active))
        };
        for (lo, hi, (bits, active)) in merge_slots(1 << log2, key) {
            let max = slot(hi) + IVec3::splat((1 << child_log2) - 1);
            self.add_tile(b, slot(lo), max, f32::from_bits(bits), active)?;
        }
        for i in (0..n).filter(|&i| bit(&child_mask, i)) {
            if log2 == 5 {
                self.read_internal(b, slot(i), 4)?;
            } else {
                let mask = self.r.mask(512, "leaf value mask")?;
                self.leaves.push(PendingLeaf {
                    origin: slot(i),
                    mask: mask.try_into().unwrap_or([0; 8]),
                });
            }
        }
        Ok(())
    }

    /// Reads the leaf buffers (value mask copy, then values) into `b`.
    pub fn read_buffers(&mut self, b: &mut GridBuilder) -> Parse<()> {
        b.reserve_leaves(self.leaves.len());
        for leaf in std::mem::take(&mut self.leaves) {
            self.r.mask(512, "leaf buffer value mask")?;
            let values = read_node_values(self.r, &self.storage, &leaf.mask)
                .map_err(|e| format!("leaf at {}: {e}", leaf.origin))?;
            let values: [f32; 512] = values
                .try_into()
                .map_err(|_| format!("leaf at {}: wrong value count", leaf.origin))?;
            b.leaf(
                leaf.origin,
                Leaf {
                    values,
                    active: leaf.mask,
                },
            );
        }
        Ok(())
    }
}

/// Greedy box merge of equal tile slots in a `side`³ node (slot index (x·side + y)·side + z):
/// grows each box along z, then y, then x. Returns (first slot, last slot, key) per box.
fn merge_slots<K: PartialEq + Copy>(
    side: usize,
    key: impl Fn(usize) -> Option<K>,
) -> Vec<(usize, usize, K)> {
    let idx = |x: usize, y: usize, z: usize| (x * side + y) * side + z;
    let keys: Vec<Option<K>> = (0..side * side * side).map(key).collect();
    let mut used = vec![false; keys.len()];
    let mut boxes = Vec::new();
    for start in 0..keys.len() {
        let Some(k) = keys[start].filter(|_| !used[start]) else {
            continue;
        };
        let (x0, y0, z0) = (start / (side * side), (start / side) % side, start % side);
        let free = |x, y, z, used: &[bool]| !used[idx(x, y, z)] && keys[idx(x, y, z)] == Some(k);
        let mut z1 = z0;
        while z1 + 1 < side && free(x0, y0, z1 + 1, &used) {
            z1 += 1;
        }
        let mut y1 = y0;
        while y1 + 1 < side && (z0..=z1).all(|z| free(x0, y1 + 1, z, &used)) {
            y1 += 1;
        }
        let mut x1 = x0;
        while x1 + 1 < side && (y0..=y1).all(|y| (z0..=z1).all(|z| free(x1 + 1, y, z, &used))) {
            x1 += 1;
        }
        for x in x0..=x1 {
            for y in y0..=y1 {
                for z in z0..=z1 {
                    used[idx(x, y, z)] = true;
                }
            }
        }
        boxes.push((start, idx(x1, y1, z1), k));
    }
    boxes
}

/// Rejects leaf layouts whose dense lookup table would be far larger than the file.
fn check_leaf_table(leaves: &[PendingLeaf], file_len: usize) -> Parse<()> {
    let Some(first) = leaves.first() else {
        return Ok(());
    };
    let (lo, hi) = leaves
        .iter()
        .fold((first.origin, first.origin), |(lo, hi), l| {
            (lo.min(l.origin), hi.max(l.origin))
        });
    let span = (hi.as_i64vec3() - lo.as_i64vec3()) / 8 + 1;
    let slots = (span.x as u64)
        .saturating_mul(span.y as u64)
        .saturating_mul(span.z as u64);
    let limit = MIN_TABLE_SLOTS.max(4 * file_len as u64);
    if slots > limit {
        return Err(format!(
            "leaves span {} x {} x {} leaf slots ({lo} to {hi}), over the limit of {limit} for a {file_len}-byte file",
            span.x, span.y, span.z
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn merges_equal_slots_into_boxes() {
        // 4³ slots: a 2x2x4 block of key 1, one lone key 2, the rest empty.
        let key = |i: usize| {
            let (x, y, z) = (i / 16, (i / 4) % 4, i % 4);
            if x < 2 && y < 2 {
                Some(1)
            } else if (x, y, z) == (3, 3, 3) {
                Some(2)
            } else {
                None
            }
        };
        let boxes = merge_slots(4, key);
        assert_eq!(boxes, vec![(0, (4 + 1) * 4 + 3, 1), (63, 63, 2)]);
    }
}
