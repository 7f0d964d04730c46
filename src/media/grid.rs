//! The density grid every source (OpenVDB, NanoVDB, procedural) produces.
//!
//! Sparse: values live in 8^3 leaves, found through a table of leaf slots over the bounding
//! box of the leaves (one u32 per 512 voxels), so empty space costs 4 bytes per leaf slot
//! and a lookup is two array reads. Each leaf is stored as a 9^3 brick: its 8^3 voxels and
//! a copy of the voxels one step past its upper faces (the apron), so that the 8 corners of
//! any trilinear cell starting in a leaf are in one brick: one table read and no branch per
//! corner, where a cell across leaf slots (a third of them) used to cost eight table reads.
//! The apron costs 42 % more memory per leaf.
//! Constant regions (VDB tiles) are stored as boxes; the table's slots that a tile covers
//! whole name it, so a lookup inside a tile (a cloud's dense core) is as cheap as one in a
//! leaf.
//! Values sit at voxel centres: voxel (i,j,k) is at `index_to_world * (i,j,k)` (the VDB
//! convention); between voxels the field is trilinear; outside leaves and tiles it is
//! `background`.
use glam::{DAffine3, DVec3, IVec3, Vec3};
use std::collections::HashMap;

/// Leaf edge length in voxels.
pub const LEAF: i32 = 8;
const LEAF_VOXELS: usize = 512;
/// Brick edge length: a leaf and its apron.
const BRICK: i32 = LEAF + 1;
const BRICK_VOXELS: usize = (BRICK * BRICK * BRICK) as usize;
/// A table slot no leaf holds and no tile touches: background.
const EMPTY: u32 = u32::MAX;
/// A table slot no leaf holds that a tile covers in part: search the tiles.
pub const SEARCH_SLOT: u32 = u32::MAX - 1;
/// Table slots with this bit name a tile (index in the low bits), not a leaf.
pub const TILE_SLOT: u32 = 1 << 31;

/// What a leaf slot of the table holds.
enum Slot<'a> {
    Leaf(&'a Brick),
    Tile(f32),
    /// No leaf and no tile touches the slot.
    Background,
    /// Outside the table, or a slot a tile covers in part: search the tiles.
    Other,
}

#[derive(Clone, Debug)]
pub struct Leaf {
    /// Values in x-major order: index = (x * 8 + y) * 8 + z, as in OpenVDB and NanoVDB.
    pub values: [f32; LEAF_VOXELS],
    /// Active flags, bit n of word n / 64 for voxel n in the same order.
    pub active: [u64; 8],
}

/// A leaf's values in x-major order over 9^3 voxels, index = (x * 9 + y) * 9 + z: the
/// leaf's own 8^3 and, at x, y or z = 8, its upper neighbours' values (whatever holds them:
/// a leaf, a tile or the background), filled in by [`GridBuilder::finish`]. Aligned to a
/// cache line, so a cell's 8 corners span as few lines as the layout allows.
#[derive(Clone, Debug)]
#[repr(C, align(64))]
struct Brick([f32; BRICK_VOXELS]);

/// One leaf of a [`Grid`], as [`Grid::leaves`] hands it out.
#[derive(Clone, Copy)]
pub struct LeafRef<'a> {
    brick: &'a Brick,
    /// Active flags, bit n of word n / 64 for voxel n of [`Leaf`]'s order.
    pub active: &'a [u64; 8],
}

impl LeafRef<'_> {
    /// Value of voxel n in [`Leaf`]'s order, (x * 8 + y) * 8 + z.
    pub fn value(&self, n: usize) -> f32 {
        let n = n as i32;
        self.brick.0[brick_offset(IVec3::new(n / 64, (n / 8) % 8, n % 8))]
    }

    /// The 512 values in [`Leaf`]'s order.
    pub fn values(&self) -> impl Iterator<Item = f32> + '_ {
        (0..LEAF_VOXELS).map(|n| self.value(n))
    }
}

/// A constant box of voxels [min, max] (inclusive), e.g. an OpenVDB tile.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Tile {
    pub min: IVec3,
    pub max: IVec3,
    pub value: f32,
    pub active: bool,
}

/// Accumulates leaves and tiles; [`GridBuilder::finish`] makes the lookup table.
#[derive(Debug)]
pub struct GridBuilder {
    pub name: String,
    pub background: f32,
    pub index_to_world: DAffine3,
    /// Leaves in the order first added, as bricks from the start (aprons filled at the
    /// end); the grid keeps them where they are, so a grid of hundreds of megabytes is
    /// never held twice.
    bricks: Vec<Brick>,
    active: Vec<[u64; 8]>,
    leaf_origins: Vec<IVec3>,
    /// Leaf key -> position in `leaves`.
    slots: HashMap<IVec3, u32>,
    tiles: Vec<Tile>,
}

#[derive(Clone, Debug)]
pub struct Grid {
    pub name: String,
    pub background: f32,
    pub index_to_world: DAffine3,
    pub world_to_index: DAffine3,
    bricks: Vec<Brick>,
    /// Active flags of each brick's leaf.
    active: Vec<[u64; 8]>,
    /// Leaf origins (in voxels) in the order of `bricks`.
    leaf_origins: Vec<IVec3>,
    tiles: Vec<Tile>,
    /// Leaf-slot table over [table_min, table_min + table_dim) in leaf units.
    table: Vec<u32>,
    table_min: IVec3,
    table_dim: IVec3,
}

#[inline(always)]
fn leaf_offset(local: IVec3) -> usize {
    ((local.x * LEAF + local.y) * LEAF + local.z) as usize
}

#[inline(always)]
fn brick_offset(local: IVec3) -> usize {
    ((local.x * BRICK + local.y) * BRICK + local.z) as usize
}

/// The leaf holding voxel `ijk`: floor division by 8, an arithmetic shift.
#[inline(always)]
fn leaf_key(ijk: IVec3) -> IVec3 {
    ijk >> LEAF.trailing_zeros() as i32
}

impl GridBuilder {
    pub fn new(name: impl Into<String>, background: f32, index_to_world: DAffine3) -> Self {
        GridBuilder {
            name: name.into(),
            background,
            index_to_world,
            bricks: Vec::new(),
            active: Vec::new(),
            leaf_origins: Vec::new(),
            slots: HashMap::new(),
            tiles: Vec::new(),
        }
    }

    /// Room for `n` more leaves, allocated once (and on 2 MiB pages) when a reader knows
    /// the count before the values.
    pub fn reserve_leaves(&mut self, n: usize) {
        if self.bricks.capacity() - self.bricks.len() < n {
            let mut v = Vec::with_capacity(self.bricks.len() + n);
            advise_huge_pages(&v);
            v.append(&mut self.bricks);
            self.bricks = v;
        }
        self.active.reserve(n);
        self.leaf_origins.reserve(n);
        self.slots.reserve(n);
    }

    /// Adds (or replaces) the leaf whose first voxel is `origin` (a multiple of 8).
    pub fn leaf(&mut self, origin: IVec3, leaf: Leaf) {
        let i = self.leaf_index(leaf_key(origin));
        let brick = &mut self.bricks[i].0;
        for (x, plane) in leaf.values.chunks_exact(64).enumerate() {
            for (y, row) in plane.chunks_exact(8).enumerate() {
                let at = brick_offset(IVec3::new(x as i32, y as i32, 0));
                brick[at..at + 8].copy_from_slice(row);
            }
        }
        self.active[i] = leaf.active;
    }

    /// Index of the leaf of key `k`, created (background, inactive) if new.
    fn leaf_index(&mut self, k: IVec3) -> usize {
        let next = self.bricks.len() as u32;
        let i = *self.slots.entry(k).or_insert(next);
        if i == next {
            self.bricks.push(Brick([self.background; BRICK_VOXELS]));
            self.active.push([0; 8]);
            self.leaf_origins.push(k * LEAF);
        }
        i as usize
    }

    /// Sets one voxel, creating its leaf (filled with background, inactive) if needed.
    pub fn set(&mut self, ijk: IVec3, value: f32, active: bool) {
        let i = self.leaf_index(leaf_key(ijk));
        let local = ijk - leaf_key(ijk) * LEAF;
        self.bricks[i].0[brick_offset(local)] = value;
        let (n, flags) = (leaf_offset(local), &mut self.active[i]);
        if active {
            flags[n / 64] |= 1 << (n % 64);
        } else {
            flags[n / 64] &= !(1 << (n % 64));
        }
    }

    pub fn tile(&mut self, tile: Tile) {
        self.tiles.push(tile);
    }

    pub fn finish(self) -> Grid {
        let (table_min, table_dim) = if self.leaf_origins.is_empty() {
            (IVec3::ZERO, IVec3::ZERO)
        } else {
            let lo = self.slots.keys().fold(IVec3::MAX, |a, &k| a.min(k));
            let hi = self.slots.keys().fold(IVec3::MIN, |a, &k| a.max(k));
            (lo, hi - lo + 1)
        };
        let mut table =
            vec![EMPTY; (table_dim.x as usize) * (table_dim.y as usize) * (table_dim.z as usize)];
        for (k, &i) in &self.slots {
            let d = *k - table_min;
            table[((d.x * table_dim.y + d.y) * table_dim.z + d.z) as usize] = i;
        }
        mark_tiles(&mut table, table_min, table_dim, &self.tiles);
        let mut grid = Grid {
            name: self.name,
            background: self.background,
            world_to_index: self.index_to_world.inverse(),
            index_to_world: self.index_to_world,
            bricks: self.bricks,
            active: self.active,
            leaf_origins: self.leaf_origins,
            tiles: self.tiles,
            table,
            table_min,
            table_dim,
        };
        grid.fill_aprons();
        grid
    }
}

/// floor(x) as an i32, without the libm call that `f64::floor` is on baseline x86-64 (no
/// SSE4.1 rounding instruction): truncate, then step down for negative non-integers.
/// Saturates outside the i32 range, as `as` does.
#[inline(always)]
fn floor_i32(x: f64) -> i32 {
    let i = x as i32;
    i - ((i as f64) > x) as i32
}

/// Asks the kernel to back a large, still untouched allocation with 2 MiB pages. Lookups
/// land on random leaves of grids of hundreds of megabytes; with 4 KiB pages nearly every
/// one also misses the TLB (measured in `ppb bench-size`). Only a hint: ignored where
/// unsupported.
fn advise_huge_pages<T>(v: &Vec<T>) {
    #[cfg(target_os = "linux")]
    {
        const HUGE: usize = 2 << 20;
        let bytes = v.capacity() * std::mem::size_of::<T>();
        let start = v.as_ptr() as usize;
        let (a, b) = (start.next_multiple_of(HUGE), (start + bytes) / HUGE * HUGE);
        if b > a {
            // SAFETY: [a, b) lies inside the vector's own allocation; MADV_HUGEPAGE changes
            // no contents, only how the kernel backs the pages.
            unsafe {
                libc::madvise(a as *mut libc::c_void, b - a, libc::MADV_HUGEPAGE);
            }
        }
    }
}

/// Marks the table's empty slots that tiles touch: a slot whose 8^3 voxels one tile covers
/// whole names it, one it covers in part is searched. A voxel takes the value of the
/// first tile containing it, so each slot goes to the first tile that touches it. Slots no
/// tile touches stay empty, so a lookup in empty space needs no search of the tiles.
fn mark_tiles(table: &mut [u32], min: IVec3, dim: IVec3, tiles: &[Tile]) {
    for (k, t) in tiles.iter().enumerate().rev() {
        let lo = (leaf_key(t.min) - min).max(IVec3::ZERO);
        let hi = (leaf_key(t.max) - min).min(dim - 1);
        for x in lo.x..=hi.x {
            for y in lo.y..=hi.y {
                for z in lo.z..=hi.z {
                    let i = ((x * dim.y + y) * dim.z + z) as usize;
                    if table[i] != EMPTY && table[i] & TILE_SLOT == 0 {
                        continue;
                    }
                    let first = (IVec3::new(x, y, z) + min) * LEAF;
                    let whole = first.cmpge(t.min).all() && (first + LEAF - 1).cmple(t.max).all();
                    table[i] = if whole {
                        TILE_SLOT | k as u32
                    } else {
                        SEARCH_SLOT
                    };
                }
            }
        }
    }
}

/// Sets `out[at(v)] = value(v)` for every voxel v of the inclusive box [a, b].
fn fill_box(
    out: &mut [f32],
    a: IVec3,
    b: IVec3,
    at: &impl Fn(IVec3) -> usize,
    value: impl Fn(IVec3) -> f32,
) {
    for x in a.x..=b.x {
        for y in a.y..=b.y {
            for z in a.z..=b.z {
                let v = IVec3::new(x, y, z);
                out[at(v)] = value(v);
            }
        }
    }
}

impl Grid {
    // Inlined: called out of line, the IVec3 argument went through memory and its reload
    // stalled on store forwarding (a third of a lookup in `perf annotate`).
    #[inline(always)]
    fn slot(&self, ijk: IVec3) -> Slot<'_> {
        let d = leaf_key(ijk) - self.table_min;
        if d.cmplt(IVec3::ZERO).any() || d.cmpge(self.table_dim).any() {
            return Slot::Other;
        }
        match self.table[((d.x * self.table_dim.y + d.y) * self.table_dim.z + d.z) as usize] {
            EMPTY => Slot::Background,
            SEARCH_SLOT => Slot::Other,
            s if s & TILE_SLOT != 0 => Slot::Tile(self.tiles[(s & !TILE_SLOT) as usize].value),
            s => Slot::Leaf(&self.bricks[s as usize]),
        }
    }

    /// Position in `bricks` of the leaf holding voxel `ijk`.
    fn leaf_index(&self, ijk: IVec3) -> Option<usize> {
        let d = leaf_key(ijk) - self.table_min;
        if d.cmplt(IVec3::ZERO).any() || d.cmpge(self.table_dim).any() {
            return None;
        }
        let s = self.table[((d.x * self.table_dim.y + d.y) * self.table_dim.z + d.z) as usize];
        (s & TILE_SLOT == 0).then_some(s as usize)
    }

    /// Copies into each brick's apron the values of the voxels past its upper faces, read
    /// from the leaves' own voxels, tiles and background (never from another apron), as
    /// [`Self::value`] gives them: per upper neighbour slot (3 faces, 3 edges, a corner), a
    /// copy from its brick or its constant, one slot lookup each.
    fn fill_aprons(&mut self) {
        let mut part = [0f32; (LEAF * LEAF) as usize];
        for i in 0..self.bricks.len() {
            let origin = self.leaf_origins[i];
            for bits in 1..8 {
                // The neighbour one slot up along the set axes; along those the apron is
                // one voxel thick (the neighbour's first), along the others a whole leaf.
                let up = IVec3::new(bits & 1, bits >> 1 & 1, bits >> 2 & 1);
                let n = (1 - up) * (LEAF - 1) + 1;
                let next = origin + up * LEAF;
                let mut k = 0;
                let slot = self.slot(next);
                for x in 0..n.x {
                    for y in 0..n.y {
                        for z in 0..n.z {
                            let local = IVec3::new(x, y, z);
                            part[k] = match slot {
                                Slot::Leaf(b) => b.0[brick_offset(local)],
                                Slot::Tile(v) => v,
                                Slot::Background => self.background,
                                Slot::Other => self.value(next + local),
                            };
                            k += 1;
                        }
                    }
                }
                let brick = &mut self.bricks[i].0;
                let mut values = part[..k].iter();
                for x in 0..n.x {
                    for y in 0..n.y {
                        for z in 0..n.z {
                            let at = brick_offset(IVec3::new(x, y, z) + up * LEAF);
                            brick[at] = *values.next().expect("one value per apron voxel");
                        }
                    }
                }
            }
        }
    }

    fn tile_at(&self, ijk: IVec3) -> Option<&Tile> {
        self.tiles
            .iter()
            .find(|t| ijk.cmpge(t.min).all() && ijk.cmple(t.max).all())
    }

    /// Value of voxel `ijk` (background outside leaves and tiles).
    #[inline(always)]
    pub fn value(&self, ijk: IVec3) -> f32 {
        match self.slot(ijk) {
            Slot::Leaf(b) => b.0[brick_offset(ijk - leaf_key(ijk) * LEAF)],
            Slot::Tile(v) => v,
            Slot::Background => self.background,
            Slot::Other => self.tile_at(ijk).map_or(self.background, |t| t.value),
        }
    }

    /// Voxel values of the inclusive index box [lo, hi] into `out`, x slowest:
    /// `out[((x * ny) + y) * nz + z]` for the box's local (x, y, z). One table read per leaf
    /// slot the box touches instead of one per voxel, so bounding a region costs about
    /// its voxel count.
    ///
    /// Returns false, leaving `out` empty, when the box holds nothing but background: a
    /// box in empty space costs a few table reads, not its voxel count.
    pub fn fill_block(&self, lo: IVec3, hi: IVec3, out: &mut Vec<f32>) -> bool {
        out.clear();
        let n = (hi - lo + 1).max(IVec3::ZERO);
        if n.cmple(IVec3::ZERO).any() || self.only_background(lo, hi) {
            return false;
        }
        out.resize((n.x * n.y * n.z) as usize, self.background);
        let (klo, khi) = (leaf_key(lo), leaf_key(hi));
        for kx in klo.x..=khi.x {
            for ky in klo.y..=khi.y {
                for kz in klo.z..=khi.z {
                    let first = IVec3::new(kx, ky, kz) * LEAF;
                    let (a, b) = (first.max(lo), (first + LEAF - 1).min(hi));
                    let at = |v: IVec3| {
                        let d = v - lo;
                        ((d.x * n.y + d.y) * n.z + d.z) as usize
                    };
                    match self.slot(first) {
                        Slot::Leaf(l) => {
                            for x in a.x..=b.x {
                                for y in a.y..=b.y {
                                    let src = brick_offset(IVec3::new(x, y, a.z) - first);
                                    let dst = at(IVec3::new(x, y, a.z));
                                    let len = (b.z - a.z + 1) as usize;
                                    out[dst..dst + len].copy_from_slice(&l.0[src..src + len]);
                                }
                            }
                        }
                        Slot::Tile(v) => fill_box(out, a, b, &at, |_| v),
                        Slot::Background => {}
                        Slot::Other if self.tiles.is_empty() => {}
                        Slot::Other => fill_box(out, a, b, &at, |v| {
                            self.tile_at(v).map_or(self.background, |t| t.value)
                        }),
                    }
                }
            }
        }
        true
    }

    /// Whether every voxel of the inclusive box [lo, hi] is background: no leaf slot of the
    /// table inside it is used (a grid with tiles is never taken as empty here).
    fn only_background(&self, lo: IVec3, hi: IVec3) -> bool {
        if !self.tiles.is_empty() {
            return false;
        }
        let dim = self.table_dim;
        let a = (leaf_key(lo) - self.table_min).max(IVec3::ZERO);
        let b = (leaf_key(hi) - self.table_min).min(dim - 1);
        if a.cmpgt(b).any() {
            return true; // the box misses the table: no leaf there
        }
        for x in a.x..=b.x {
            for y in a.y..=b.y {
                let row = ((x * dim.y + y) * dim.z) as usize;
                let slots = &self.table[row + a.z as usize..=row + b.z as usize];
                if slots.iter().any(|&e| e != EMPTY) {
                    return false;
                }
            }
        }
        true
    }

    /// Whether voxel `ijk` is active.
    pub fn is_active(&self, ijk: IVec3) -> bool {
        if let Some(i) = self.leaf_index(ijk) {
            let n = leaf_offset(ijk - leaf_key(ijk) * LEAF);
            return self.active[i][n / 64] >> (n % 64) & 1 == 1;
        }
        self.tile_at(ijk).is_some_and(|t| t.active)
    }

    /// Trilinear interpolation at continuous index-space position `p` (voxel centres at
    /// integer coordinates).
    #[inline]
    pub fn sample_index(&self, p: DVec3) -> f32 {
        let i = IVec3::new(floor_i32(p.x), floor_i32(p.y), floor_i32(p.z));
        let t = (p - i.as_dvec3()).as_vec3();
        let local = i - leaf_key(i) * LEAF;
        // A constant slot is the cell's value only if the cell does not reach past it.
        let inside = local.cmplt(IVec3::splat(LEAF - 1)).all();
        match self.slot(i) {
            Slot::Leaf(b) => {
                let o = brick_offset(local);
                let v = |d: usize| b.0[o + d];
                let (dx, dy, dz) = ((BRICK * BRICK) as usize, BRICK as usize, 1usize);
                let lerp = |a: f32, b: f32, t: f32| a + (b - a) * t;
                let x00 = lerp(v(0), v(dx), t.x);
                let x10 = lerp(v(dy), v(dx + dy), t.x);
                let x01 = lerp(v(dz), v(dx + dz), t.x);
                let x11 = lerp(v(dy + dz), v(dx + dy + dz), t.x);
                return lerp(lerp(x00, x10, t.y), lerp(x01, x11, t.y), t.z);
            }
            Slot::Tile(v) if inside => return v,
            Slot::Background if inside => return self.background,
            _ => {}
        }
        let v = |dx, dy, dz| self.value(i + IVec3::new(dx, dy, dz));
        let lerp = |a: f32, b: f32, t: f32| a + (b - a) * t;
        let x00 = lerp(v(0, 0, 0), v(1, 0, 0), t.x);
        let x10 = lerp(v(0, 1, 0), v(1, 1, 0), t.x);
        let x01 = lerp(v(0, 0, 1), v(1, 0, 1), t.x);
        let x11 = lerp(v(0, 1, 1), v(1, 1, 1), t.x);
        lerp(lerp(x00, x10, t.y), lerp(x01, x11, t.y), t.z)
    }

    /// Trilinear value at world position `p`.
    pub fn sample_world(&self, p: Vec3) -> f32 {
        self.sample_index(self.world_to_index.transform_point3(p.as_dvec3()))
    }

    /// The leaf-slot table (`u32::MAX` = no leaf and no tile touching the slot;
    /// [`SEARCH_SLOT`] = no leaf, a tile covering the slot in part; [`TILE_SLOT`] | k =
    /// inside tile k; else an index into [`Self::leaves`] order), its minimum leaf key and
    /// its size in leaves, x-major.
    pub fn leaf_table(&self) -> (&[u32], IVec3, IVec3) {
        (&self.table, self.table_min, self.table_dim)
    }

    pub fn leaf_count(&self) -> usize {
        self.bricks.len()
    }

    pub fn tiles(&self) -> &[Tile] {
        &self.tiles
    }

    /// Leaves with their first voxel, in a fixed order.
    pub fn leaves(&self) -> impl Iterator<Item = (IVec3, LeafRef<'_>)> {
        let refs = self
            .bricks
            .iter()
            .zip(&self.active)
            .map(|(brick, active)| LeafRef { brick, active });
        self.leaf_origins.iter().copied().zip(refs)
    }

    /// Number of active voxels (leaf voxels plus active tile volumes).
    pub fn active_voxels(&self) -> u64 {
        let in_leaves: u64 = self
            .active
            .iter()
            .map(|a| a.iter().map(|w| w.count_ones() as u64).sum::<u64>())
            .sum();
        let in_tiles: u64 = self
            .tiles
            .iter()
            .filter(|t| t.active)
            .map(|t| {
                let d = (t.max - t.min + 1).as_i64vec3();
                (d.x * d.y * d.z) as u64
            })
            .sum();
        in_leaves + in_tiles
    }

    /// Inclusive index bounding box of the active voxels, if any.
    pub fn active_bbox(&self) -> Option<(IVec3, IVec3)> {
        let mut lo = IVec3::MAX;
        let mut hi = IVec3::MIN;
        for (origin, leaf) in self.leaves() {
            for n in 0..LEAF_VOXELS {
                if leaf.active[n / 64] >> (n % 64) & 1 == 1 {
                    let n = n as i32;
                    let p = origin + IVec3::new(n / 64, (n / 8) % 8, n % 8);
                    lo = lo.min(p);
                    hi = hi.max(p);
                }
            }
        }
        for t in self.tiles.iter().filter(|t| t.active) {
            lo = lo.min(t.min);
            hi = hi.max(t.max);
        }
        (lo.x <= hi.x).then_some((lo, hi))
    }

    /// (min, max, mean) over the active voxels (tiles weighted by their volume).
    pub fn active_stats(&self) -> Option<(f32, f32, f64)> {
        let (mut lo, mut hi, mut sum, mut n) = (f32::MAX, f32::MIN, 0.0f64, 0u64);
        for (_, leaf) in self.leaves() {
            for (i, v) in leaf.values().enumerate() {
                if leaf.active[i / 64] >> (i % 64) & 1 == 1 {
                    lo = lo.min(v);
                    hi = hi.max(v);
                    sum += v as f64;
                    n += 1;
                }
            }
        }
        for t in self.tiles.iter().filter(|t| t.active) {
            let d = (t.max - t.min + 1).as_i64vec3();
            let count = (d.x * d.y * d.z) as u64;
            lo = lo.min(t.value);
            hi = hi.max(t.value);
            sum += t.value as f64 * count as f64;
            n += count;
        }
        (n > 0).then(|| (lo, hi, sum / n as f64))
    }

    /// Bytes held by the grid's data structures.
    pub fn memory_bytes(&self) -> usize {
        self.bricks.len() * (std::mem::size_of::<Brick>() + std::mem::size_of::<[u64; 8]>())
            + self.leaf_origins.len() * std::mem::size_of::<IVec3>()
            + self.table.len() * 4
            + self.tiles.len() * std::mem::size_of::<Tile>()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sparse_lookup_and_trilinear() {
        let mut b = GridBuilder::new("density", 0.0, DAffine3::IDENTITY);
        b.set(IVec3::new(-1, 0, 0), 1.0, true);
        b.set(IVec3::new(0, 0, 0), 3.0, true);
        b.tile(Tile {
            min: IVec3::new(16, 16, 16),
            max: IVec3::new(23, 23, 23),
            value: 2.0,
            active: true,
        });
        let g = b.finish();
        assert_eq!(g.value(IVec3::new(-1, 0, 0)), 1.0);
        assert_eq!(g.value(IVec3::new(0, 0, 0)), 3.0);
        assert_eq!(g.value(IVec3::new(20, 17, 23)), 2.0);
        assert_eq!(g.value(IVec3::new(100, 0, 0)), 0.0);
        assert!(g.is_active(IVec3::new(0, 0, 0)) && !g.is_active(IVec3::new(1, 0, 0)));
        assert_eq!(g.active_voxels(), 2 + 512);
        assert!((g.sample_index(DVec3::new(-0.25, 0.0, 0.0)) - 2.5).abs() < 1e-6);
        assert!((g.sample_index(DVec3::new(0.0, 0.5, 0.0)) - 1.5).abs() < 1e-6);
    }

    /// Trilinear samples in cells across 2, 4 and 8 leaf slots (leaves, tiles, partial
    /// tiles, background, outside the table) equal the corner-by-corner formula on
    /// `value` bit for bit.
    #[test]
    fn trilinear_across_leaf_slots_reads_each_corner_as_value() {
        let mut b = GridBuilder::new("density", 0.25, DAffine3::IDENTITY);
        for x in -3..20 {
            for y in -3..12 {
                b.set(
                    IVec3::new(x, y, (x * 7 + y * 3) % 17),
                    (x + 2 * y) as f32 * 0.1,
                    true,
                );
            }
        }
        b.tile(Tile {
            min: IVec3::new(16, 0, 0),
            max: IVec3::new(27, 11, 7),
            value: 2.0,
            active: true,
        });
        let g = b.finish();
        let mut rng = crate::sampling::Rng::new(3, 1);
        let lerp = |a: f32, b: f32, t: f32| a + (b - a) * t;
        let mut across = 0;
        for _ in 0..20_000 {
            let u = DVec3::new(rng.f32() as f64, rng.f32() as f64, rng.f32() as f64);
            let p = DVec3::new(-12.0, -12.0, -4.0) + u * DVec3::new(44.0, 30.0, 26.0);
            let i = IVec3::new(floor_i32(p.x), floor_i32(p.y), floor_i32(p.z));
            let t = (p - i.as_dvec3()).as_vec3();
            let v = |dx, dy, dz| g.value(i + IVec3::new(dx, dy, dz));
            let x00 = lerp(v(0, 0, 0), v(1, 0, 0), t.x);
            let x10 = lerp(v(0, 1, 0), v(1, 1, 0), t.x);
            let x01 = lerp(v(0, 0, 1), v(1, 0, 1), t.x);
            let x11 = lerp(v(0, 1, 1), v(1, 1, 1), t.x);
            let want = lerp(lerp(x00, x10, t.y), lerp(x01, x11, t.y), t.z);
            assert_eq!(g.sample_index(p).to_bits(), want.to_bits(), "{p}");
            across += (i - leaf_key(i) * LEAF).cmpeq(IVec3::splat(LEAF - 1)).any() as u32;
        }
        assert!(across > 4000, "{across} samples across slots");
    }

    /// Tiles inside the table's span (whole slots, a part of a slot, overlapping ones)
    /// give every voxel the value of the first tile containing it, as a search would, and
    /// trilinear samples inside a tile are its value.
    #[test]
    fn tile_slots_keep_the_first_tile_rule() {
        let mut b = GridBuilder::new("density", 0.5, DAffine3::IDENTITY);
        b.set(IVec3::new(0, 0, 0), 1.0, true);
        b.set(IVec3::new(40, 40, 40), 1.0, true);
        let tiles = [
            (IVec3::new(8, 8, 8), IVec3::new(23, 15, 15), 2.0),
            (IVec3::new(16, 8, 8), IVec3::new(31, 31, 31), 3.0),
            (IVec3::new(3, 3, 3), IVec3::new(12, 12, 12), 4.0),
            (IVec3::new(24, 24, 24), IVec3::new(31, 31, 31), 5.0),
        ];
        for (min, max, value) in tiles {
            b.tile(Tile {
                min,
                max,
                value,
                active: true,
            });
        }
        let g = b.finish();
        let search = |ijk: IVec3| {
            if let Some(i) = g.leaf_index(ijk) {
                return g.bricks[i].0[brick_offset(ijk - leaf_key(ijk) * LEAF)];
            }
            g.tile_at(ijk).map_or(g.background, |t| t.value)
        };
        let (mut marked, mut background) = (0, 0);
        for x in -2..50 {
            for y in -2..50 {
                for z in -2..50 {
                    let ijk = IVec3::new(x, y, z);
                    assert_eq!(g.value(ijk), search(ijk), "{ijk}");
                    marked += matches!(g.slot(ijk), Slot::Tile(_)) as u32;
                    background += matches!(g.slot(ijk), Slot::Background) as u32;
                }
            }
        }
        assert!(marked > 0, "no slot names a tile");
        assert!(background > 0, "no slot is known to be background");
        assert_eq!(g.value(IVec3::new(20, 10, 10)), 2.0);
        assert_eq!(g.value(IVec3::new(26, 26, 26)), 3.0);
        assert_eq!(g.sample_index(DVec3::new(17.3, 9.5, 10.2)), 2.0);
        // Without tiles, a box in empty space is reported as background and not filled.
        let mut b2 = GridBuilder::new("density", 0.0, DAffine3::IDENTITY);
        b2.set(IVec3::new(3, 3, 3), 1.0, true);
        b2.set(IVec3::new(100, 3, 3), 1.0, true);
        let g2 = b2.finish();
        let mut block = Vec::new();
        assert!(!g2.fill_block(IVec3::new(20, 0, 0), IVec3::new(90, 7, 7), &mut block));
        assert!(block.is_empty());
        assert!(!g2.fill_block(
            IVec3::new(-50, -50, -50),
            IVec3::new(-1, 40, 40),
            &mut block
        ));
        assert!(g2.fill_block(IVec3::new(0, 0, 0), IVec3::new(9, 9, 9), &mut block));
        assert_eq!(block[(3 * 10 + 3) * 10 + 3], 1.0);
        // Blocks across leaves, tiles, partial tiles and empty space read as `value` does.
        for (lo, hi) in [
            (IVec3::new(-3, -3, -3), IVec3::new(45, 44, 43)),
            (IVec3::new(5, 7, 9), IVec3::new(17, 9, 26)),
            (IVec3::new(40, 40, 40), IVec3::new(40, 40, 40)),
        ] {
            assert!(g.fill_block(lo, hi, &mut block));
            let n = hi - lo + 1;
            for x in 0..n.x {
                for y in 0..n.y {
                    for z in 0..n.z {
                        let v = block[((x * n.y + y) * n.z + z) as usize];
                        assert_eq!(v, g.value(lo + IVec3::new(x, y, z)), "{lo} + {x},{y},{z}");
                    }
                }
            }
        }
    }
}
