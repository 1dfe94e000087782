//! The properties every input must keep, whatever its bytes: the fuzzers' oracle (the
//! proptest mutation tests here, the libFuzzer targets in fuzz/).

use std::time::{Duration, Instant};

use crate::{ChunkReader, Encoding, EventSource, Events, Stats};

/// Longest an input may take through all the decodes below (microseconds for the seeds): more
/// is a hang. Generous, since a shared machine can stall a thread for a second; libFuzzer's
/// `-timeout=1` (scripts/fuzz.sh) holds the one-second limit.
const HANG: Duration = Duration::from_secs(10);

/// Decodes `data` in several buffer and chunk sizes and panics unless: every chunk but the
/// last holds exactly `max_events` events, in vectors of at most twice that capacity (memory
/// bounded by the chunk, not the input); the events number at most the format's events per word times the
/// whole words; the trailing partial word is what `truncated_bytes` counts; buffer and chunk
/// sizes do not change the events or the counts (the state crosses boundaries); a truncated
/// copy decodes to a prefix of the events; and it all ends (`HANG`).
pub fn decode_checked(encoding: Encoding, data: &[u8]) -> (Events, Stats) {
    let start = Instant::now();
    let (events, stats) = decode_all(encoding, data, 1 << 16, 1 << 16);
    let (word, per_word) = (encoding.word(), encoding.max_per_word());
    assert!(
        events.len() <= data.len() / word * per_word,
        "more events than words allow"
    );
    assert_eq!(stats.truncated_bytes as usize, data.len() % word);
    for (block, max_events) in [(1, 1), (data.len() % 61 + 1, data.len() % 29 + 1)] {
        let other = decode_all(encoding, data, block, max_events);
        assert!(
            other == (events.clone(), stats),
            "block {block}, chunk {max_events} differ"
        );
    }
    let cut = data.len() * 2 / 3;
    let (head, head_stats) = decode_all(encoding, &data[..cut], 4096, 4096);
    assert_eq!(head_stats.truncated_bytes as usize, cut % word);
    assert_prefix(&head, &events);
    assert!(start.elapsed() < HANG, "took {:?}", start.elapsed());
    (events, stats)
}

/// Every event of `data`, read through a `block`-byte buffer in chunks of `max_events`.
pub fn decode_all(
    encoding: Encoding,
    data: &[u8],
    block: usize,
    max_events: usize,
) -> (Events, Stats) {
    let mut reader = ChunkReader::new(data, encoding, block);
    let all = drain(&mut reader, max_events, |_| {});
    (all, reader.stats())
}

/// The same properties for a ROS 1 bag (`rosbag::BagReader`, every event-array connection):
/// the reader refuses exactly the inputs without the bag line; chunks are full but the last
/// and hold at most twice `max_events` capacity; each record buffer holds at most twice the
/// input or the window of unpacked bytes (the largest unpacked chunk up to
/// `rosbag::MAX_WINDOW`: no allocation from a corrupt length or a chunk's declared size; a
/// chunk declared past the unpack ratio is refused, a large one read through the window); at
/// most one event per 13 unpacked
/// bytes; `truncated_bytes` within the input;
/// buffer and chunk sizes change nothing; a truncated copy decodes to a prefix; it all ends.
pub fn decode_bag_checked(data: &[u8]) -> Option<(Events, Stats)> {
    let start = Instant::now();
    let Some((events, stats, unpacked)) = decode_bag_all(data, 1 << 16, 1 << 16) else {
        assert!(!data.starts_with(crate::rosbag::MAGIC), "a bag refused");
        return None;
    };
    assert!(
        data.starts_with(crate::rosbag::MAGIC),
        "not a bag, yet read"
    );
    assert!(stats.truncated_bytes as usize <= data.len());
    assert!(
        events.len() * crate::rosbag::EVENT <= unpacked,
        "more events than unpacked bytes"
    );
    for (block, max_events) in [(1, 1), (data.len() % 61 + 1, data.len() % 29 + 1)] {
        let other = decode_bag_all(data, block, max_events);
        assert!(
            other == Some((events.clone(), stats, unpacked)),
            "block {block}, chunk {max_events} differ"
        );
    }
    let cut = data.len() * 2 / 3;
    if cut >= crate::rosbag::MAGIC.len() {
        let (head, _, _) = decode_bag_all(&data[..cut], 4096, 4096).expect("a cut bag opens");
        assert_prefix(&head, &events);
    }
    assert!(start.elapsed() < HANG, "took {:?}", start.elapsed());
    Some((events, stats))
}

/// Every event of the bag `data` through a `block`-byte read buffer in chunks of `max_events`,
/// its stats and the bytes its chunks unpacked to; None when it is not a bag.
pub fn decode_bag_all(
    data: &[u8],
    block: usize,
    max_events: usize,
) -> Option<(Events, Stats, usize)> {
    let mut reader = crate::rosbag::BagReader::new(data, None, block).ok()?;
    let all = drain(&mut reader, max_events, |r| {
        // Held memory: never the declared or unpacked size of a chunk, only the input and the
        // window (`rosbag::MAX_WINDOW`), each buffer at most twice the bytes it holds.
        let (buffers, largest, _) = r.buffers();
        let window = largest.min(crate::rosbag::MAX_WINDOW);
        assert_buffers(&buffers, data.len().max(window));
    });
    Some((all, reader.stats(), reader.buffers().2 as usize))
}

/// The same properties for AEDAT 4 packets (`aedat4::AedatReader`, stream 0, no data table):
/// the first byte of `data` picks the compression (its value mod 3: none, LZ4, Zstd), the rest
/// is the packets. Chunks full but the last and of bounded capacity; the packet buffers at most
/// twice the input or the largest unpacked packet (no allocation from a corrupt size); at most
/// one event per 16 unpacked bytes; `truncated_bytes` within the input; buffer and chunk sizes
/// change nothing; a truncated copy decodes to a prefix; it all ends.
pub fn decode_aedat_checked(data: &[u8]) -> (Events, Stats) {
    let start = Instant::now();
    let (events, stats, unpacked) = decode_aedat_all(data, 1 << 16, 1 << 16);
    assert!(stats.truncated_bytes as usize <= data.len());
    assert!(
        events.len() * crate::aedat4::EVENT <= unpacked,
        "more events than unpacked bytes"
    );
    for (block, max_events) in [(1, 1), (data.len() % 61 + 1, data.len() % 29 + 1)] {
        let other = decode_aedat_all(data, block, max_events);
        assert!(
            other == (events.clone(), stats, unpacked),
            "block {block}, chunk {max_events} differ"
        );
    }
    let cut = data.len() * 2 / 3;
    let (head, _, _) = decode_aedat_all(&data[..cut], 4096, 4096);
    assert_prefix(&head, &events);
    assert!(start.elapsed() < HANG, "took {:?}", start.elapsed());
    (events, stats)
}

/// Every event of the AEDAT 4 packets in `data` (first byte: the compression) through a
/// `block`-byte read buffer in chunks of `max_events`, its stats and its unpacked bytes.
pub fn decode_aedat_all(data: &[u8], block: usize, max_events: usize) -> (Events, Stats, usize) {
    use crate::aedat4::{AedatReader, Compression};
    let (compression, packets) = match data.split_first() {
        Some((&c, rest)) => (
            [Compression::None, Compression::Lz4, Compression::Zstd][c as usize % 3],
            rest,
        ),
        None => (Compression::None, data),
    };
    let mut reader = AedatReader::new(packets, compression, 0, 0, -1, block);
    let all = drain(&mut reader, max_events, |r| {
        let (buffers, largest, _) = r.buffers();
        assert_buffers(&buffers, data.len().max(largest));
    });
    (all, reader.stats(), reader.buffers().2 as usize)
}

/// The bag properties for an MCAP file (`mcap::McapReader`, every event-array channel): the
/// reader refuses exactly the inputs without the magic; at most one event per 13 unpacked
/// bytes (a message's first event is packed); the rest as `decode_bag_checked`.
pub fn decode_mcap_checked(data: &[u8]) -> Option<(Events, Stats)> {
    let start = Instant::now();
    let Some((events, stats, unpacked)) = decode_mcap_all(data, 1 << 16, 1 << 16) else {
        assert!(
            !data.starts_with(crate::mcap::MAGIC),
            "an MCAP file refused"
        );
        return None;
    };
    assert!(data.starts_with(crate::mcap::MAGIC), "not MCAP, yet read");
    assert!(stats.truncated_bytes as usize <= data.len());
    assert!(
        events.len() * 13 <= unpacked,
        "more events than unpacked bytes"
    );
    for (block, max_events) in [(1, 1), (data.len() % 61 + 1, data.len() % 29 + 1)] {
        let other = decode_mcap_all(data, block, max_events);
        assert!(
            other == Some((events.clone(), stats, unpacked)),
            "block {block}, chunk {max_events} differ"
        );
    }
    let cut = data.len() * 2 / 3;
    if cut >= crate::mcap::MAGIC.len() {
        let (head, _, _) = decode_mcap_all(&data[..cut], 4096, 4096).expect("a cut file opens");
        assert_prefix(&head, &events);
    }
    assert!(start.elapsed() < HANG, "took {:?}", start.elapsed());
    Some((events, stats))
}

/// Every event of the MCAP file `data` through a `block`-byte read buffer in chunks of
/// `max_events`, its stats and the bytes it unpacked (whole records read count too); None
/// when it is not MCAP.
pub fn decode_mcap_all(
    data: &[u8],
    block: usize,
    max_events: usize,
) -> Option<(Events, Stats, usize)> {
    let mut reader = crate::mcap::McapReader::new(data, None, block).ok()?;
    let all = drain(&mut reader, max_events, |r| {
        let (buffers, largest, _) = r.buffers();
        assert_buffers(&buffers, data.len().max(largest));
    });
    let unpacked = data.len() + reader.buffers().2 as usize;
    Some((all, reader.stats(), unpacked))
}

/// A message-compressed bag's zstd frame (`unpack::Frames`, as the .db3 and MCAP readers
/// unpack one), after `before` through the same unpacker: it unpacks to at most
/// `unpack::cap` of its size (a bomb is an error, not an allocation), its buffer held within
/// twice the larger cap of the two, and it all ends (`HANG`). Returns the unpacked bytes.
pub fn unpack_frame_checked(before: &[u8], frame: &[u8]) -> Option<Vec<u8>> {
    let start = Instant::now();
    let mut frames = crate::unpack::Frames::new().expect("a zstd context");
    let _ = frames.unpack(before);
    let unpacked = frames.unpack(frame).ok().map(<[u8]>::to_vec);
    let cap = crate::unpack::cap(frame.len() as u64) as usize;
    let held = cap.max(crate::unpack::cap(before.len() as u64) as usize);
    assert!(
        unpacked.as_ref().is_none_or(|u| u.len() <= cap),
        "past the cap"
    );
    assert!(
        frames.capacity() <= 2 * (held + 1),
        "a buffer of {}",
        frames.capacity()
    );
    assert!(start.elapsed() < HANG, "took {:?}", start.elapsed());
    unpacked
}

/// Every event of `reader` in chunks of `max_events`, asserting that each chunk but the last
/// is full, that its vectors hold at most twice `max_events` (Vec's smallest allocation, 8
/// elements, is the floor), and `each` (the reader's own bounds) after every chunk.
fn drain<S: EventSource>(reader: &mut S, max_events: usize, mut each: impl FnMut(&S)) -> Events {
    let limit = max_events.max(1);
    let mut all = Events::default();
    let mut last = limit;
    loop {
        let chunk = match reader.next_chunk(max_events) {
            Ok(chunk) => chunk,
            Err(e) => panic!("reading a slice failed: {e}"),
        };
        assert!(chunk.len() <= limit, "chunk of {} > {limit}", chunk.len());
        let capacity = [chunk.x.capacity(), chunk.y.capacity(), chunk.t.capacity()];
        assert!(
            capacity.iter().all(|&c| c <= (2 * limit).max(8)),
            "chunk capacity {capacity:?}"
        );
        each(reader);
        if chunk.is_empty() {
            return all;
        }
        assert!(last == limit, "a chunk of {last} < {limit} before the end");
        last = chunk.len();
        all.x.extend(chunk.x);
        all.y.extend(chunk.y);
        all.t.extend(chunk.t);
        all.p.extend(chunk.p);
    }
}

/// Every buffer at most twice `held` bytes (at least 32): what a reader may hold for an input.
fn assert_buffers(buffers: &[usize], held: usize) {
    let bound = 2 * held.max(32);
    assert!(
        buffers.iter().all(|&c| c <= bound),
        "buffers {buffers:?} > {bound}"
    );
}

/// `head` (the events of a truncated copy) is a prefix of `events`.
fn assert_prefix(head: &Events, events: &Events) {
    let n = head.len();
    assert!(n <= events.len(), "a truncated copy has more events");
    assert!(
        head.x == events.x[..n]
            && head.y == events.y[..n]
            && head.t == events.t[..n]
            && head.p == events.p[..n],
        "a truncated copy's events are not a prefix"
    );
}
