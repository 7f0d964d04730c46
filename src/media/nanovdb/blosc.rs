//! Blosc1 frame decoder for NanoVDB's BLOSC codec. NanoVDB stores a grid as chunks of at
//! most 1 GiB, each a u64 byte count and one blosc1 frame (LZ4 with byte shuffle).
//! The frame format is c-blosc's: a 16-byte header, a table of block starts, and per
//! block one or `typesize` compressed streams, each prefixed by its i32 length.
use super::bytes::{Bytes, Parse};
use super::codec::buffer;

const CHUNK_BYTES: usize = 1 << 30;
const FRAME_HEADER: usize = 16;
const DO_SHUFFLE: u8 = 0x01;
const MEMCPYED: u8 = 0x02;
const DO_BITSHUFFLE: u8 = 0x04;
const DONT_SPLIT: u8 = 0x10;
const LZ4_FORMAT: u8 = 1;
/// c-blosc only splits blocks of at least this many elements (and types of at most 16 bytes).
const MIN_SPLIT_ELEMENTS: usize = 128;
const MAX_SPLITS: usize = 16;

/// Decodes NanoVDB's chunk sequence into a `size`-byte grid buffer.
pub(super) fn decompress(stored: &[u8], size: usize) -> Parse<Vec<u8>> {
    let mut out = buffer(size)?;
    out.resize(size, 0);
    let b = Bytes(stored);
    let (mut pos, mut done) = (0u64, 0usize);
    while done < size {
        let chunk = (size - done).min(CHUNK_BYTES);
        let count = b.u64(pos).map_err(|m| format!("blosc chunk size: {m}"))?;
        let frame = b
            .slice(pos + 8, count)
            .map_err(|m| format!("blosc chunk: {m}"))?;
        decode_frame(frame, &mut out[done..done + chunk])
            .map_err(|m| format!("blosc chunk at byte {pos}: {m}"))?;
        pos += 8 + count;
        done += chunk;
    }
    Ok(out)
}

struct Header {
    flags: u8,
    typesize: usize,
    blocksize: usize,
}

impl Header {
    fn parse(frame: &[u8], expected: usize) -> Parse<(Header, &[u8])> {
        let b = Bytes(frame);
        let (version, flags, typesize) = (frame.first(), frame.get(2), frame.get(3));
        let (Some(&version), Some(&flags), Some(&typesize)) = (version, flags, typesize) else {
            return Err("frame shorter than its header".into());
        };
        let nbytes = b.u32(4)? as usize;
        let blocksize = b.u32(8)? as usize;
        let cbytes = b.u32(12)? as u64;
        if version == 0 || flags & (DO_SHUFFLE | DO_BITSHUFFLE) == DO_SHUFFLE | DO_BITSHUFFLE {
            return Err(format!(
                "unsupported blosc format {version} (flags {flags:#04x})"
            ));
        }
        if nbytes != expected {
            return Err(format!("frame holds {nbytes} bytes, expected {expected}"));
        }
        if typesize == 0 || (blocksize == 0 && nbytes > 0) {
            return Err(format!("bad typesize {typesize} or block size {blocksize}"));
        }
        let frame = b.slice(0, cbytes)?;
        let header = Header {
            flags,
            typesize: typesize as usize,
            blocksize,
        };
        Ok((header, frame))
    }

    fn shuffled(&self) -> bool {
        self.flags & DO_SHUFFLE != 0 && self.typesize > 1
    }

    /// Whether a block was compressed as `typesize` separate byte streams (c-blosc's rule).
    fn splits(&self, bsize: usize, leftover: bool) -> usize {
        let split = self.flags & DONT_SPLIT == 0
            && self.typesize <= MAX_SPLITS
            && bsize / self.typesize >= MIN_SPLIT_ELEMENTS
            && !leftover;
        if split {
            self.typesize
        } else {
            1
        }
    }
}

fn decode_frame(frame: &[u8], dst: &mut [u8]) -> Parse<()> {
    let (h, frame) = Header::parse(frame, dst.len())?;
    if h.flags & MEMCPYED != 0 {
        let raw = Bytes(frame).slice(FRAME_HEADER as u64, dst.len() as u64)?;
        dst.copy_from_slice(raw);
        return Ok(());
    }
    let compressor = h.flags >> 5;
    if compressor != LZ4_FORMAT {
        return Err(format!(
            "blosc inner codec {} is not supported (only lz4)",
            codec_name(compressor)
        ));
    }
    if h.flags & DO_BITSHUFFLE != 0 {
        return Err("blosc bit-shuffle is not supported (only byte shuffle)".into());
    }
    let mut tmp = if h.shuffled() {
        buffer(h.blocksize.min(dst.len()))?
    } else {
        Vec::new()
    };
    for (j, block) in dst.chunks_mut(h.blocksize).enumerate() {
        let start = Bytes(frame).i32((FRAME_HEADER + 4 * j) as u64)?;
        decode_block(frame, &h, start, block, &mut tmp).map_err(|m| format!("block {j}: {m}"))?;
    }
    Ok(())
}

fn codec_name(code: u8) -> String {
    match code {
        0 => "blosclz".into(),
        2 => "snappy".into(),
        3 => "zlib".into(),
        4 => "zstd".into(),
        c => format!("#{c}"),
    }
}

fn decode_block(
    frame: &[u8],
    h: &Header,
    start: i32,
    dst: &mut [u8],
    tmp: &mut Vec<u8>,
) -> Parse<()> {
    let start = u64::try_from(start).map_err(|_| format!("negative block start {start}"))?;
    let nsplits = h.splits(dst.len(), dst.len() < h.blocksize);
    if !dst.len().is_multiple_of(nsplits) {
        return Err(format!(
            "block of {} bytes does not split into {nsplits}",
            dst.len()
        ));
    }
    if !h.shuffled() {
        return decode_streams(frame, start, dst, nsplits);
    }
    tmp.clear();
    tmp.resize(dst.len(), 0);
    decode_streams(frame, start, tmp, nsplits)?;
    unshuffle(tmp, dst, h.typesize);
    Ok(())
}

/// The block's `nsplits` streams, each an i32 length and LZ4 data (or raw bytes when the
/// length equals the stream's decoded size).
fn decode_streams(frame: &[u8], mut pos: u64, dst: &mut [u8], nsplits: usize) -> Parse<()> {
    let b = Bytes(frame);
    let neblock = dst.len() / nsplits;
    for part in dst.chunks_mut(neblock.max(1)) {
        let len = b.i32(pos)?;
        let len = u64::try_from(len).map_err(|_| format!("negative stream length {len}"))?;
        let src = b.slice(pos + 4, len)?;
        if src.len() == part.len() {
            part.copy_from_slice(src);
        } else {
            let n = lz4_flex::block::decompress_into(src, part).map_err(|e| format!("lz4: {e}"))?;
            if n != part.len() {
                return Err(format!(
                    "lz4 stream gives {n} bytes, expected {}",
                    part.len()
                ));
            }
        }
        pos += 4 + len;
    }
    Ok(())
}

/// Undoes blosc's byte shuffle: byte `k` of element `i` was stored at `k * n + i`.
fn unshuffle(src: &[u8], dst: &mut [u8], typesize: usize) {
    let n = src.len() / typesize;
    for (i, elem) in dst[..n * typesize].chunks_exact_mut(typesize).enumerate() {
        for (k, byte) in elem.iter_mut().enumerate() {
            *byte = src[k * n + i];
        }
    }
    dst[n * typesize..].copy_from_slice(&src[n * typesize..]);
}
