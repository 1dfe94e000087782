//! Each decoder on words written by hand from the format's spec.

use crate::check::decode_all as decode;
use crate::{Encoding, EventSource, Events, Stats};

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

/// A ROS 1 bag record: header fields, then data.
fn record(fields: &[(&str, &[u8])], data: &[u8]) -> Vec<u8> {
    let mut header = Vec::new();
    for (name, value) in fields {
        header.extend(((name.len() + 1 + value.len()) as u32).to_le_bytes());
        header.extend(name.as_bytes());
        header.push(b'=');
        header.extend(*value);
    }
    let mut out = (header.len() as u32).to_le_bytes().to_vec();
    out.extend(header);
    out.extend((data.len() as u32).to_le_bytes());
    out.extend(data);
    out
}

fn connection(id: u32, topic: &str, msgtype: &str) -> Vec<u8> {
    let data = record(
        &[("topic", topic.as_bytes()), ("type", msgtype.as_bytes())],
        b"",
    );
    // A connection's data is a bare header: the record framing less its data length.
    let data = &data[4..data.len() - 4];
    record(
        &[
            ("op", &[0x07]),
            ("conn", &id.to_le_bytes()),
            ("topic", topic.as_bytes()),
        ],
        data,
    )
}

/// An EventArray message on `conn` with events (x, y, sec, nsec, polarity).
fn event_message(conn: u32, events: &[(u16, u16, u32, u32, u8)]) -> Vec<u8> {
    let mut data = Vec::new();
    data.extend(7u32.to_le_bytes()); // seq
    data.extend([0u8; 8]); // stamp
    data.extend(3u32.to_le_bytes());
    data.extend(b"cam");
    data.extend(240u32.to_le_bytes()); // height
    data.extend(320u32.to_le_bytes()); // width
    data.extend((events.len() as u32).to_le_bytes());
    for &(x, y, s, ns, p) in events {
        data.extend(x.to_le_bytes());
        data.extend(y.to_le_bytes());
        data.extend(s.to_le_bytes());
        data.extend(ns.to_le_bytes());
        data.push(p);
    }
    record(&[("op", &[0x02]), ("conn", &conn.to_le_bytes())], &data)
}

fn chunk(compression: &str, records: &[u8]) -> Vec<u8> {
    let size = (records.len() as u32).to_le_bytes();
    record(
        &[
            ("op", &[0x05]),
            ("compression", compression.as_bytes()),
            ("size", &size),
        ],
        records,
    )
}

fn bag(records: &[Vec<u8>]) -> Vec<u8> {
    let mut out = crate::rosbag::MAGIC.to_vec();
    out.extend(record(
        &[("op", &[0x03]), ("index_pos", &0u64.to_le_bytes())],
        &[b' '; 100],
    ));
    out.extend(records.concat());
    out
}

/// Every event a reader's `next_chunk` gives in chunks of `max_events`, until an empty one.
fn drain(
    mut next_chunk: impl FnMut(usize) -> std::io::Result<Events>,
    max_events: usize,
) -> std::io::Result<Events> {
    let mut all = Events::default();
    loop {
        let c = next_chunk(max_events)?;
        if c.is_empty() {
            return Ok(all);
        }
        all.x.extend(c.x);
        all.y.extend(c.y);
        all.t.extend(c.t);
        all.p.extend(c.p);
    }
}

fn decode_bag(data: &[u8], topic: Option<&str>) -> (Events, Stats) {
    let mut reader = crate::rosbag::BagReader::new(data, topic, 7).expect("a bag");
    let all = drain(|n| reader.next_chunk(n), 2).expect("a slice reads");
    (all, reader.stats())
}

#[test]
fn bag_reader_takes_event_arrays_of_the_chosen_topic_in_file_order() {
    let first = [(1, 2, 10, 5_999, 1), (3, 4, 10, 1_000_000, 0)];
    let second = [(5, 6, 11, 999_999_999, 2)];
    let other = [(9, 9, 1, 1, 1)];
    let mut records = connection(0, "/dvs/events", "dvs_msgs/EventArray");
    records.extend(connection(1, "/other", "prophesee_event_msgs/EventArray"));
    records.extend(connection(2, "/pose", "geometry_msgs/PoseStamped"));
    records.extend(event_message(0, &first));
    records.extend(event_message(1, &other));
    records.extend(record(
        &[("op", &[0x02]), ("conn", &2u32.to_le_bytes())],
        b"pose",
    ));
    // One byte more than the count says: another layout, skipped and counted.
    let mut bad = event_message(0, &first);
    let at = 4 + u32::from_le_bytes([bad[0], bad[1], bad[2], bad[3]]) as usize;
    let len = u32::from_le_bytes([bad[at], bad[at + 1], bad[at + 2], bad[at + 3]]) + 1;
    bad[at..at + 4].copy_from_slice(&len.to_le_bytes());
    bad.push(0);
    let data = bag(&[chunk("none", &records), chunk("none", &bad), {
        let mut c = event_message(0, &second);
        c = chunk("none", &c);
        c
    }]);
    let (ev, stats) = decode_bag(&data, Some("/dvs/events"));
    assert_eq!(
        rows(&ev),
        [
            (1, 2, 10_000_005, 1),
            (3, 4, 10_001_000, 0),
            (5, 6, 11_999_999, 1)
        ]
    );
    assert_eq!((stats.unknown_words, stats.truncated_bytes), (1, 0));
    let (all, _) = decode_bag(&data, None);
    assert_eq!(all.len(), 4); // both event-array topics
    let conns = crate::rosbag::bag_connections(std::io::Cursor::new(&data), 16).expect("a bag");
    let names: Vec<_> = conns
        .iter()
        .map(|c| (c.id, c.topic.as_str(), c.msgtype.as_str()))
        .collect();
    assert_eq!(
        names,
        [
            (0, "/dvs/events", "dvs_msgs/EventArray"),
            (1, "/other", "prophesee_event_msgs/EventArray"),
            (2, "/pose", "geometry_msgs/PoseStamped")
        ]
    );
}

#[test]
fn bag_reader_unpacks_lz4_and_bz2_chunks() {
    use std::io::Write;
    let events: Vec<_> = (0..500)
        .map(|i| (i as u16, 7, 3, i * 1000, (i % 2) as u8))
        .collect();
    let mut records = connection(4, "/e", "dvs_msgs/EventArray");
    records.extend(event_message(4, &events));
    let mut lz4 = lz4_flex::frame::FrameEncoder::new(Vec::new());
    lz4.write_all(&records).expect("in memory");
    let lz4 = lz4.finish().expect("in memory");
    let mut bz2 = bzip2::write::BzEncoder::new(Vec::new(), bzip2::Compression::best());
    bz2.write_all(&records).expect("in memory");
    let bz2 = bz2.finish().expect("in memory");
    let size = (records.len() as u32).to_le_bytes();
    for (name, packed) in [("lz4", lz4), ("bz2", bz2)] {
        let data = bag(&[record(
            &[
                ("op", &[0x05]),
                ("compression", name.as_bytes()),
                ("size", &size),
            ],
            &packed,
        )]);
        let (ev, stats) = decode_bag(&data, None);
        assert_eq!(ev.len(), 500, "{name}");
        assert_eq!(ev.t[499], 3_000_000 + 499, "{name}");
        assert_eq!(stats, Stats::default(), "{name}");
    }
}

#[test]
fn cut_bag_keeps_the_messages_before_the_cut_and_counts_the_bytes_of_its_last_record() {
    let a = event_message(0, &[(1, 1, 1, 0, 1)]);
    let b = event_message(0, &[(2, 2, 2, 0, 0)]);
    let mut records = connection(0, "/e", "dvs_msgs/EventArray");
    records.extend(&a);
    records.extend(&b);
    let whole = bag(&[chunk("none", &records)]);
    let cut = &whole[..whole.len() - 3];
    let (ev, stats) = decode_bag(cut, None);
    assert_eq!(rows(&ev), [(1, 1, 1_000_000, 1)]);
    let chunk_bytes = chunk("none", &records).len() - 3;
    assert_eq!(stats.truncated_bytes as usize, chunk_bytes);
    assert_eq!(stats.unknown_words, 0);
    assert!(crate::rosbag::BagReader::new(&b"#ROSBAG V1.2\n"[..], None, 8).is_err());
}

/// A bag of one compressed chunk (`lz4` or `bz2`) holding `records`, its size declared.
fn packed_bag(compression: &str, records: &[u8], cut: usize) -> Vec<u8> {
    use std::io::Write;
    let packed = if compression == "lz4" {
        let mut enc = lz4_flex::frame::FrameEncoder::new(Vec::new());
        enc.write_all(records).expect("in memory");
        enc.finish().expect("in memory")
    } else {
        let mut enc = bzip2::write::BzEncoder::new(Vec::new(), bzip2::Compression::fast());
        enc.write_all(records).expect("in memory");
        enc.finish().expect("in memory")
    };
    let size = (records.len() as u32).to_le_bytes();
    bag(&[record(
        &[
            ("op", &[0x05]),
            ("compression", compression.as_bytes()),
            ("size", &size),
        ],
        &packed[..packed.len() - cut],
    )])
}

#[test]
fn a_chunk_larger_than_the_reader_holds_streams_through_its_window() {
    // 700,000 events (9.1 MB) and a 3 MB message of another topic between them: more than
    // `IN_MEMORY`, so the chunk is checked by a first decode and then streamed.
    let events: Vec<(u16, u16, u32, u32, u8)> = (0..700_000u32)
        .map(|i| {
            let (x, y) = ((i * 7 % 1280) as u16, (i / 1280 % 720) as u16);
            (x, y, i / 1000, i % 1000 * 1000 + i % 7, (i % 3 == 0) as u8)
        })
        .collect();
    let mut records = connection(0, "/e", "dvs_msgs/EventArray");
    records.extend(connection(1, "/image", "sensor_msgs/Image"));
    records.extend(event_message(0, &events[..300_000]));
    records.extend(record(
        &[("op", &[0x02]), ("conn", &1u32.to_le_bytes())],
        &vec![5u8; 3 << 20],
    ));
    records.extend(event_message(0, &events[300_000..]));
    assert!(records.len() > crate::rosbag::IN_MEMORY);
    let expected: Vec<_> = events
        .iter()
        .map(|&(x, y, s, ns, p)| (x, y, s as i64 * 1_000_000 + ns as i64 / 1000, p as i8))
        .collect();
    for compression in ["lz4", "bz2"] {
        let data = packed_bag(compression, &records, 0);
        let (ev, stats) = decode_bag(&data, Some("/e"));
        assert!(rows(&ev) == expected, "{compression}");
        assert_eq!(stats, Stats::default(), "{compression}");
        // All or nothing: the stream cut short fails in the first decode, so no event is
        // emitted from the start of the chunk (which decodes).
        let damaged = packed_bag(compression, &records, 100);
        let (ev, stats) = decode_bag(&damaged, None);
        assert_eq!((ev.len(), stats.unknown_words), (0, 1), "{compression}");
    }
    // The fuzzers' properties, window bound included.
    let lz4 = packed_bag("lz4", &records, 0);
    let (ev, _) = crate::check::decode_bag_checked(&lz4).expect("a bag");
    assert_eq!(ev.len(), events.len());
}

#[test]
fn a_bag_chunk_declared_past_the_unpack_ratio_is_refused_before_decoding() {
    // 400,000 copies of one event (5.2 MB): bzip2 packs them into a few hundred bytes, a
    // bomb made of valid events. Refused whole from its declared size, without decoding, so
    // a chunk's time is bounded by its compressed bytes.
    let mut records = connection(0, "/e", "dvs_msgs/EventArray");
    records.extend(event_message(0, &vec![(3, 4, 1, 0, 1); 400_000]));
    let data = packed_bag("bz2", &records, 0);
    assert!(records.len() as u64 > crate::unpack::cap(data.len() as u64));
    let (ev, stats) = decode_bag(&data, None);
    assert_eq!((ev.len(), stats.unknown_words), (0, 1));
    // Distinct events, packed a few times: read.
    let events: Vec<_> = (0..20_000u32)
        .map(|i| ((i % 640) as u16, (i / 640) as u16, 1, i * 37, (i % 2) as u8))
        .collect();
    let mut records = connection(0, "/e", "dvs_msgs/EventArray");
    records.extend(event_message(0, &events));
    let (ev, stats) = decode_bag(&packed_bag("bz2", &records, 0), None);
    assert_eq!((ev.len(), stats), (events.len(), Stats::default()));
}

/// An AEDAT 4 event packet (size-prefixed flatbuffer, "EVTS") in its framing: stream id, size.
fn aedat_packet(stream: i32, events: &[(i64, i16, i16, bool)]) -> Vec<u8> {
    let mut fb = Vec::new();
    fb.extend(14u32.to_le_bytes()); // root: the table at 14
    fb.extend(b"EVTS");
    fb.extend([6u8, 0, 8, 0, 4, 0]); // vtable at 8: its size, the table's, field 0 at +4
    fb.extend(6i32.to_le_bytes()); // table at 14: the vtable 6 bytes before
    fb.extend(4u32.to_le_bytes()); // field 0: the vector 4 bytes on, at 22
    fb.extend((events.len() as u32).to_le_bytes());
    for &(t, x, y, on) in events {
        fb.extend(t.to_le_bytes());
        fb.extend(x.to_le_bytes());
        fb.extend(y.to_le_bytes());
        fb.extend([on as u8, 0, 0, 0]);
    }
    let mut packet = (fb.len() as u32).to_le_bytes().to_vec();
    packet.extend(fb);
    let mut out = stream.to_le_bytes().to_vec();
    out.extend((packet.len() as u32).to_le_bytes());
    out.extend(packet);
    out
}

#[test]
fn aedat_reader_takes_the_event_packets_of_its_stream_and_drops_a_cut_one() {
    use crate::aedat4::{AedatReader, Compression};
    let mut data = aedat_packet(
        0,
        &[
            (1_700_000_000_000_001, 5, 6, true),
            (1_700_000_000_000_002, 345, 259, false),
        ],
    );
    data.extend(aedat_packet(3, &[(9, 9, 9, true)])); // another stream: skipped
    let mut bad = aedat_packet(0, &[(3, 1, 1, true)]);
    bad[16..20].copy_from_slice(b"FRME"); // not an event packet: counted
    data.extend(bad);
    data.extend(aedat_packet(0, &[(1_700_000_000_000_003, 0, 1, true)]));
    let whole = data.len();
    data.extend(&aedat_packet(0, &[(4, 4, 4, true)])[..20]);
    let mut reader = AedatReader::new(&data[..], Compression::None, 0, 0, -1, 5);
    let mut ev = Events::default();
    loop {
        let c = reader.next_chunk(1).expect("a slice reads");
        if c.is_empty() {
            break;
        }
        ev.push(c.x[0], c.y[0], c.t[0], c.p[0]);
    }
    assert_eq!(
        rows(&ev),
        [
            (5, 6, 1_700_000_000_000_001, 1),
            (345, 259, 1_700_000_000_000_002, 0),
            (0, 1, 1_700_000_000_000_003, 1)
        ]
    );
    let stats = reader.stats();
    assert_eq!((stats.unknown_words, stats.truncated_bytes), (1, 20));
    // The data table's position ends the packets.
    let mut reader = AedatReader::new(&data[..], Compression::None, 0, 100, 100 + whole as i64, 5);
    assert_eq!(reader.next_chunk(10).expect("a slice reads").len(), 3);
    assert_eq!(reader.stats().truncated_bytes, 0);
}

/// An MCAP record: op, u64 length, content.
fn mcap_record(op: u8, content: &[u8]) -> Vec<u8> {
    let mut out = vec![op];
    out.extend((content.len() as u64).to_le_bytes());
    out.extend(content);
    out
}

fn mcap_string(s: &[u8]) -> Vec<u8> {
    let mut out = (s.len() as u32).to_le_bytes().to_vec();
    out.extend(s);
    out
}

/// A CDR EventArray message on `channel`: events (x, y, sec, nanosec, polarity).
fn mcap_message(channel: u16, events: &[(u16, u16, i32, u32, u8)]) -> Vec<u8> {
    mcap_message_packed(channel, events, |cdr| cdr)
}

/// The same, its CDR bytes through `pack` (rosbag2's zstd per message).
fn mcap_message_packed(
    channel: u16,
    events: &[(u16, u16, i32, u32, u8)],
    pack: impl Fn(Vec<u8>) -> Vec<u8>,
) -> Vec<u8> {
    let mut cdr = vec![0u8, 1, 0, 0]; // little-endian CDR
    cdr.extend(5i32.to_le_bytes()); // stamp
    cdr.extend(0u32.to_le_bytes());
    cdr.extend(mcap_string(b"cam\0")); // frame_id: 4 bytes with its NUL, so aligned
    cdr.extend(240u32.to_le_bytes());
    cdr.extend(320u32.to_le_bytes());
    cdr.extend((events.len() as u32).to_le_bytes());
    for (i, &(x, y, s, ns, p)) in events.iter().enumerate() {
        if i > 0 {
            cdr.push(0); // x aligns to 2 after the previous polarity
        }
        cdr.extend(x.to_le_bytes());
        cdr.extend(y.to_le_bytes());
        if i > 0 {
            cdr.extend([0, 0]); // sec aligns to 4
        }
        cdr.extend(s.to_le_bytes());
        cdr.extend(ns.to_le_bytes());
        cdr.push(p);
    }
    let mut content = channel.to_le_bytes().to_vec();
    content.extend([0u8; 20]); // sequence, log and publish times
    content.extend(pack(cdr));
    mcap_record(0x05, &content)
}

fn decode_mcap(data: &[u8]) -> (Events, Stats) {
    let mut reader = crate::mcap::McapReader::new(data, None, 7).expect("an MCAP file");
    let all = drain(|n| reader.next_chunk(n), 2).expect("a slice reads");
    (all, reader.stats())
}

#[test]
fn mcap_reader_takes_cdr_event_arrays_from_chunks_and_drops_a_cut_chunk() {
    let mut schema = 7u16.to_le_bytes().to_vec();
    schema.extend(mcap_string(b"dvs_msgs/msg/EventArray"));
    let mut channel = 3u16.to_le_bytes().to_vec();
    channel.extend(7u16.to_le_bytes());
    channel.extend(mcap_string(b"/events"));
    let mut records = mcap_record(0x03, &schema);
    records.extend(mcap_record(0x04, &channel));
    records.extend(mcap_message(
        3,
        &[(1, 2, 10, 5_999, 1), (3, 4, 11, 1_000_000, 0)],
    ));
    records.extend(mcap_message(9, &[(9, 9, 9, 9, 1)])); // no such channel: skipped
    records.extend(mcap_message(3, &[(5, 6, 12, 999_999_999, 2)]));
    let chunk = |records: &[u8]| {
        let mut c = [0u8; 16].to_vec(); // start and end times
        c.extend((records.len() as u64).to_le_bytes());
        c.extend(0u32.to_le_bytes()); // CRC (unchecked)
        c.extend(mcap_string(b""));
        c.extend((records.len() as u64).to_le_bytes());
        c.extend(records);
        mcap_record(0x06, &c)
    };
    let mut data = crate::mcap::MAGIC.to_vec();
    data.extend(mcap_record(
        0x01,
        &[mcap_string(b"ros2"), mcap_string(b"test")].concat(),
    ));
    data.extend(chunk(&records));
    let whole = data.clone();
    let (ev, stats) = decode_mcap(&whole);
    assert_eq!(
        rows(&ev),
        [
            (1, 2, 10_000_005, 1),
            (3, 4, 11_001_000, 0),
            (5, 6, 12_999_999, 1)
        ]
    );
    assert_eq!(stats, Stats::default());
    // A second chunk cut by the end of the file: dropped whole, its bytes counted.
    let second = chunk(&mcap_message(3, &[(7, 7, 13, 0, 1)]));
    data.extend(&second[..second.len() - 5]);
    let (ev, stats) = decode_mcap(&data);
    assert_eq!(ev.len(), 3);
    assert_eq!(stats.truncated_bytes as usize, second.len() - 5);
    let channels = crate::mcap::mcap_channels(std::io::Cursor::new(&whole), 16).expect("MCAP");
    assert_eq!(channels[0].topic, "/events");
    assert_eq!(channels[0].msgtype, "dvs_msgs/msg/EventArray");
}

/// A CDR EventArray (ROS 2) with events (x, y, sec, nsec, polarity), laid out by hand.
fn cdr_event_array(events: &[(u16, u16, i32, u32, u8)]) -> Vec<u8> {
    let mut b = vec![0, 1, 0, 0];
    b.extend(5i32.to_le_bytes()); // stamp
    b.extend(6u32.to_le_bytes());
    b.extend(4u32.to_le_bytes()); // frame id "cam" and its NUL: 16 bytes after the header
    b.extend(b"cam\0");
    b.extend(240u32.to_le_bytes());
    b.extend(320u32.to_le_bytes());
    b.extend((events.len() as u32).to_le_bytes());
    for (i, &(x, y, s, ns, p)) in events.iter().enumerate() {
        if i > 0 {
            b.push(0); // pads x to 2 bytes
        }
        b.extend(x.to_le_bytes());
        b.extend(y.to_le_bytes());
        if i > 0 {
            b.extend([0, 0]); // pads sec to 4 bytes
        }
        b.extend(s.to_le_bytes());
        b.extend(ns.to_le_bytes());
        b.push(p);
    }
    b
}

fn db3_all(
    paths: &[std::path::PathBuf],
    topic: &str,
    compression: crate::Ros2Compression,
    chunk: usize,
    max_events: usize,
) -> std::io::Result<(Events, Stats)> {
    let mut reader = crate::db3::Db3Reader::new(paths, topic, compression, chunk)?;
    let next = |n| {
        let c = reader.next_chunk(n)?;
        assert!(c.len() <= n);
        Ok(c)
    };
    let all = drain(next, max_events)?;
    Ok((all, reader.stats()))
}

/// A .db3 file as rosbag2 lays it out: topics 1 ("/other") and 2 ("/dvs/events"), and the
/// messages (topic id, timestamp, data) inserted in the given order.
fn make_db3(path: &std::path::Path, messages: &[(i64, i64, Vec<u8>)]) -> std::path::PathBuf {
    let _ = std::fs::remove_file(path);
    let db = rusqlite::Connection::open(path).expect("a new database");
    db.execute_batch(
        "CREATE TABLE topics (id INTEGER PRIMARY KEY, name TEXT NOT NULL, type TEXT NOT NULL,
           serialization_format TEXT NOT NULL, offered_qos_profiles TEXT NOT NULL);
         CREATE TABLE messages (id INTEGER PRIMARY KEY, topic_id INTEGER NOT NULL,
           timestamp INTEGER NOT NULL, data BLOB NOT NULL);
         CREATE INDEX timestamp_idx ON messages (timestamp ASC);
         INSERT INTO topics VALUES (1, '/other', 'dvs_msgs/msg/EventArray', 'cdr', '');
         INSERT INTO topics VALUES (2, '/dvs/events', 'dvs_msgs/msg/EventArray', 'cdr', '');",
    )
    .expect("the bag tables");
    for (topic, stamp, data) in messages {
        db.execute(
            "INSERT INTO messages (topic_id, timestamp, data) VALUES (?1, ?2, ?3)",
            rusqlite::params![topic, stamp, data],
        )
        .expect("a message");
    }
    path.to_path_buf()
}

const PLAIN: crate::Ros2Compression = crate::Ros2Compression::None;

#[test]
fn db3_reader_takes_a_topics_event_arrays_in_timestamp_order_across_files() {
    let dir = std::env::temp_dir().join(format!("evsplat-db3-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("a temp folder");
    let make = |name: &str, messages: &[(i64, i64, Vec<u8>)]| make_db3(&dir.join(name), messages);
    let a = cdr_event_array(&[(1, 2, 10, 5_999, 1), (3, 4, 10, 1_000_000, 0)]);
    let b = cdr_event_array(&[(5, 6, 11, 999_999_999, 1)]);
    let c = cdr_event_array(&[(7, 8, 12, 0, 0)]);
    let mut bad = cdr_event_array(&[(9, 9, 1, 1, 1)]);
    bad.extend([0; 4]); // four bytes more than the count allows: another layout
                        // Inserted out of order: the reader orders by timestamp.
    let first = make(
        "first.db3",
        &[(2, 200, b), (1, 50, c.clone()), (2, 100, a), (2, 150, bad)],
    );
    let second = make("second.db3", &[(2, 300, c)]);
    // The thread's chunks handed over whole, split, and gathered from several.
    let files = [first.clone(), second.clone()];
    let (ev, stats) = db3_all(&files, "/dvs/events", PLAIN, 3, 3).expect("reads");
    for (chunk, max_events) in [(1, 1), (2, 3), (1 << 20, 2), (3, 1 << 20)] {
        let other = db3_all(&files, "/dvs/events", PLAIN, chunk, max_events).expect("reads");
        assert!(
            other == (ev.clone(), stats),
            "chunk {chunk}, max {max_events} differ"
        );
    }
    assert_eq!(
        rows(&ev),
        [
            (1, 2, 10_000_005, 1),
            (3, 4, 10_001_000, 0),
            (5, 6, 11_999_999, 1),
            (7, 8, 12_000_000, 0)
        ]
    );
    assert_eq!(stats.unknown_words, 1);
    let topics = crate::db3::db3_topics(&first).expect("topics");
    assert_eq!(topics[1].name, "/dvs/events");
    // Not a database: an error naming the file, when opened.
    let junk = dir.join("junk.db3");
    std::fs::write(&junk, [7u8; 4096]).expect("a file");
    let err = db3_all(&[first, junk.clone()], "/dvs/events", PLAIN, 2, 2).expect_err("junk fails");
    assert!(
        err.to_string().contains(&junk.display().to_string()),
        "{err}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// This process's temporary .db3 files (the unpacked copies of `NAME.db3.zstd` files).
fn temp_db3s() -> Vec<std::path::PathBuf> {
    let prefix = format!("evsplat-{}-", std::process::id());
    let listed = std::fs::read_dir(std::env::temp_dir()).expect("the temp folder");
    (listed.flatten())
        .map(|e| e.path())
        .filter(|p| {
            (p.file_name().and_then(|n| n.to_str()))
                .is_some_and(|n| n.starts_with(&prefix) && n.ends_with(".db3"))
        })
        .collect()
}

#[test]
fn db3_reader_unpacks_zstd_messages_and_files_within_bounds_and_leaves_no_temp_file() {
    use crate::Ros2Compression as Compression;
    let dir = std::env::temp_dir().join(format!("evsplat-db3-zstd-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("a temp folder");
    let a = cdr_event_array(&[(1, 2, 10, 5_999, 1), (3, 4, 10, 1_000_000, 0)]);
    let b = cdr_event_array(&[(5, 6, 11, 999_999_999, 1)]);
    let messages = [(2, 200, b), (1, 50, a.clone()), (2, 100, a)];
    let plain = make_db3(&dir.join("plain.db3"), &messages);
    let (want, _) =
        db3_all(std::slice::from_ref(&plain), "/dvs/events", PLAIN, 2, 2).expect("reads");
    assert_eq!(want.len(), 3);
    // Streamed (no size in the frame) and in one call (the size declared, as rosbag2 writes).
    let zstd = |data: &[u8]| zstd::stream::encode_all(data, 3).expect("zstd");
    let sized = |data: &[u8]| zstd::bulk::compress(data, 3).expect("zstd");
    // "message": each message's data a zstd frame, of both kinds.
    let framed: Vec<_> = (messages.iter().enumerate())
        .map(|(i, (topic, stamp, data))| {
            let frame = if i % 2 == 0 { zstd(data) } else { sized(data) };
            (*topic, *stamp, frame)
        })
        .collect();
    let per_message = make_db3(&dir.join("message.db3"), &framed);
    let read = |path: &std::path::PathBuf, how| {
        db3_all(std::slice::from_ref(path), "/dvs/events", how, 2, 2)
    };
    assert_eq!(
        read(&per_message, Compression::Message).expect("reads").0,
        want
    );
    // "file": the whole .db3 one zstd stream, unpacked into a temporary file, then removed.
    let whole = dir.join("plain.db3.zstd");
    std::fs::write(&whole, zstd(&std::fs::read(&plain).expect("the .db3"))).expect("written");
    let before = temp_db3s();
    let files = [whole.clone(), whole.clone()];
    let (twice, _) = db3_all(&files, "/dvs/events", Compression::File, 1, 1).expect("reads");
    assert_eq!(rows(&twice), [rows(&want), rows(&want)].concat());
    // A reader dropped after its first chunk: its thread stops and removes its copy too.
    let mut early =
        crate::db3::Db3Reader::new(&files, "/dvs/events", Compression::File, 1).expect("opens");
    assert_eq!(early.next_chunk(1).expect("a chunk").len(), 1);
    drop(early);
    // A damaged frame, a decompression bomb (zeros: far more than 256 bytes per byte) and a
    // cut file: one error naming the file (and the message), no temporary file left.
    let mut bad = framed.clone();
    bad[2].2[6] ^= 0xff;
    let zeros = vec![0u8; 64 << 20];
    let (bomb, sized_bomb) = ((2, 300, zstd(&zeros)), (2, 300, sized(&zeros)));
    for (name, messages, what) in [
        ("damaged.db3", bad, "message 1 of /dvs/events: zstd"),
        (
            "bomb.db3",
            vec![bomb],
            "more than 256 bytes per compressed byte",
        ),
        (
            "sized.db3",
            vec![sized_bomb],
            "more than 256 bytes per compressed byte",
        ),
    ] {
        let path = make_db3(&dir.join(name), &messages);
        let err = read(&path, Compression::Message).expect_err("fails");
        let msg = err.to_string();
        assert!(
            msg.starts_with(&path.display().to_string()) && msg.contains(what),
            "{msg}"
        );
    }
    let data = std::fs::read(&whole).expect("the .zstd");
    let cut = dir.join("cut.db3.zstd");
    std::fs::write(&cut, &data[..data.len() / 2]).expect("written");
    let err = read(&cut, Compression::File).expect_err("a cut file fails");
    assert!(
        err.to_string().starts_with(&cut.display().to_string()),
        "{err}"
    );
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(10);
    while temp_db3s() != before && std::time::Instant::now() < deadline {
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    assert_eq!(temp_db3s(), before, "a temporary .db3 left behind");
    let _ = std::fs::remove_dir_all(&dir);
}

/// A CDR event: x, y, sec, nanosec, polarity.
type CdrEvent = (u16, u16, i32, u32, u8);

/// An MCAP file of top-level records: the event-array schema, `channel` on "/events", and a
/// message of each event list there, its CDR bytes through `pack`.
fn mcap_file(
    channel: u16,
    messages: &[&[CdrEvent]],
    pack: impl Fn(Vec<u8>) -> Vec<u8> + Copy,
) -> Vec<u8> {
    let mut schema = 7u16.to_le_bytes().to_vec();
    schema.extend(mcap_string(b"dvs_msgs/msg/EventArray"));
    let mut chan = channel.to_le_bytes().to_vec();
    chan.extend(7u16.to_le_bytes());
    chan.extend(mcap_string(b"/events"));
    let mut data = crate::mcap::MAGIC.to_vec();
    data.extend(mcap_record(0x03, &schema));
    data.extend(mcap_record(0x04, &chan));
    for events in messages {
        data.extend(mcap_message_packed(channel, events, pack));
    }
    data
}

#[test]
fn split_mcap_files_read_one_after_another_in_full_chunks() {
    let dir = std::env::temp_dir().join(format!("evsplat-mcap-split-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("a temp folder");
    let first: &[CdrEvent] = &[(1, 2, 10, 0, 1), (3, 4, 10, 5_000, 0)];
    let second: &[CdrEvent] = &[(5, 6, 11, 0, 1)];
    let third: &[CdrEvent] = &[(7, 8, 12, 0, 0), (9, 9, 12, 1_000, 1)];
    // Each file its own channel ids (rosbag2 writes every split file whole); the first ends
    // in a cut record, counted in the stats.
    let mut a = mcap_file(3, &[first, second], |cdr| cdr);
    a.extend(&mcap_message(3, third)[..10]);
    let paths = [dir.join("bag_0.mcap"), dir.join("bag_1.mcap")];
    std::fs::write(&paths[0], &a).expect("written");
    std::fs::write(&paths[1], mcap_file(1, &[third], |cdr| cdr)).expect("written");
    let read = |paths: &[std::path::PathBuf], n: usize| {
        let mut reader =
            crate::mcap::McapFiles::new(paths, Some("/events"), crate::Ros2Compression::None, 7)?;
        let size = reader.sensor_size()?;
        let mut chunks = Vec::new();
        loop {
            let c = reader.next_chunk(n)?;
            if c.is_empty() {
                return Ok::<_, std::io::Error>((chunks, size, reader.stats()));
            }
            chunks.push(c);
        }
    };
    let (chunks, size, stats) = read(&paths, 2).expect("reads");
    assert_eq!(size, Some((320, 240)));
    assert_eq!(stats.truncated_bytes, 10);
    let lens: Vec<_> = chunks.iter().map(Events::len).collect();
    assert_eq!(
        lens,
        [2, 2, 1],
        "only the last chunk short, across the files"
    );
    let all: Vec<_> = chunks.iter().flat_map(rows).collect();
    assert_eq!(
        all,
        [
            (1, 2, 10_000_000, 1),
            (3, 4, 10_000_005, 0),
            (5, 6, 11_000_000, 1),
            (7, 8, 12_000_000, 0),
            (9, 9, 12_000_001, 1)
        ]
    );
    // A listed file that is not MCAP: an error naming it, once the reading reaches it.
    let junk = dir.join("bag_2.mcap");
    std::fs::write(&junk, b"not an MCAP file").expect("written");
    let err = read(&[paths[0].clone(), junk.clone()], 100).expect_err("fails");
    assert!(
        err.to_string().starts_with(&junk.display().to_string()),
        "{err}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn mcap_files_compressed_per_message_or_per_file_read_as_plain_ones() {
    use crate::Ros2Compression as Compression;
    let dir = std::env::temp_dir().join(format!("evsplat-mcap-zstd-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("a temp folder");
    let messages: [&[CdrEvent]; 2] = [
        &[(1, 2, 10, 0, 1), (3, 4, 10, 5_000, 0)],
        &[(5, 6, 11, 0, 1)],
    ];
    let read = |path: &std::path::Path, compression| {
        let paths = [path.to_path_buf()];
        let mut reader = crate::mcap::McapFiles::new(&paths, Some("/events"), compression, 7)?;
        let all = drain(|n| reader.next_chunk(n), 2)?;
        Ok::<_, std::io::Error>((rows(&all), reader.stats()))
    };
    let plain = dir.join("plain.mcap");
    std::fs::write(&plain, mcap_file(3, &messages, |cdr| cdr)).expect("written");
    let (want, stats) = read(&plain, Compression::None).expect("reads");
    assert_eq!((want.len(), stats), (3, Stats::default()));
    // "message": each message's data a zstd frame (rosbag2 declares its size).
    let sized = |cdr: Vec<u8>| zstd::bulk::compress(&cdr, 3).expect("zstd");
    let per_message = dir.join("message.mcap");
    std::fs::write(&per_message, mcap_file(3, &messages, sized)).expect("written");
    assert_eq!(
        read(&per_message, Compression::Message).expect("reads"),
        (want.clone(), stats)
    );
    // A frame that does not unpack: that message counted, the others read.
    let broken = |cdr: Vec<u8>| {
        if cdr.len() > 50 {
            sized(cdr)[..20].to_vec()
        } else {
            sized(cdr)
        }
    };
    let damaged = dir.join("damaged.mcap");
    std::fs::write(&damaged, mcap_file(3, &messages, broken)).expect("written");
    let (rest, stats) = read(&damaged, Compression::Message).expect("reads");
    assert_eq!((rest.as_slice(), stats.unknown_words), (&want[2..], 1));
    // "file": the whole file one zstd stream, unpacked as it is read.
    let whole = dir.join("plain.mcap.zstd");
    let packed = zstd::stream::encode_all(&std::fs::read(&plain).expect("read")[..], 3);
    std::fs::write(&whole, packed.expect("zstd")).expect("written");
    assert_eq!(
        read(&whole, Compression::File).expect("reads"),
        (want.clone(), Stats::default())
    );
    // Cut short inside its zstd frame: read up to the last whole record, as a cut .mcap is,
    // the record it ends in counted as truncated; the same cut of the plain file reads alike.
    // (Flushed every 48 bytes: zstd unpacks whole blocks, so a cut inside the only block of a
    // file this small would leave nothing.)
    let plain_bytes = std::fs::read(&plain).expect("read");
    let mut encoder = zstd::stream::write::Encoder::new(Vec::new(), 3).expect("zstd");
    for piece in plain_bytes.chunks(48) {
        std::io::Write::write_all(&mut encoder, piece).expect("packed");
        std::io::Write::flush(&mut encoder).expect("a block");
    }
    let packed = encoder.finish().expect("zstd");
    let mut lost = 0;
    for keep in [packed.len() / 3, packed.len() * 2 / 3, packed.len() - 1] {
        let cut = dir.join("cut.mcap.zstd");
        std::fs::write(&cut, &packed[..keep]).expect("written");
        let (got, stats) = read(&cut, Compression::File).expect("a cut file reads");
        assert!(want.starts_with(&got), "{keep}: {got:?}");
        // What the cut frame unpacks to is a prefix of the plain file: cut the plain file there.
        let mut prefix = Vec::new();
        let cut_reader = std::fs::File::open(&cut).expect("opened");
        let mut dec = unpack_prefix(cut_reader);
        std::io::Read::read_to_end(&mut dec, &mut prefix).expect("a prefix");
        assert!(plain_bytes.starts_with(&prefix));
        let cut_plain = dir.join("cut.mcap");
        std::fs::write(&cut_plain, &prefix).expect("written");
        let expected = read(&cut_plain, Compression::None).expect("reads");
        lost += usize::from(got.len() < want.len() && stats.truncated_bytes > 0);
        assert_eq!((got, stats), expected, "{keep}");
    }
    assert!(lost >= 2, "the cuts inside the data lose events and say so");
    // A damaged frame is still an error, naming the file.
    let mut damaged = packed.clone();
    let middle = damaged.len() / 2;
    damaged[middle..middle + 8].copy_from_slice(&[0xff; 8]);
    let bad = dir.join("bad.mcap.zstd");
    std::fs::write(&bad, &damaged).expect("written");
    let err = read(&bad, Compression::File).expect_err("a damaged frame fails");
    assert!(
        err.to_string().starts_with(&bad.display().to_string()),
        "{err}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// What a cut zstd file unpacks to before its cut.
fn unpack_prefix(file: std::fs::File) -> impl std::io::Read {
    crate::unpack::EndsWhereCut(zstd::stream::read::Decoder::new(file).expect("a decoder"))
}
