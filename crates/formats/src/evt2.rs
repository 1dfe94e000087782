//! Prophesee EVT 2.0: little-endian 32-bit words, the type in bits 31..28.
//!
//! CD_OFF (0x0) / CD_ON (0x1): timestamp bits 5..0 in 27..22, x in 21..11, y in 10..0.
//! EVT_TIME_HIGH (0x8): timestamp bits 33..6 in 27..0. EXT_TRIGGER (0xA), OTHERS (0xE) and
//! CONTINUED (0xF) carry no CD event and are skipped. CD events before the first TIME_HIGH
//! have no time base: counted, not emitted (as the EVT 3.0 decoders do; expelliarmus gives
//! them TIME_HIGH 0).

use crate::{Decode, Events, Stats, Unwrap};

const CD_OFF: u32 = 0x0;
const CD_ON: u32 = 0x1;
const TIME_HIGH: u32 = 0x8;
const EXT_TRIGGER: u32 = 0xA;
const OTHERS: u32 = 0xE;
const CONTINUED: u32 = 0xF;

/// TIME_HIGH counts 2^28 steps of 64 µs (4.8 hours); a drop by half of that or more is the
/// counter wrapping (the reference decoder, expelliarmus, does not unwrap it).
const HIGH_BITS: u32 = 28;
const WRAP_DROP: u64 = 1 << (HIGH_BITS - 1);

#[derive(Debug, Default, Clone)]
pub struct Decoder {
    high: Unwrap,
    /// The current TIME_HIGH in µs; None before the first one.
    base: Option<i64>,
}

impl Decode for Decoder {
    const WORD: usize = 4;
    const MAX_PER_WORD: usize = 1;

    fn decode(
        &mut self,
        bytes: &[u8],
        out: &mut Events,
        max_events: usize,
        stats: &mut Stats,
    ) -> usize {
        let mut used = 0;
        for w in bytes.chunks_exact(Self::WORD) {
            if out.len() >= max_events {
                break;
            }
            let w = u32::from_le_bytes([w[0], w[1], w[2], w[3]]);
            match w >> 28 {
                CD_OFF | CD_ON => match self.base {
                    Some(base) => out.push(
                        ((w >> 11) & 0x7FF) as u16,
                        (w & 0x7FF) as u16,
                        base | ((w >> 22) & 0x3F) as i64,
                        (w >> 28) as i8,
                    ),
                    None => stats.untimed_events += 1,
                },
                TIME_HIGH => {
                    let high = self
                        .high
                        .next((w & 0x0FFF_FFFF) as u64, HIGH_BITS, WRAP_DROP);
                    self.base = Some((high << 6) as i64);
                }
                EXT_TRIGGER | OTHERS | CONTINUED => {}
                _ => stats.unknown_words += 1,
            }
            used += Self::WORD;
        }
        used
    }
}
