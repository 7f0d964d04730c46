//! Turns a grid's stored bytes into its grid buffer (NanoVDB's `Codec`: none, zip, blosc).
use std::borrow::Cow;
use std::io::Read;

use super::bytes::{buffer, Bytes, Parse};
use super::{blosc, Codec};

/// The grid buffer of `stored`, which must decode to exactly `grid_bytes` bytes.
pub(super) fn decode(stored: &[u8], codec: Codec, grid_bytes: u64) -> Parse<Cow<'_, [u8]>> {
    let size =
        usize::try_from(grid_bytes).map_err(|_| format!("grid size {grid_bytes} too large"))?;
    match codec {
        Codec::None if stored.len() == size => Ok(Cow::Borrowed(stored)),
        Codec::None => Err(format!(
            "{} stored bytes for a {size}-byte grid",
            stored.len()
        )),
        Codec::Zip => inflate(stored, size).map(Cow::Owned),
        Codec::Blosc => blosc::decompress(stored, size).map(Cow::Owned),
    }
}

/// NanoVDB's ZIP payload: a u64 byte count, then a zlib stream of that many bytes.
fn inflate(stored: &[u8], size: usize) -> Parse<Vec<u8>> {
    let b = Bytes(stored);
    let count = b.u64(0).map_err(|m| format!("zip size: {m}"))?;
    let stream = b.slice(8, count).map_err(|m| format!("zip stream: {m}"))?;
    let mut out = buffer(size)?;
    flate2::read::ZlibDecoder::new(stream)
        .take(size as u64 + 1)
        .read_to_end(&mut out)
        .map_err(|e| format!("zip stream: {e}"))?;
    if out.len() != size {
        return Err(format!(
            "zip stream inflates to {} bytes, not {size}",
            out.len()
        ));
    }
    Ok(out)
}
