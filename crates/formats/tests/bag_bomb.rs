//! A ROS 1 bag read in bounded memory and time (a counting global allocator, so this file is
//! its own test binary with one test): a decompression bomb, a small file whose compressed
//! chunk unpacks to 109 MB of one valid event message, is refused from its declared size
//! before any decoding; a large chunk of a real bag's ratio streams through the reader's
//! window, the peak of the bytes allocated bounded by constants and the input, far below what
//! the chunk unpacks to.

use std::alloc::{GlobalAlloc, Layout, System};
use std::io::Write;
use std::sync::atomic::{AtomicUsize, Ordering};

use evsplat_formats::rosbag::{BagReader, MAX_WINDOW};
use evsplat_formats::EventSource;

struct Counting;

static NOW: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let now = NOW.fetch_add(layout.size(), Ordering::SeqCst) + layout.size();
        PEAK.fetch_max(now, Ordering::SeqCst);
        // SAFETY: the caller's layout, passed on unchanged.
        unsafe { System.alloc(layout) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        NOW.fetch_sub(layout.size(), Ordering::SeqCst);
        // SAFETY: `ptr` came from `alloc` above with this layout.
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static ALLOC: Counting = Counting;

/// A record: u32 header length, `name=value` fields, u32 data length, data.
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

/// The chunk's records: the events connection and one EventArray message of `n` events,
/// event `i` made by `event(i)` (13 bytes: x, y, ts sec, ts nsec, polarity).
fn records(n: usize, event: impl Fn(u32) -> [u8; 13]) -> Vec<u8> {
    let mut out = record(
        &[
            ("op", &[0x07]),
            ("conn", &0u32.to_le_bytes()),
            ("topic", b"/dvs/events"),
        ],
        &record(&[("type", b"dvs_msgs/EventArray")], &[])[4..],
    );
    let mut data = Vec::with_capacity(31 + 13 * n);
    data.extend([0u8; 12]); // seq, stamp
    data.extend(3u32.to_le_bytes());
    data.extend(b"cam");
    data.extend(480u32.to_le_bytes());
    data.extend(640u32.to_le_bytes());
    data.extend((n as u32).to_le_bytes());
    for i in 0..n as u32 {
        data.extend(event(i));
    }
    out.extend(record(
        &[("op", &[0x02]), ("conn", &0u32.to_le_bytes())],
        &data,
    ));
    out
}

/// A sensor's events: bursts of 64 along a row (one timestamp each, 1 ms apart), rows in
/// turn, polarity flipping from burst to burst; bzip2 packs them about 20 times, LZ4 about 3.
fn scan(i: u32) -> [u8; 13] {
    let burst = i / 64;
    let mut e = [0u8; 13];
    e[0..2].copy_from_slice(&((100 + i % 64) as u16).to_le_bytes());
    e[2..4].copy_from_slice(&((burst % 480) as u16).to_le_bytes());
    e[4..8].copy_from_slice(&(burst / 1000).to_le_bytes());
    e[8..12].copy_from_slice(&(burst % 1000 * 1_000_000).to_le_bytes());
    e[12] = (burst % 2) as u8;
    e
}

/// A bag of one chunk of `records`, compressed with `compression` (`bz2` or `lz4`, the latter
/// in the largest blocks a frame header may declare, linked: lz4_flex's biggest buffers), its
/// size declared.
fn bag(compression: &str, records: &[u8]) -> Vec<u8> {
    let packed = if compression == "bz2" {
        let mut bz2 = bzip2::write::BzEncoder::new(Vec::new(), bzip2::Compression::best());
        bz2.write_all(records).expect("in memory");
        bz2.finish().expect("in memory")
    } else {
        let info = lz4_flex::frame::FrameInfo::new()
            .block_size(lz4_flex::frame::BlockSize::Max4MB)
            .block_mode(lz4_flex::frame::BlockMode::Linked);
        let mut lz4 = lz4_flex::frame::FrameEncoder::with_frame_info(info, Vec::new());
        lz4.write_all(records).expect("in memory");
        lz4.finish().expect("in memory")
    };
    let mut out = evsplat_formats::rosbag::MAGIC.to_vec();
    out.extend(record(
        &[
            ("op", &[0x05]),
            ("compression", compression.as_bytes()),
            ("size", &(records.len() as u32).to_le_bytes()),
        ],
        &packed,
    ));
    out
}

/// (events, sum of every column, chunks refused, peak bytes allocated while reading above the
/// start, seconds).
fn read(bag: &[u8]) -> (usize, i64, u64, usize, f64) {
    let start = std::time::Instant::now();
    let base = NOW.load(Ordering::SeqCst);
    PEAK.store(base, Ordering::SeqCst);
    let mut reader = BagReader::new(bag, None, 1 << 22).expect("a bag");
    let (mut n, mut sum) = (0, 0i64);
    loop {
        let chunk = reader.next_chunk(1 << 16).expect("a slice reads");
        if chunk.is_empty() {
            break;
        }
        n += chunk.len();
        sum += chunk.t.iter().sum::<i64>();
        sum += chunk.x.iter().map(|&v| i64::from(v)).sum::<i64>();
        sum += chunk.y.iter().map(|&v| i64::from(v)).sum::<i64>();
        sum += chunk.p.iter().map(|&v| i64::from(v)).sum::<i64>();
    }
    let stats = reader.stats();
    assert_eq!((stats.truncated_bytes, stats.untimed_events), (0, 0));
    let peak = PEAK.load(Ordering::SeqCst) - base;
    (
        n,
        sum,
        stats.unknown_words,
        peak,
        start.elapsed().as_secs_f64(),
    )
}

#[test]
fn a_bag_is_read_in_bounded_memory_and_a_bomb_is_refused_before_decoding() {
    let n = 128 << 20 >> 4; // ~8.4 M events, 109 MB of records
                            // Constants: the window's buffer (at most twice MAX_WINDOW), LZ4's header-sized buffers
                            // (4 MiB + 2 x 4 MiB + 64 KiB), one chunk of 2^16 events, the 4 MiB read buffer; and twice
                            // the input.
    let events = (1 << 16) * 13 * 2;
    let constant = 2 * MAX_WINDOW + (12 << 20) + (64 << 10) + events + (4 << 20);
    let bomb = records(n, |_| [0u8; 13]);
    let sensor = records(n, scan);
    let (x, y, t, p) = (0..n as u32).fold((0i64, 0i64, 0i64, 0i64), |acc, i| {
        let e = scan(i);
        let (sec, nsec) = (
            u32::from_le_bytes([e[4], e[5], e[6], e[7]]),
            u32::from_le_bytes([e[8], e[9], e[10], e[11]]),
        );
        (
            acc.0 + i64::from(u16::from_le_bytes([e[0], e[1]])),
            acc.1 + i64::from(u16::from_le_bytes([e[2], e[3]])),
            acc.2 + i64::from(sec) * 1_000_000 + i64::from(nsec) / 1000,
            acc.3 + i64::from(e[12]),
        )
    });
    // LZ4 cannot pack more than 255 times (the reader's ratio, 256, is LZ4's own limit plus a
    // margin): its "bomb" is read, through the window. bzip2 packs the zeros ~370,000 times:
    // refused. (LZ4 packs the sensor's events 3 times only: too little for the peak to show
    // the window.)
    let cases = [
        ("bz2", "bomb", &bomb, None),
        ("bz2", "sensor", &sensor, Some(x + y + t + p)),
        ("lz4", "bomb", &bomb, Some(0)),
    ];
    for (compression, name, plain, expected) in cases {
        let file = bag(compression, plain);
        let (got, sum, refused, peak, seconds) = read(&file);
        let bound = constant + 2 * file.len();
        eprintln!(
            "{compression} {name}: {} byte bag, chunk of {} bytes ({:.0}x); {got} events, \
             {refused} refused, peak {peak} bytes (bound {bound}), {seconds:.3} s",
            file.len(),
            plain.len(),
            plain.len() as f64 / file.len() as f64,
        );
        assert!(peak <= bound, "{compression} {name}: peak {peak} > {bound}");
        assert!(peak < plain.len() / 2, "{compression} {name}: peak {peak}");
        match expected {
            Some(s) => assert_eq!((got, sum, refused), (n, s, 0), "{compression} {name}"),
            None => assert_eq!((got, refused), (0, 1), "{compression} {name}"),
        }
    }
}
