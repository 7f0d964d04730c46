//! NanoVDB's BLOSC codec: a grid is stored as chunks of at most 1 GiB, each a u64 byte
//! count and one blosc1 frame, decoded by the shared [`crate::media::blosc`] decoder.
use super::bytes::{buffer, Bytes, Parse};

const CHUNK_BYTES: usize = 1 << 30;

/// Decodes NanoVDB's chunk sequence into a `size`-byte grid buffer.
pub(super) fn decompress(stored: &[u8], size: usize) -> Parse<Vec<u8>> {
    let mut out = buffer(size)?;
    let b = Bytes(stored);
    let mut pos = 0u64;
    while out.len() < size {
        let chunk = (size - out.len()).min(CHUNK_BYTES);
        let count = b.u64(pos).map_err(|m| format!("blosc chunk size: {m}"))?;
        let frame = b
            .slice(pos + 8, count)
            .map_err(|m| format!("blosc chunk: {m}"))?;
        let decoded = crate::media::blosc::decompress(frame, chunk)
            .map_err(|m| format!("blosc chunk at byte {pos}: {m}"))?;
        out.extend_from_slice(&decoded);
        pos += 8 + count;
    }
    Ok(out)
}
