//! Decoder for one Blosc 1 frame, shared by the OpenVDB reader (`blosc_compress_ctx`
//! buffers) and the NanoVDB loader (one frame per chunk).
//!
//! Frame: a 16-byte header (format version, codec version, flags, type size, raw size,
//! block size, frame size), then one u32 start offset per block, then the blocks. A block
//! is split into `typesize` streams when the writer could split it; each stream is a u32
//! length and the codec's bytes (or the raw bytes when the length equals the stream size).
//! With the shuffle flag the decoded block is byte-transposed by `typesize`.
use std::io::Read;

pub use crate::media::Parse;

const HEADER: usize = 16;
const FLAG_SHUFFLE: u8 = 0x01;
const FLAG_MEMCPYED: u8 = 0x02;
const FLAG_BITSHUFFLE: u8 = 0x04;
const FLAG_DONT_SPLIT: u8 = 0x10;
const MAX_SPLITS: usize = 16;
const MIN_BUFFERSIZE: usize = 128;

struct Header {
    flags: u8,
    typesize: usize,
    nbytes: usize,
    blocksize: usize,
}

fn u32_at(src: &[u8], at: usize, what: &str) -> Parse<usize> {
    src.get(at..at + 4)
        .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize)
        .ok_or_else(|| format!("blosc frame too short for {what} at offset {at}"))
}

fn header(src: &[u8], expected: usize) -> Parse<Header> {
    if src.len() < HEADER {
        return Err(format!(
            "blosc frame of {} bytes is shorter than its header",
            src.len()
        ));
    }
    if !(1..=2).contains(&src[0]) {
        return Err(format!("unsupported blosc format version {}", src[0]));
    }
    let h = Header {
        flags: src[2],
        typesize: src[3] as usize,
        nbytes: u32_at(src, 4, "raw size")?,
        blocksize: u32_at(src, 8, "block size")?,
    };
    let cbytes = u32_at(src, 12, "frame size")?;
    if h.nbytes != expected {
        return Err(format!(
            "blosc frame holds {} bytes, expected {expected}",
            h.nbytes
        ));
    }
    if cbytes != src.len() {
        return Err(format!(
            "blosc frame says it is {cbytes} bytes (cbytes): it would run past the end of the {}-byte chunk",
            src.len()
        ));
    }
    if h.nbytes > 0 && (h.typesize == 0 || h.blocksize == 0 || h.blocksize > h.nbytes) {
        return Err(format!(
            "blosc frame with typesize {} and block size {} for {} bytes",
            h.typesize, h.blocksize, h.nbytes
        ));
    }
    Ok(h)
}

/// Decodes one frame whose raw size must be `expected` bytes.
pub fn decompress(src: &[u8], expected: usize) -> Parse<Vec<u8>> {
    let h = header(src, expected)?;
    if h.nbytes == 0 {
        return Ok(Vec::new());
    }
    if h.flags & FLAG_MEMCPYED != 0 {
        return src
            .get(HEADER..)
            .filter(|raw| raw.len() == h.nbytes)
            .map(<[u8]>::to_vec)
            .ok_or_else(|| "stored blosc frame has the wrong length".into());
    }
    if h.flags & FLAG_BITSHUFFLE != 0 && h.typesize > 1 {
        return Err("blosc bit-shuffle is not supported".into());
    }
    let codec = Codec::from_flags(h.flags)?;
    let nblocks = h.nbytes.div_ceil(h.blocksize);
    if nblocks > (src.len() - HEADER) / 4 {
        return Err(format!("blosc frame too short for {nblocks} block offsets"));
    }
    let mut out = vec![0u8; h.nbytes];
    let mut tmp = vec![0u8; h.blocksize.min(h.nbytes)];
    for (j, dest) in out.chunks_mut(h.blocksize).enumerate() {
        let start = u32_at(src, HEADER + 4 * j, "block offset")?;
        if start > i32::MAX as usize {
            return Err(format!(
                "negative block start {} (block {j})",
                start as u32 as i32
            ));
        }
        let leftover = dest.len() < h.blocksize;
        let shuffled = h.flags & FLAG_SHUFFLE != 0 && h.typesize > 1;
        let buf = if shuffled {
            &mut tmp[..dest.len()]
        } else {
            &mut *dest
        };
        decode_block(src, start, buf, &h, leftover, codec)?;
        if shuffled {
            unshuffle(h.typesize, &tmp[..dest.len()], dest);
        }
    }
    Ok(out)
}

fn splits(h: &Header, bsize: usize, leftover: bool) -> usize {
    let split = h.flags & FLAG_DONT_SPLIT == 0
        && h.typesize <= MAX_SPLITS
        && h.blocksize / h.typesize >= MIN_BUFFERSIZE
        && !leftover;
    if split && bsize.is_multiple_of(h.typesize) {
        h.typesize
    } else {
        1
    }
}

fn decode_block(
    src: &[u8],
    mut at: usize,
    dest: &mut [u8],
    h: &Header,
    leftover: bool,
    codec: Codec,
) -> Parse<()> {
    let nsplits = splits(h, dest.len(), leftover);
    let neblock = dest.len() / nsplits;
    for part in dest.chunks_mut(neblock) {
        let cbytes = u32_at(src, at, "stream length")?;
        at += 4;
        let stream = src.get(at..).and_then(|s| s.get(..cbytes)).ok_or_else(|| {
            format!("blosc stream of {cbytes} bytes would run past the end of the frame")
        })?;
        at += cbytes;
        if cbytes == part.len() {
            part.copy_from_slice(stream);
        } else {
            codec.decode(stream, part)?;
        }
    }
    Ok(())
}

/// Undoes the byte shuffle: byte `j` of element `i` was stored at `j * n + i`.
fn unshuffle(typesize: usize, src: &[u8], dest: &mut [u8]) {
    let n = src.len() / typesize;
    for i in 0..n {
        for j in 0..typesize {
            dest[i * typesize + j] = src[j * n + i];
        }
    }
    let done = n * typesize;
    dest[done..].copy_from_slice(&src[done..]);
}

#[derive(Clone, Copy)]
enum Codec {
    Lz4,
    Zlib,
}

impl Codec {
    fn from_flags(flags: u8) -> Parse<Codec> {
        match flags >> 5 {
            1 => Ok(Codec::Lz4),
            3 => Ok(Codec::Zlib),
            0 => Err("blosc codec blosclz is not supported (only lz4 and zlib)".into()),
            2 => Err("blosc codec snappy is not supported (only lz4 and zlib)".into()),
            4 => Err("blosc codec zstd is not supported (only lz4 and zlib)".into()),
            n => Err(format!("unknown blosc codec {n}")),
        }
    }

    /// Decodes `src` into exactly `dest.len()` bytes.
    fn decode(self, src: &[u8], dest: &mut [u8]) -> Parse<()> {
        let n = match self {
            Codec::Lz4 => lz4_flex::block::decompress_into(src, dest)
                .map_err(|e| format!("lz4 stream in blosc frame: {e}"))?,
            Codec::Zlib => inflate_into(src, dest)?,
        };
        if n != dest.len() {
            return Err(format!(
                "blosc stream decoded to {n} bytes, expected {}",
                dest.len()
            ));
        }
        Ok(())
    }
}

fn inflate_into(src: &[u8], dest: &mut [u8]) -> Parse<usize> {
    let mut z = flate2::read::ZlibDecoder::new(src);
    let mut n = 0;
    while n < dest.len() {
        match z.read(&mut dest[n..]) {
            Ok(0) => break,
            Ok(k) => n += k,
            Err(e) => return Err(format!("zlib stream in blosc frame: {e}")),
        }
    }
    Ok(n)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(flags: u8, typesize: u8, raw: &[u8], body: &[u8]) -> Vec<u8> {
        let mut f = vec![2, 1, flags, typesize];
        f.extend((raw.len() as u32).to_le_bytes());
        f.extend((raw.len() as u32).to_le_bytes());
        f.extend(((16 + body.len()) as u32).to_le_bytes());
        f.extend(body);
        f
    }

    #[test]
    fn stored_frame() {
        let raw: Vec<u8> = (0..40).collect();
        let f = frame(FLAG_MEMCPYED | 0x20, 4, &raw, &raw);
        assert_eq!(decompress(&f, 40).unwrap(), raw);
        assert!(decompress(&f, 41).is_err());
    }

    #[test]
    fn shuffled_raw_streams() {
        // 2 elements of 4 bytes, shuffled, one stream holding the block verbatim.
        let raw = [1u8, 2, 3, 4, 5, 6, 7, 8];
        let shuffled = [1u8, 5, 2, 6, 3, 7, 4, 8];
        let mut body = 20u32.to_le_bytes().to_vec();
        body.extend(8u32.to_le_bytes());
        body.extend(shuffled);
        let f = frame(FLAG_SHUFFLE | FLAG_DONT_SPLIT | 0x20, 4, &raw, &body);
        assert_eq!(decompress(&f, 8).unwrap(), raw);
    }

    #[test]
    fn lz4_stream() {
        // One literal-only LZ4 sequence: token 0x80 (8 literals), then the literals.
        let raw = [9u8, 8, 7, 6, 5, 4, 3, 2];
        let mut body = 20u32.to_le_bytes().to_vec();
        body.extend(9u32.to_le_bytes());
        body.push(0x80);
        body.extend(raw);
        let f = frame(FLAG_DONT_SPLIT | 0x20, 4, &raw, &body);
        assert_eq!(decompress(&f, 8).unwrap(), raw);
    }

    #[test]
    fn names_unsupported_codecs() {
        for (code, name) in [(0u8, "blosclz"), (2, "snappy"), (4, "zstd")] {
            let f = frame(code << 5, 4, &[0; 256], &[0; 8]);
            let e = decompress(&f, 256).unwrap_err();
            assert!(e.contains(name), "{e}");
        }
    }

    #[test]
    fn garbage_is_an_error() {
        for n in 0..64 {
            let junk: Vec<u8> = (0..n).map(|i| (i * 37 + 11) as u8).collect();
            assert!(decompress(&junk, 2048).is_err());
        }
    }
}
