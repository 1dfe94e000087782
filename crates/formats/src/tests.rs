//! Each decoder on words written by hand from the format's spec.

use crate::check::decode_all as decode;
use crate::{Encoding, Events, Stats};

fn rows(e: &Events) -> Vec<(u16, u16, i64, i8)> {
    (0..e.len())
        .map(|i| (e.x[i], e.y[i], e.t[i], e.p[i]))
        .collect()
}

fn evt2(words: &[u32]) -> Vec<u8> {
    words.iter().flat_map(|w| w.to_le_bytes()).collect()
}

fn evt3(words: &[u16]) -> Vec<u8> {
    words.iter().flat_map(|w| w.to_le_bytes()).collect()
}

fn cd2(t: u32, x: u32, y: u32, p: u32) -> u32 {
    (p << 28) | ((t & 0x3F) << 22) | (x << 11) | y
}

#[test]
fn evt2_events_take_time_high_and_their_six_low_bits() {
    let bytes = evt2(&[
        cd2(1, 5, 5, 1), // before any TIME_HIGH: no time base
        0x8000_0003,
        cd2(5, 10, 20, 1),
        0xA000_0101, // trigger, skipped
        cd2(63, 2047, 2047, 0),
        0x2000_0000, // undefined type
        0x8FFF_FFFF,
        cd2(0, 1, 2, 1),
        0x8000_0000, // the 28-bit counter wraps
        cd2(7, 3, 4, 0),
    ]);
    let (ev, stats) = decode(Encoding::Evt2, &bytes, 64, 1 << 10);
    let wrap = 1i64 << 34;
    assert_eq!(
        rows(&ev),
        [
            (10, 20, 3 * 64 + 5, 1),
            (2047, 2047, 3 * 64 + 63, 0),
            (1, 2, wrap - 64, 1),
            (3, 4, wrap + 7, 0)
        ]
    );
    assert_eq!(
        stats,
        Stats {
            untimed_events: 1,
            unknown_words: 1,
            truncated_bytes: 0
        }
    );
}

#[test]
fn evt3_single_events_vectors_and_time_words() {
    let bytes = evt3(&[
        0x2005,         // ADDR_X before any TIME_HIGH: no time base
        0x8001,         // TIME_HIGH 1
        0x6005,         // TIME_LOW 5
        0x0003,         // ADDR_Y 3
        0x2807,         // ADDR_X 7, polarity 1
        0x3800 | 100,   // VECT_BASE_X 100, polarity 1
        0x4000 | 0b101, // VECT_12: 100, 102; base 112
        0x5000 | 0b11,  // VECT_8: 112, 113; base 120
        0xA101,         // trigger, skipped
        0x1234,         // undefined type
        0x8002,         // TIME_HIGH 2: the low bits back to 0
        0x2009,
    ]);
    let (ev, stats) = decode(Encoding::Evt3, &bytes, 6, 12);
    let t = 4096 + 5;
    assert_eq!(
        rows(&ev),
        [
            (7, 3, t, 1),
            (100, 3, t, 1),
            (102, 3, t, 1),
            (112, 3, t, 1),
            (113, 3, t, 1),
            (9, 3, 8192, 0)
        ]
    );
    assert_eq!((stats.untimed_events, stats.unknown_words), (1, 1));
}

#[test]
fn evt3_time_high_wraps_only_on_a_drop_of_almost_its_range() {
    // 0xFFF -> 0x00A (drop 4085) is a wrap; 0x00A -> 0x009 is a step back in time, kept.
    let bytes = evt3(&[0x8FFF, 0x2001, 0x800A, 0x2002, 0x8009, 0x2003]);
    let (ev, _) = decode(Encoding::Evt3, &bytes, 1 << 10, 1 << 10);
    let wrap = 1i64 << 24;
    assert_eq!(ev.t, [0xFFF << 12, wrap + (0xA << 12), wrap + (0x9 << 12)]);
}

fn dat(records: &[(u32, u32, u32, u32)]) -> Vec<u8> {
    records
        .iter()
        .flat_map(|&(t, x, y, p)| [t.to_le_bytes(), (x | (y << 14) | (p << 28)).to_le_bytes()])
        .flatten()
        .collect()
}

#[test]
fn dat_records_unwrap_their_32_bit_time() {
    let bytes = dat(&[(5, 1, 2, 1), (u32::MAX, 16383, 16383, 0), (3, 4, 5, 1)]);
    let (ev, _) = decode(Encoding::Dat, &bytes, 8, 1);
    assert_eq!(
        rows(&ev),
        [
            (1, 2, 5, 1),
            (16383, 16383, u32::MAX as i64, 0),
            (4, 5, (1 << 32) + 3, 1)
        ]
    );
}

#[test]
fn truncated_input_keeps_every_complete_record_and_counts_the_rest() {
    let full = dat(&[(5, 1, 2, 1), (6, 3, 4, 0), (7, 5, 6, 1)]);
    for cut in 1..8 {
        let (ev, stats) = decode(Encoding::Dat, &full[..full.len() - cut], 8, 1 << 10);
        assert_eq!(ev.t, [5, 6]);
        assert_eq!(stats.truncated_bytes, 8 - cut as u64);
    }
    let (ev, stats) = decode(Encoding::Evt3, &evt3(&[0x8001, 0x2001, 0x2002])[..5], 3, 64);
    assert_eq!((ev.t.len(), stats.truncated_bytes), (1, 1));
}

#[test]
fn chunks_and_buffer_sizes_do_not_change_the_events() {
    let mut words = vec![0x8001u16, 0x6002, 0x0003];
    for i in 0..200u16 {
        words.extend([
            0x6000 | (i * 7 % 4096),
            0x3800 | i,
            0x4FFF,
            0x50AA,
            0x2000 | i,
        ]);
    }
    let bytes = evt3(&words);
    let (want, _) = decode(Encoding::Evt3, &bytes, 1 << 16, 1 << 16);
    assert_eq!(want.len(), 200 * (12 + 4 + 1));
    for (block, max_events) in [(2, 12), (3, 13), (7, 100), (1000, 25), (4096, 4096)] {
        let (got, _) = decode(Encoding::Evt3, &bytes, block, max_events);
        assert_eq!(got, want, "block {block}, chunk {max_events}");
    }
}
