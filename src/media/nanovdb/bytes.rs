//! Bounds-checked little-endian reads. Every offset in a NanoVDB file comes from the file
//! itself, so each read is checked against the buffer instead of trusted.
use glam::{DVec3, IVec3};

pub(super) use crate::media::Parse;

#[derive(Clone, Copy)]
pub(super) struct Bytes<'a>(pub &'a [u8]);

impl<'a> Bytes<'a> {
    pub fn len(&self) -> u64 {
        self.0.len() as u64
    }

    pub fn slice(&self, off: u64, len: u64) -> Parse<&'a [u8]> {
        match off.checked_add(len) {
            Some(end) if end <= self.len() => Ok(&self.0[off as usize..end as usize]),
            _ => Err(format!(
                "{len} bytes at offset {off} run past the end of the {}-byte buffer",
                self.len()
            )),
        }
    }

    fn array<const N: usize>(&self, off: u64) -> Parse<[u8; N]> {
        let s = self.slice(off, N as u64)?;
        let mut a = [0u8; N];
        a.copy_from_slice(s);
        Ok(a)
    }

    pub fn u16(&self, off: u64) -> Parse<u16> {
        self.array(off).map(u16::from_le_bytes)
    }

    pub fn u32(&self, off: u64) -> Parse<u32> {
        self.array(off).map(u32::from_le_bytes)
    }

    pub fn i32(&self, off: u64) -> Parse<i32> {
        self.array(off).map(i32::from_le_bytes)
    }

    pub fn u64(&self, off: u64) -> Parse<u64> {
        self.array(off).map(u64::from_le_bytes)
    }

    pub fn i64(&self, off: u64) -> Parse<i64> {
        self.array(off).map(i64::from_le_bytes)
    }

    pub fn f32(&self, off: u64) -> Parse<f32> {
        self.array(off).map(f32::from_le_bytes)
    }

    pub fn f64(&self, off: u64) -> Parse<f64> {
        self.array(off).map(f64::from_le_bytes)
    }

    pub fn ivec3(&self, off: u64) -> Parse<IVec3> {
        Ok(IVec3::new(
            self.i32(off)?,
            self.i32(off + 4)?,
            self.i32(off + 8)?,
        ))
    }

    pub fn dvec3(&self, off: u64) -> Parse<DVec3> {
        Ok(DVec3::new(
            self.f64(off)?,
            self.f64(off + 8)?,
            self.f64(off + 16)?,
        ))
    }

    /// `count` consecutive u64 words (bit masks).
    pub fn words(&self, off: u64, count: u64) -> Parse<Vec<u64>> {
        let s = self.slice(off, count.saturating_mul(8))?;
        Ok(s.chunks_exact(8)
            .map(|c| u64::from_le_bytes(c.try_into().expect("8-byte chunk")))
            .collect())
    }

    /// A NUL-terminated string stored in a fixed-size field.
    pub fn c_str(&self, off: u64, len: u64) -> Parse<String> {
        let s = self.slice(off, len)?;
        let end = s.iter().position(|&c| c == 0).unwrap_or(s.len());
        Ok(String::from_utf8_lossy(&s[..end]).into_owned())
    }
}

/// Offset `base + rel` as stored in node tables (signed, relative), if it stays in range.
pub(super) fn offset(base: u64, rel: i64) -> Parse<u64> {
    base.checked_add_signed(rel)
        .ok_or_else(|| format!("child offset {rel} from {base} is out of range"))
}
/// Room for `size` bytes, or an error instead of an abort when memory is short.
pub(super) fn buffer(size: usize) -> Parse<Vec<u8>> {
    let mut v = Vec::new();
    v.try_reserve_exact(size)
        .map_err(|_| format!("cannot allocate {size} bytes for the grid"))?;
    Ok(v)
}
