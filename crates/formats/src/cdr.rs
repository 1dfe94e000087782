//! The CDR (ROS 2) EventArray layout, shared by the MCAP and SQLite (.db3) readers.
//!
//! An EventArray in little-endian CDR: a 4-byte encapsulation header (`00 01 00 00`), then,
//! aligned from its end, Header (stamp sec i32, nanosec u32, frame_id as u32 length including
//! its NUL + bytes), padding to 4, height u32, width u32, the event count u32, then the events:
//! the first packed in 13 bytes (x u16, y u16, sec i32, nanosec u32, polarity u8) and every
//! further one aligned, 16 bytes apart (x at +1 after the previous polarity, sec at +6 of x).

use crate::bytes::u32_at;
use crate::Events;

/// Bytes of each event after the first in CDR.
pub const EVENT: usize = 16;

/// An EventArray's (width, height, offset of its first event, event count), or None when the
/// bytes are not exactly that layout (up to 3 bytes of padding after the last event).
pub fn event_array(data: &[u8]) -> Option<(u32, u32, usize, usize)> {
    if data.get(..2)? != b"\x00\x01" {
        return None;
    }
    let id_len = u32_at(data, 4 + 8)? as usize;
    let start = 4 + (12usize.checked_add(id_len)?.checked_add(3)? / 4 * 4) + 12;
    let height = u32_at(data, start - 12)?;
    let width = u32_at(data, start - 8)?;
    let n = u32_at(data, start - 4)? as usize;
    let end = match n {
        0 => start,
        _ => start.checked_add(n.checked_mul(EVENT)? - 3)?,
    };
    (end <= data.len() && data.len() <= end + 3).then_some((width, height, start, n))
}

/// µs of a builtin_interfaces/Time (sec i32, nanosec u32; 8 bytes).
#[inline]
fn cdr_time(r: &[u8]) -> i64 {
    let sec = i32::from_le_bytes([r[0], r[1], r[2], r[3]]) as i64;
    let nsec = u32::from_le_bytes([r[4], r[5], r[6], r[7]]) as i64;
    sec * 1_000_000 + nsec / 1000
}

/// Appends events `next..next + take` of the event array whose first event is at `start` of
/// `b` (checked by `event_array`) to `out`, column by column.
pub(crate) fn push_events(b: &[u8], start: usize, next: usize, take: usize, out: &mut Events) {
    let (mut i, mut take) = (next, take);
    if take == 0 {
        return;
    }
    if i == 0 {
        // The first event is packed: x, y, sec, nanosec, polarity at 0, 2, 4, 8, 12.
        let r = &b[start..start + 13];
        out.push(
            u16::from_le_bytes([r[0], r[1]]),
            u16::from_le_bytes([r[2], r[3]]),
            cdr_time(&r[4..12]),
            (r[12] != 0) as i8,
        );
        (i, take) = (1, take - 1);
    }
    // Every further one fills a 16-byte record from the padding byte before its x:
    // x, y, sec, nanosec, polarity at 1, 3, 7, 11, 15. Column by column, as the others.
    let from = start + 13 + EVENT * (i - 1);
    let records = b[from..from + EVENT * take].chunks_exact(EVENT);
    out.x
        .extend(records.clone().map(|r| u16::from_le_bytes([r[1], r[2]])));
    out.y
        .extend(records.clone().map(|r| u16::from_le_bytes([r[3], r[4]])));
    out.t.extend(records.clone().map(|r| cdr_time(&r[7..15])));
    out.p.extend(records.map(|r| (r[15] != 0) as i8));
}
