//! Little-endian reads from byte slices that are already known to be long enough. They never
//! panic: a read past the end yields zero, which validation (docs/FORMAT.md) makes unreachable.

pub(crate) fn u8_at(b: &[u8], off: usize) -> u8 {
    b.get(off).copied().unwrap_or(0)
}

pub(crate) fn arr<const N: usize>(b: &[u8], off: usize) -> [u8; N] {
    let mut out = [0u8; N];
    if let Some(src) = off.checked_add(N).and_then(|end| b.get(off..end)) {
        out.copy_from_slice(src);
    }
    out
}

pub(crate) fn u16_at(b: &[u8], off: usize) -> u16 {
    u16::from_le_bytes(arr(b, off))
}

pub(crate) fn i16_at(b: &[u8], off: usize) -> i16 {
    i16::from_le_bytes(arr(b, off))
}

pub(crate) fn u32_at(b: &[u8], off: usize) -> u32 {
    u32::from_le_bytes(arr(b, off))
}

pub(crate) fn i32_at(b: &[u8], off: usize) -> i32 {
    i32::from_le_bytes(arr(b, off))
}

pub(crate) fn f32_at(b: &[u8], off: usize) -> f32 {
    f32::from_le_bytes(arr(b, off))
}

/// `len` bytes from `off`, or `None` if that runs past the end (checked arithmetic).
pub(crate) fn slice(b: &[u8], off: usize, len: usize) -> Option<&[u8]> {
    b.get(off..off.checked_add(len)?)
}

pub(crate) const fn align4(n: usize) -> usize {
    (n + 3) & !3
}
