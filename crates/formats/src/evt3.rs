//! Prophesee EVT 3.0: little-endian 16-bit words, the type in bits 15..12, decoded as OpenEB
//! and the reference decoder `evt3` do.
//!
//! EVT_ADDR_Y (0x0): y in 10..0. EVT_ADDR_X (0x2): polarity in 11, x in 10..0: one event at
//! the current row and time. VECT_BASE_X (0x3): polarity in 11, x in 10..0, the base of the
//! vectors that follow. VECT_12 (0x4) / VECT_8 (0x5): a bit mask of events at base + i, then
//! base += 12 / 8. EVT_TIME_LOW (0x6): time bits 11..0. EVT_TIME_HIGH (0x8): time bits 23..12
//! (and the low bits back to 0). CONTINUED_4 (0x7), EXT_TRIGGER (0xA), OTHERS (0xE) and
//! CONTINUED_12 (0xF) carry no CD event and are skipped.

use crate::{Decode, Events, Stats, Unwrap};

const ADDR_Y: u16 = 0x0;
const ADDR_X: u16 = 0x2;
const VECT_BASE_X: u16 = 0x3;
const VECT_12: u16 = 0x4;
const VECT_8: u16 = 0x5;
const TIME_LOW: u16 = 0x6;
const CONTINUED_4: u16 = 0x7;
const TIME_HIGH: u16 = 0x8;
const EXT_TRIGGER: u16 = 0xA;
const OTHERS: u16 = 0xE;
const CONTINUED_12: u16 = 0xF;

/// The 24-bit time wraps every 16.8 s: TIME_HIGH (12 bits) dropping by at least 4085 of its
/// 4096 steps is a wrap; a smaller drop is a step back, kept as is (measured on `evt3` 0.4.1).
const HIGH_BITS: u32 = 12;
const WRAP_DROP: u64 = 4085;

#[derive(Debug, Default, Clone)]
pub struct Decoder {
    high: Unwrap,
    /// TIME_HIGH in µs (with its wraps); None before the first one.
    base: Option<i64>,
    low: i64,
    y: u16,
    vect_x: u16,
    vect_p: i8,
    /// The events of a vector word that did not fit in the last chunk.
    pending: Vector,
}

/// A vector word's events: bit i of `mask` is an event at x + i.
#[derive(Debug, Default, Clone, Copy)]
struct Vector {
    mask: u16,
    x: u16,
    y: u16,
    t: i64,
    p: i8,
}

impl Vector {
    /// Emits events until `out` holds `max_events`; the mask keeps the rest.
    #[inline(always)]
    fn emit(&mut self, out: &mut Events, max_events: usize) {
        while self.mask != 0 && out.len() < max_events {
            let i = self.mask.trailing_zeros() as u16;
            out.push(self.x.wrapping_add(i), self.y, self.t, self.p);
            self.mask &= self.mask - 1;
        }
    }
}

impl Decoder {
    /// The events of a vector mask at the current base, which then moves by `width`; those
    /// past `max_events` wait in `pending`, so that chunks come out exactly full.
    #[inline(always)]
    fn vector(
        &mut self,
        mask: u16,
        width: u16,
        out: &mut Events,
        max_events: usize,
        stats: &mut Stats,
    ) {
        match self.base {
            Some(base) => {
                let (x, y, t, p) = (self.vect_x, self.y, base | self.low, self.vect_p);
                self.pending = Vector { mask, x, y, t, p };
                self.pending.emit(out, max_events);
            }
            None => stats.untimed_events += mask.count_ones() as u64,
        }
        self.vect_x = self.vect_x.wrapping_add(width);
    }
}

impl Decode for Decoder {
    const WORD: usize = 2;
    const MAX_PER_WORD: usize = 12;

    fn decode(
        &mut self,
        bytes: &[u8],
        out: &mut Events,
        max_events: usize,
        stats: &mut Stats,
    ) -> usize {
        self.pending.emit(out, max_events);
        // The current row and time in locals: a single event (ADDR_X, most words) then needs
        // no load from the decoder.
        let mut y = self.y;
        let mut t = self.base.map(|base| base | self.low);
        let mut used = 0;
        for w in bytes.chunks_exact(Self::WORD) {
            if out.len() >= max_events {
                break;
            }
            let w = u16::from_le_bytes([w[0], w[1]]);
            let (kind, x, p) = (w >> 12, w & 0x7FF, ((w >> 11) & 1) as i8);
            used += Self::WORD;
            if kind == ADDR_X {
                match t {
                    Some(t) => out.push(x, y, t, p),
                    None => stats.untimed_events += 1,
                }
                continue;
            }
            match kind {
                ADDR_Y => y = x,
                VECT_BASE_X => (self.vect_x, self.vect_p) = (x, p),
                VECT_12 | VECT_8 => {
                    let (mask, width) = if kind == VECT_12 {
                        (w & 0xFFF, 12)
                    } else {
                        (w & 0xFF, 8)
                    };
                    self.y = y;
                    self.vector(mask, width, out, max_events, stats);
                }
                TIME_LOW => {
                    self.low = (w & 0xFFF) as i64;
                    t = self.base.map(|base| base | self.low);
                }
                TIME_HIGH => {
                    let high = self.high.next((w & 0xFFF) as u64, HIGH_BITS, WRAP_DROP);
                    self.base = Some((high << 12) as i64);
                    self.low = 0;
                    t = self.base;
                }
                CONTINUED_4 | EXT_TRIGGER | OTHERS | CONTINUED_12 => {}
                _ => stats.unknown_words += 1,
            }
        }
        self.y = y;
        used
    }
}
