//! The file container: segments (header, per-grid metadata and names, then the stored grid
//! buffers), or from NanoVDB 32.6 on also a bare sequence of grid buffers.
use super::bytes::{Bytes, Parse};
use super::{
    tree, version, Codec, GridClass, GridMetaData, GridType, Version, MAGIC_GRID, MAGIC_NUMB,
};

const MAGIC_FILE: u64 = u64::from_le_bytes(*b"NanoVDB2");
const OPENVDB_MAGIC: u32 = 0x5644_4220;
const HEADER_BYTES: u64 = 16;
const META_BYTES: u64 = 176;
/// Deflate cannot expand data by more than about 1032:1.
const ZIP_RATIO: u64 = 1032;
/// LZ4 (blosc's inner codec) cannot expand data by more than about 255:1.
const BLOSC_RATIO: u64 = 256;
const RATIO_SLACK: u64 = 4096;

/// One grid: what the file says about it and where its stored bytes start.
pub(super) struct Entry {
    pub info: GridMetaData,
    pub offset: u64,
}

pub(super) fn entries(b: Bytes) -> Parse<Vec<Entry>> {
    let magic = b
        .u64(0)
        .map_err(|_| format!("{} bytes is too short for a NanoVDB file", b.len()))?;
    match magic {
        MAGIC_NUMB | MAGIC_FILE => segments(b),
        MAGIC_GRID => raw_grids(b),
        m if [MAGIC_NUMB, MAGIC_GRID, MAGIC_FILE].contains(&m.swap_bytes()) => {
            Err("big-endian NanoVDB files are not supported".into())
        }
        m if m as u32 == OPENVDB_MAGIC => Err("this is an OpenVDB file, not NanoVDB".into()),
        m => Err(format!("not a NanoVDB file (magic {m:#018x})")),
    }
}

fn segments(b: Bytes) -> Parse<Vec<Entry>> {
    let mut out = Vec::new();
    let mut pos = 0;
    while pos < b.len() {
        pos = segment(b, pos, &mut out).map_err(|m| format!("segment at byte {pos}: {m}"))?;
    }
    Ok(out)
}

/// Reads the segment at `pos` into `out` and returns where the next one starts.
fn segment(b: Bytes, pos: u64, out: &mut Vec<Entry>) -> Parse<u64> {
    let magic = b.u64(pos)?;
    if magic != MAGIC_NUMB && magic != MAGIC_FILE {
        return Err(format!("bad segment magic {magic:#018x}"));
    }
    let version = version(b.u32(pos + 8)?)?;
    let count = b.u16(pos + 12)?;
    let codec = codec(b.u16(pos + 14)?)?;
    if count == 0 {
        return Err("segment holds no grids".into());
    }
    let mut at = pos + HEADER_BYTES;
    let mut infos = Vec::with_capacity(count as usize);
    for i in 0..count {
        let (info, next) =
            meta(b, at, version, codec).map_err(|m| format!("metadata of grid {i}: {m}"))?;
        infos.push(info);
        at = next;
    }
    for info in infos {
        b.slice(at, info.file_bytes)
            .map_err(|m| format!("grid \"{}\": {m}", info.name))?;
        let next = at + info.file_bytes;
        out.push(Entry { info, offset: at });
        at = next;
    }
    Ok(at)
}

fn codec(code: u16) -> Parse<Codec> {
    match code {
        0 => Ok(Codec::None),
        1 => Ok(Codec::Zip),
        2 => Ok(Codec::Blosc),
        c => Err(format!("unknown codec {c}")),
    }
}

/// One 176-byte FileMetaData record and the name after it; returns the end of the name.
fn meta(b: Bytes, p: u64, version: Version, codec: Codec) -> Parse<(GridMetaData, u64)> {
    b.slice(p, META_BYTES)?;
    let name_size = b.u32(p + 136)? as u64;
    if name_size == 0 {
        return Err("empty grid name field".into());
    }
    let name = b.c_str(p + META_BYTES, name_size)?;
    let info = GridMetaData {
        name,
        grid_type: GridType(b.u32(p + 32)?),
        grid_class: GridClass(b.u32(p + 36)?),
        version,
        codec,
        grid_bytes: b.u64(p)?,
        file_bytes: b.u64(p + 8)?,
        active_voxels: b.u64(p + 24)?,
        index_bbox: (b.ivec3(p + 88)?, b.ivec3(p + 100)?),
        world_bbox: (b.dvec3(p + 40)?, b.dvec3(p + 64)?),
        voxel_size: b.dvec3(p + 112)?,
        node_counts: [b.u32(p + 140)?, b.u32(p + 144)?, b.u32(p + 148)?],
        active_tiles: [b.u32(p + 156)?, b.u32(p + 160)?, b.u32(p + 164)?],
    };
    check_sizes(&info).map_err(|m| format!("grid \"{}\": {m}", info.name))?;
    Ok((info, p + META_BYTES + name_size))
}

/// Rejects a decoded size that the stored bytes cannot produce, before anything is allocated.
fn check_sizes(info: &GridMetaData) -> Parse<()> {
    let (grid, stored) = (info.grid_bytes, info.file_bytes);
    if grid < tree::MIN_GRID_BYTES {
        return Err(format!("grid size {grid} is smaller than a grid header"));
    }
    let limit = match info.codec {
        Codec::None if stored != grid => {
            return Err(format!(
                "stored size {stored} differs from grid size {grid}"
            ));
        }
        Codec::None => grid,
        Codec::Zip => stored.saturating_mul(ZIP_RATIO).saturating_add(RATIO_SLACK),
        Codec::Blosc => stored
            .saturating_mul(BLOSC_RATIO)
            .saturating_add(RATIO_SLACK),
    };
    if grid > limit {
        return Err(format!(
            "grid size {grid} cannot come from {stored} stored {:?} bytes",
            info.codec
        ));
    }
    Ok(())
}

/// A file that is just grid buffers back to back, each starting with `NanoVDB1`.
fn raw_grids(b: Bytes) -> Parse<Vec<Entry>> {
    let mut out = Vec::new();
    let mut pos = 0;
    while pos < b.len() {
        let buf = raw_grid(b, pos).map_err(|m| format!("grid buffer at byte {pos}: {m}"))?;
        let info = tree::info(buf).map_err(|m| format!("grid buffer at byte {pos}: {m}"))?;
        out.push(Entry { info, offset: pos });
        pos += buf.len() as u64;
    }
    Ok(out)
}

fn raw_grid<'a>(b: Bytes<'a>, pos: u64) -> Parse<&'a [u8]> {
    let magic = b.u64(pos)?;
    if magic != MAGIC_GRID {
        return Err(format!("bad grid magic {magic:#018x}"));
    }
    let size = b.u64(pos + 32)?;
    if size < tree::MIN_GRID_BYTES {
        return Err(format!("grid size {size} is smaller than a grid header"));
    }
    b.slice(pos, size)
}
