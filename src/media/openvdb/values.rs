//! Node value arrays as OpenVDB stores them (`io::readCompressedValues`): a per-node
//! metadata byte that says how inactive values can be rebuilt, optional inactive values and
//! a selection mask, then the values (all of them, or only the active ones under active-mask
//! compression) as one raw, zlib or Blosc chunk, in f32 or IEEE half.
use super::bytes::{bit, count_ones, Parse, Reader};
use crate::media::blosc;
use std::io::Read;

pub const COMPRESS_ZIP: u32 = 0x1;
pub const COMPRESS_ACTIVE_MASK: u32 = 0x2;
pub const COMPRESS_BLOSC: u32 = 0x4;

/// Per-node metadata byte values (OpenVDB's `NodeMetadata`).
const NO_MASK_OR_INACTIVE_VALS: u8 = 0;
const NO_MASK_AND_ONE_INACTIVE_VAL: u8 = 2;
const MASK_AND_NO_INACTIVE_VALS: u8 = 3;
const MASK_AND_ONE_INACTIVE_VAL: u8 = 4;
const MASK_AND_TWO_INACTIVE_VALS: u8 = 5;
const NO_MASK_AND_ALL_VALS: u8 = 6;

/// How one grid's values are stored.
#[derive(Clone, Copy, Debug)]
pub struct Storage {
    pub compression: u32,
    pub half: bool,
    pub background: f32,
}

/// The inactive-value rule a node's metadata byte selects.
struct Inactive {
    meta: u8,
    val0: f32,
    val1: f32,
    selection: Option<Vec<u64>>,
}

fn read_inactive(r: &mut Reader, s: &Storage, count: usize) -> Parse<Inactive> {
    let meta = r.u8("node compression metadata")?;
    if meta > NO_MASK_AND_ALL_VALS {
        return Err(format!(
            "invalid node compression metadata {meta} at byte {}",
            r.pos() - 1
        ));
    }
    let bg = s.background;
    let mut val0 = if meta == NO_MASK_OR_INACTIVE_VALS {
        bg
    } else {
        -bg
    };
    let mut val1 = bg;
    if matches!(
        meta,
        NO_MASK_AND_ONE_INACTIVE_VAL | MASK_AND_ONE_INACTIVE_VAL | MASK_AND_TWO_INACTIVE_VALS
    ) {
        val0 = r.f32("inactive value")?;
        if meta == MASK_AND_TWO_INACTIVE_VALS {
            val1 = r.f32("second inactive value")?;
        }
    }
    let selection = match meta {
        MASK_AND_NO_INACTIVE_VALS | MASK_AND_ONE_INACTIVE_VAL | MASK_AND_TWO_INACTIVE_VALS => {
            Some(r.mask(count, "inactive value selection mask")?)
        }
        _ => None,
    };
    Ok(Inactive {
        meta,
        val0,
        val1,
        selection,
    })
}

/// Reads `value_mask.len() * 64` values of one node, rebuilding inactive ones if only the
/// active values were stored.
pub fn read_node_values(r: &mut Reader, s: &Storage, value_mask: &[u64]) -> Parse<Vec<f32>> {
    let count = value_mask.len() * 64;
    let inactive = read_inactive(r, s, count)?;
    let masked = s.compression & COMPRESS_ACTIVE_MASK != 0 && inactive.meta != NO_MASK_AND_ALL_VALS;
    let stored = if masked {
        count_ones(value_mask)
    } else {
        count
    };
    let values = read_values(r, s, stored)?;
    if stored == count {
        return Ok(values);
    }
    let mut active = values.into_iter();
    Ok((0..count)
        .map(|n| {
            if bit(value_mask, n) {
                active.next().unwrap_or(s.background)
            } else if inactive.selection.as_deref().is_some_and(|m| bit(m, n)) {
                inactive.val1
            } else {
                inactive.val0
            }
        })
        .collect())
}

/// Reads `n` values stored as one chunk (OpenVDB's `readData` / `HalfReader`).
fn read_values(r: &mut Reader, s: &Storage, n: usize) -> Parse<Vec<f32>> {
    if s.half && n == 0 {
        return Ok(Vec::new());
    }
    let size = if s.half { 2 } else { 4 };
    let bytes = read_chunk(r, s.compression, n * size)?;
    Ok(if s.half {
        bytes
            .chunks_exact(2)
            .map(|b| half::f16::from_le_bytes([b[0], b[1]]).to_f32())
            .collect()
    } else {
        bytes
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect()
    })
}

/// Reads `nbytes` of data: raw, or an i64 size and a zlib/Blosc chunk (size <= 0: stored raw).
fn read_chunk(r: &mut Reader, compression: u32, nbytes: usize) -> Parse<Vec<u8>> {
    if compression & (COMPRESS_BLOSC | COMPRESS_ZIP) == 0 {
        return Ok(r.take(nbytes, "node values")?.to_vec());
    }
    let at = r.pos();
    let size = r.i64("compressed chunk size")?;
    if size <= 0 {
        if size.unsigned_abs() != nbytes as u64 {
            return Err(format!(
                "chunk at byte {at} holds {} raw bytes, expected {nbytes}",
                size.unsigned_abs()
            ));
        }
        return Ok(r.take(nbytes, "uncompressed chunk")?.to_vec());
    }
    let len = usize::try_from(size).unwrap_or(usize::MAX);
    let src = r.take(len, "compressed chunk")?;
    let out = if compression & COMPRESS_BLOSC != 0 {
        blosc::decompress(src, nbytes)
    } else {
        inflate(src, nbytes)
    };
    out.map_err(|e| format!("chunk at byte {at}: {e}"))
}

/// Inflates a zlib stream that must hold exactly `nbytes`; reads at most one byte more.
fn inflate(src: &[u8], nbytes: usize) -> Parse<Vec<u8>> {
    let mut out = Vec::with_capacity(nbytes);
    flate2::read::ZlibDecoder::new(src)
        .take(nbytes as u64 + 1)
        .read_to_end(&mut out)
        .map_err(|e| format!("zlib: {e}"))?;
    if out.len() != nbytes {
        return Err(format!(
            "zlib chunk inflated to {}{} bytes, expected {nbytes}",
            if out.len() > nbytes { "more than " } else { "" },
            out.len().min(nbytes)
        ));
    }
    Ok(out)
}
