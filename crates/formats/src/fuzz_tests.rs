//! Mutation fuzzing on stable Rust: the seed corpus (fuzz/seeds, valid words from the
//! project's writer) mutated by proptest (bit flips, truncation, inserted and deleted bytes,
//! random words, splices) and run through `check::decode_checked`. PROPTEST_CASES sets the
//! inputs per decoder (256 by default); a failure is shrunk to a small input and becomes a
//! named regression test below.

use std::path::Path;

use proptest::prelude::*;

use crate::check::{
    decode_aedat_checked, decode_bag_checked, decode_checked, decode_mcap_checked,
    unpack_frame_checked,
};
use crate::Encoding;

/// The seed files of one encoding, in name order.
fn seeds(folder: &str) -> Vec<Vec<u8>> {
    // cargo sets CARGO_MANIFEST_DIR when it runs the tests; env! would bake in the checkout the
    // binary was compiled in, which a target directory shared with CI's checkout reuses.
    let manifest = std::env::var("CARGO_MANIFEST_DIR")
        .unwrap_or_else(|_| env!("CARGO_MANIFEST_DIR").to_string());
    let dir = Path::new(&manifest).join("fuzz/seeds").join(folder);
    let mut paths: Vec<_> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("{}: {e}; run scripts/fuzz_seeds.py", dir.display()))
        .map(|entry| entry.expect("a seed directory entry").path())
        .collect();
    paths.sort();
    paths
        .iter()
        .map(|p| std::fs::read(p).expect("a seed file"))
        .collect()
}

#[derive(Debug, Clone)]
enum Mutation {
    FlipBit(usize, u8),
    Truncate(usize),
    Insert(usize, Vec<u8>),
    Delete(usize, usize),
    /// A random word of the format's size written over the bytes at a word boundary.
    Word(usize, u64),
    /// The tail of another seed from a position on.
    Splice(usize, usize, usize),
}

fn mutation() -> impl Strategy<Value = Mutation> {
    let at = any::<usize>();
    prop_oneof![
        (at, 0..8u8).prop_map(|(i, b)| Mutation::FlipBit(i, b)),
        at.prop_map(Mutation::Truncate),
        (at, prop::collection::vec(any::<u8>(), 1..16)).prop_map(|(i, b)| Mutation::Insert(i, b)),
        (at, 1..64usize).prop_map(|(i, n)| Mutation::Delete(i, n)),
        (at, any::<u64>()).prop_map(|(i, w)| Mutation::Word(i, w)),
        (at, any::<usize>(), any::<usize>()).prop_map(|(i, s, j)| Mutation::Splice(i, s, j)),
    ]
}

fn mutate(seeds: &[Vec<u8>], data: &mut Vec<u8>, m: &Mutation, word: usize) {
    let pos = |i: usize, len: usize| if len == 0 { 0 } else { i % len };
    match *m {
        Mutation::FlipBit(i, b) if !data.is_empty() => {
            let i = pos(i, data.len());
            data[i] ^= 1 << b;
        }
        Mutation::Truncate(i) => data.truncate(pos(i, data.len() + 1)),
        Mutation::Insert(i, ref bytes) => {
            let i = pos(i, data.len() + 1);
            data.splice(i..i, bytes.iter().copied());
        }
        Mutation::Delete(i, n) => {
            let i = pos(i, data.len() + 1);
            data.drain(i..(i + n).min(data.len()));
        }
        Mutation::Word(i, w) if data.len() >= word => {
            let i = pos(i, data.len() / word) * word;
            data[i..i + word].copy_from_slice(&w.to_le_bytes()[..word]);
        }
        Mutation::Splice(i, s, j) => {
            let other = &seeds[s % seeds.len()];
            data.truncate(pos(i, data.len() + 1));
            data.extend_from_slice(&other[pos(j, other.len() + 1)..]);
        }
        _ => {}
    }
}

fn fuzz(encoding: Encoding, folder: &str, seed: usize, mutations: &[Mutation]) {
    let seeds = seeds(folder);
    let mut data = seeds[seed % seeds.len()].clone();
    for m in mutations {
        mutate(&seeds, &mut data, m, encoding.word());
    }
    decode_checked(encoding, &data);
}

fn fuzz_bag(seed: usize, mutations: &[Mutation]) {
    let seeds = seeds("rosbag");
    let mut data = seeds[seed % seeds.len()].clone();
    for m in mutations {
        mutate(&seeds, &mut data, m, 4);
    }
    decode_bag_checked(&data);
}

fn fuzz_aedat(seed: usize, mutations: &[Mutation]) {
    let seeds = seeds("aedat4");
    let mut data = seeds[seed % seeds.len()].clone();
    for m in mutations {
        mutate(&seeds, &mut data, m, 8);
    }
    decode_aedat_checked(&data);
}

#[test]
fn aedat_seeds_decode_to_sorted_events_and_drop_nothing() {
    for data in seeds("aedat4") {
        let (events, stats) = decode_aedat_checked(&data);
        assert!(events.len() >= 200 && events.t.windows(2).all(|w| w[0] <= w[1]));
        assert_eq!(stats, Default::default());
    }
}

fn fuzz_mcap(seed: usize, mutations: &[Mutation]) {
    let seeds = seeds("mcap");
    let mut data = seeds[seed % seeds.len()].clone();
    for m in mutations {
        mutate(&seeds, &mut data, m, 8);
    }
    decode_mcap_checked(&data);
}

#[test]
fn mcap_seeds_decode_to_sorted_events_and_drop_nothing() {
    for data in seeds("mcap") {
        let (events, stats) = decode_mcap_checked(&data).expect("a seed file opens");
        assert!(events.len() >= 200 && events.t.windows(2).all(|w| w[0] <= w[1]));
        assert_eq!(stats, Default::default());
    }
}

#[test]
fn bag_seeds_decode_to_sorted_events_and_drop_nothing() {
    for data in seeds("rosbag") {
        let (events, stats) = decode_bag_checked(&data).expect("a seed bag opens");
        assert!(events.len() >= 200 && events.t.windows(2).all(|w| w[0] <= w[1]));
        assert_eq!(stats, Default::default());
    }
}

#[test]
fn seeds_decode_to_sorted_events_and_drop_nothing() {
    for (encoding, folder) in [
        (Encoding::Evt2, "evt2"),
        (Encoding::Evt3, "evt3"),
        (Encoding::Dat, "dat"),
    ] {
        for data in seeds(folder) {
            let (events, stats) = decode_checked(encoding, &data);
            assert!(events.len() >= 200 && events.t.windows(2).all(|w| w[0] <= w[1]));
            assert_eq!(stats, Default::default());
        }
    }
}

proptest! {
    #[test]
    fn evt2_decoder_keeps_its_properties_on_mutated_files(
        seed in any::<usize>(), m in prop::collection::vec(mutation(), 1..8)
    ) {
        fuzz(Encoding::Evt2, "evt2", seed, &m);
    }

    #[test]
    fn evt3_decoder_keeps_its_properties_on_mutated_files(
        seed in any::<usize>(), m in prop::collection::vec(mutation(), 1..8)
    ) {
        fuzz(Encoding::Evt3, "evt3", seed, &m);
    }

    #[test]
    fn dat_decoder_keeps_its_properties_on_mutated_files(
        seed in any::<usize>(), m in prop::collection::vec(mutation(), 1..8)
    ) {
        fuzz(Encoding::Dat, "dat", seed, &m);
    }

    #[test]
    fn rosbag_reader_keeps_its_properties_on_mutated_files(
        seed in any::<usize>(), m in prop::collection::vec(mutation(), 1..8)
    ) {
        fuzz_bag(seed, &m);
    }

    #[test]
    fn aedat4_reader_keeps_its_properties_on_mutated_files(
        seed in any::<usize>(), m in prop::collection::vec(mutation(), 1..8)
    ) {
        fuzz_aedat(seed, &m);
    }

    #[test]
    fn mcap_reader_keeps_its_properties_on_mutated_files(
        seed in any::<usize>(), m in prop::collection::vec(mutation(), 1..8)
    ) {
        fuzz_mcap(seed, &m);
    }

    #[test]
    fn random_records_after_the_mcap_magic_keep_the_properties(
        data in prop::collection::vec(any::<u8>(), 0..4096)
    ) {
        let mut file = crate::mcap::MAGIC.to_vec();
        file.extend(data);
        decode_mcap_checked(&file);
    }

    #[test]
    fn random_records_after_the_bag_line_keep_the_properties(
        data in prop::collection::vec(any::<u8>(), 0..4096)
    ) {
        let mut bag = crate::rosbag::MAGIC.to_vec();
        bag.extend(data);
        decode_bag_checked(&bag);
    }

    #[test]
    fn random_bytes_keep_the_properties(data in prop::collection::vec(any::<u8>(), 0..4096)) {
        for encoding in [Encoding::Evt2, Encoding::Evt3, Encoding::Dat] {
            decode_checked(encoding, &data);
        }
        decode_bag_checked(&data);
        decode_aedat_checked(&data);
        decode_mcap_checked(&data);
    }

    #[test]
    fn zstd_frames_of_bag_messages_unpack_within_the_cap_when_mutated(
        seed in any::<usize>(), m in prop::collection::vec(mutation(), 1..8), level in 1..4i32
    ) {
        // The seed files' bytes as messages of a message-compressed bag: in one call (the
        // size declared) and streamed, mutated (the size field, the blocks, cut, spliced).
        let seeds = seeds("mcap");
        let message = &seeds[seed % seeds.len()];
        let sized = zstd::bulk::compress(message, level).expect("zstd");
        let mut frame = sized.clone();
        for m in &m {
            mutate(std::slice::from_ref(&sized), &mut frame, m, 1);
        }
        let streamed = zstd::stream::encode_all(&message[..], level).expect("zstd");
        prop_assert_eq!(unpack_frame_checked(&frame, &sized), Some(message.clone()));
        prop_assert_eq!(unpack_frame_checked(&sized, &streamed), Some(message.clone()));
        unpack_frame_checked(&streamed, &frame);
    }

    #[test]
    fn random_bytes_after_the_zstd_magic_unpack_within_the_cap(
        data in prop::collection::vec(any::<u8>(), 0..4096)
    ) {
        let mut frame = vec![0x28, 0xb5, 0x2f, 0xfd];
        frame.extend(data);
        unpack_frame_checked(&[], &frame);
    }
}
