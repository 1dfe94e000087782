//! Little-endian integers read at an offset of untrusted bytes: None past the end (or on an
//! offset whose end overflows), never a panic. Shared by the container readers.

fn array_at<const N: usize>(b: &[u8], at: usize) -> Option<[u8; N]> {
    b.get(at..at.checked_add(N)?)?.try_into().ok()
}

pub(crate) fn u16_at(b: &[u8], at: usize) -> Option<u16> {
    array_at(b, at).map(u16::from_le_bytes)
}

pub(crate) fn u32_at(b: &[u8], at: usize) -> Option<u32> {
    array_at(b, at).map(u32::from_le_bytes)
}

pub(crate) fn u64_at(b: &[u8], at: usize) -> Option<u64> {
    array_at(b, at).map(u64::from_le_bytes)
}

pub(crate) fn i64_at(b: &[u8], at: usize) -> Option<i64> {
    array_at(b, at).map(i64::from_le_bytes)
}
