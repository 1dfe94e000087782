//! Prophesee DAT, CD events: after the header and its two bytes of event type and size,
//! 8-byte little-endian records: a 32-bit timestamp (µs), then a 32-bit word with x in bits
//! 13..0, y in 27..14 and the polarity in 31..28.

use crate::{Decode, Events, Stats, Unwrap};

/// The 32-bit timestamp wraps every 71.6 minutes: a drop by half its range or more is a
/// wrap (the reference, expelliarmus, takes any drop for one: the same on sorted files).
const TIME_BITS: u32 = 32;
const WRAP_DROP: u64 = 1 << (TIME_BITS - 1);

#[derive(Debug, Default, Clone)]
pub struct Decoder {
    time: Unwrap,
}

impl Decode for Decoder {
    const WORD: usize = 8;
    const MAX_PER_WORD: usize = 1;

    fn decode(
        &mut self,
        bytes: &[u8],
        out: &mut Events,
        max_events: usize,
        _stats: &mut Stats,
    ) -> usize {
        let n = (bytes.len() / Self::WORD).min(max_events.saturating_sub(out.len()));
        let records = bytes[..n * Self::WORD].chunks_exact(Self::WORD);
        let data = |r: &[u8]| u32::from_le_bytes([r[4], r[5], r[6], r[7]]);
        // Column by column: exact-size iterators extend without a capacity check per event.
        out.x
            .extend(records.clone().map(|r| (data(r) & 0x3FFF) as u16));
        out.y
            .extend(records.clone().map(|r| ((data(r) >> 14) & 0x3FFF) as u16));
        out.p.extend(records.clone().map(|r| (data(r) >> 28) as i8));
        out.t.extend(records.map(|r| {
            let ts = u32::from_le_bytes([r[0], r[1], r[2], r[3]]);
            self.time.next(ts as u64, TIME_BITS, WRAP_DROP) as i64
        }));
        n * Self::WORD
    }
}
