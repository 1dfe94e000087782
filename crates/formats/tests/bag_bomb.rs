//! A decompression bomb in a ROS 1 bag: a small file whose compressed chunk declares 4 GiB and
//! unpacks to 128 MiB of one valid event message. The reader must stream it through its
//! window: the peak of the bytes allocated while it reads (a counting global allocator, so
//! this file is its own test binary with one test) stays bounded by constants and the input,
//! far below what the chunk unpacks to.

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

/// The chunk's records: the events connection and one EventArray message of `n` zero events.
fn records(n: usize) -> Vec<u8> {
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
    data.resize(data.len() + 13 * n, 0);
    out.extend(record(
        &[("op", &[0x02]), ("conn", &0u32.to_le_bytes())],
        &data,
    ));
    out
}

fn bag(compression: &str, packed: &[u8]) -> Vec<u8> {
    let mut out = evsplat_formats::rosbag::MAGIC.to_vec();
    out.extend(record(
        &[
            ("op", &[0x05]),
            ("compression", compression.as_bytes()),
            ("size", &u32::MAX.to_le_bytes()),
        ],
        packed,
    ));
    out
}

/// (events, sum of every column, peak bytes allocated while reading above the start).
fn read(bag: &[u8]) -> (usize, i64, usize) {
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
    assert_eq!(reader.stats(), Default::default());
    (n, sum, PEAK.load(Ordering::SeqCst) - base)
}

#[test]
fn a_decompression_bomb_is_read_in_bounded_memory() {
    let n = 128 << 20 >> 4; // ~8.4 M events, 109 MB of records
    let plain = records(n);
    let mut bz2 = bzip2::write::BzEncoder::new(Vec::new(), bzip2::Compression::best());
    bz2.write_all(&plain).expect("in memory");
    let bz2 = bag("bz2", &bz2.finish().expect("in memory"));
    // The largest blocks a frame header may declare, linked: lz4_flex's biggest buffers.
    let info = lz4_flex::frame::FrameInfo::new()
        .block_size(lz4_flex::frame::BlockSize::Max4MB)
        .block_mode(lz4_flex::frame::BlockMode::Linked);
    let mut lz4 = lz4_flex::frame::FrameEncoder::with_frame_info(info, Vec::new());
    lz4.write_all(&plain).expect("in memory");
    let lz4 = bag("lz4", &lz4.finish().expect("in memory"));
    drop(plain);
    // Constants: the window's buffer (at most twice MAX_WINDOW), LZ4's header-sized buffers
    // (4 MiB + 2 x 4 MiB + 64 KiB), one chunk of 2^16 events, the 4 MiB read buffer; and twice
    // the input.
    let events = (1 << 16) * 13 * 2;
    let constant = 2 * MAX_WINDOW + (12 << 20) + (64 << 10) + events + (4 << 20);
    for (name, file) in [("bz2", &bz2), ("lz4", &lz4)] {
        let (got, sum, peak) = read(file);
        let bound = constant + 2 * file.len();
        eprintln!(
            "{name}: {} byte bag, chunk of {} bytes declared {}; peak {peak} bytes (bound {bound})",
            file.len(),
            records(0).len() + 13 * n,
            u32::MAX
        );
        assert_eq!((got, sum), (n, 0), "{name}");
        assert!(peak <= bound, "{name}: peak {peak} > {bound}");
        assert!(
            peak < 13 * n / 2,
            "{name}: peak {peak} is not far below the chunk"
        );
    }
}
