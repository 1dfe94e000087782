//! HDF5 chunks compressed as the Blosc filter (HDF5 filter id 32001, hdf5-blosc, as
//! `hdf5plugin.Blosc()` sets it up) compresses them with LZ4 and byte shuffle, so the event
//! writer compresses a chunk here, without the GIL, and hands HDF5 the finished bytes
//! (`H5Dwrite_chunk`) instead of running the filter on its own thread.
//!
//! The output is a Blosc 1 buffer (format version 2) as c-blosc 1.x lays it out: a 16-byte
//! header (version, compressor version, flags, type size, then little-endian u32 `nbytes`,
//! `blocksize`, `cbytes`); one i32 start offset per block, counted from the buffer's start;
//! then per block its splits (one per byte of the type when the block is split, else one),
//! each an i32 length and an LZ4 block, or the split's bytes as they are when LZ4 does not
//! make them smaller. Block sizes and the split rule follow c-blosc's for the same `clevel`,
//! so chunks decode with any Blosc 1 or 2 reader. LZ4 is lz4_flex's block compressor, which
//! searches as LZ4 does at acceleration 1 (c-blosc uses `10 - clevel`, 5 at the default
//! level): on event columns its chunks are 10% smaller than c-blosc's and no slower to make.

/// Bytes of a Blosc 1 header.
pub const HEADER: usize = 16;
/// Blosc's buffer format version (c-blosc 1.x `BLOSC_VERSION_FORMAT`).
const VERSION_FORMAT: u8 = 2;
/// Blosc's format version for LZ4 streams.
const LZ4_VERSION_FORMAT: u8 = 1;
/// Blosc's compressor code for LZ4, stored in the flags' top three bits.
const LZ4_CODE: u8 = 1;
const FLAG_SHUFFLE: u8 = 0x01;
const FLAG_MEMCPYED: u8 = 0x02;
const FLAG_DONT_SPLIT: u8 = 0x10;
/// Buffers smaller than this are stored as they are (c-blosc's `MIN_BUFFERSIZE`).
const MIN_BUFFER: usize = 128;
/// Types wider than this are not split into one stream per byte.
const MAX_SPLITS: usize = 16;
/// c-blosc's L1 size, the unit of its block sizes.
const L1: usize = 32 * 1024;
/// Types wider than this are compressed as bytes (c-blosc's `BLOSC_MAX_TYPESIZE`).
const MAX_TYPESIZE: usize = 255;

/// What the Blosc filter produced for one chunk.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Filtered {
    /// `out` holds the Blosc buffer: write it with filter mask 0.
    Compressed,
    /// The Blosc buffer would be larger than the chunk: the filter (optional in HDF5) gives up
    /// and HDF5 stores the chunk's bytes as they are, with filter mask 1; `out` is empty.
    Raw,
}

/// Compresses chunks, keeping its buffers (the shuffled block, LZ4's output) from one chunk to
/// the next.
#[derive(Debug, Default)]
pub struct Compressor {
    shuffled: Vec<u8>,
    lz4: Vec<u8>,
}

impl Compressor {
    /// Compresses `chunk` (whole elements of `typesize` bytes, zero-padded to the dataset's chunk
    /// size as HDF5 pads an edge chunk) into `out` (cleared first) as the HDF5 Blosc filter does
    /// with LZ4 at `clevel` (0-9), byte-shuffled if `shuffle`.
    ///
    /// Panics if `chunk` is 2 GiB or more (HDF5 chunks are under 4 GiB, Blosc's under 2 GiB) or
    /// `typesize` is 0; the caller checks both once.
    pub fn compress_chunk(
        &mut self,
        chunk: &[u8],
        typesize: usize,
        clevel: u8,
        shuffle: bool,
        out: &mut Vec<u8>,
    ) -> Filtered {
        out.clear();
        let nbytes = chunk.len();
        assert!(
            nbytes <= i32::MAX as usize - HEADER,
            "a Blosc buffer is under 2 GiB"
        );
        assert!(typesize > 0, "typesize is at least 1");
        let typesize = if typesize > MAX_TYPESIZE { 1 } else { typesize };
        let clevel = clevel.min(9);
        let blocksize = block_size(clevel, typesize, nbytes);
        let split = splits(typesize, blocksize);
        let mut flags = (LZ4_CODE << 5) | if split { 0 } else { FLAG_DONT_SPLIT };
        if shuffle {
            flags |= FLAG_SHUFFLE;
        }
        let memcpyed = clevel == 0 || nbytes < MIN_BUFFER;
        if memcpyed {
            flags |= FLAG_MEMCPYED;
        }
        out.extend_from_slice(&[VERSION_FORMAT, LZ4_VERSION_FORMAT, flags, typesize as u8]);
        for v in [nbytes, blocksize, 0] {
            out.extend_from_slice(&(v as u32).to_le_bytes());
        }
        if memcpyed {
            out.extend_from_slice(chunk);
        } else {
            let nblocks = nbytes.div_ceil(blocksize);
            out.resize(HEADER + 4 * nblocks, 0);
            let Self { shuffled, lz4 } = self;
            for (j, block) in chunk.chunks(blocksize).enumerate() {
                let start = out.len() as u32;
                out[HEADER + 4 * j..HEADER + 4 * j + 4].copy_from_slice(&start.to_le_bytes());
                let data = if shuffle && typesize > 1 {
                    if shuffled.len() < block.len() {
                        shuffled.resize(block.len(), 0);
                    }
                    let shuffled = &mut shuffled[..block.len()];
                    byte_shuffle(block, typesize, shuffled);
                    &shuffled[..]
                } else {
                    block
                };
                // c-blosc splits whole blocks only, never the shorter last one.
                let nsplits = if split && block.len() == blocksize {
                    typesize
                } else {
                    1
                };
                for stream in data.chunks_exact(data.len() / nsplits) {
                    push_split(stream, lz4, out);
                }
                if out.len() > nbytes {
                    break; // larger than the chunk: stored raw (below)
                }
            }
        }
        if out.len() > nbytes {
            // The filter compresses into a buffer of the chunk's size and gives up past it.
            out.clear();
            return Filtered::Raw;
        }
        let cbytes = out.len() as u32;
        out[12..16].copy_from_slice(&cbytes.to_le_bytes());
        Filtered::Compressed
    }
}

/// One split: its i32 length, then its LZ4 block (made in `lz4`), or its bytes as they are
/// when LZ4 does not make them smaller (a reader copies a split whose length equals its size).
fn push_split(stream: &[u8], lz4: &mut Vec<u8>, out: &mut Vec<u8>) {
    let bound = lz4_flex::block::get_maximum_output_size(stream.len());
    if lz4.len() < bound {
        lz4.resize(bound, 0);
    }
    let n = lz4_flex::block::compress_into(stream, lz4).expect("the buffer holds LZ4's bound");
    let bytes = if n < stream.len() { &lz4[..n] } else { stream };
    out.extend_from_slice(&(bytes.len() as u32).to_le_bytes());
    out.extend_from_slice(bytes);
}

/// c-blosc 1.x's block size for LZ4 (`compute_blocksize` without a forced size).
fn block_size(clevel: u8, typesize: usize, nbytes: usize) -> usize {
    if nbytes < typesize {
        return 1;
    }
    let mut blocksize = nbytes;
    if nbytes >= L1 {
        blocksize = match clevel {
            0 => L1 / 4,
            1 => L1 / 2,
            2 => L1,
            3 => 2 * L1,
            4 | 5 => 4 * L1,
            _ => 8 * L1,
        };
    }
    if clevel > 0 && splits(typesize, blocksize) {
        // A split stream of at most 256 KiB; a block of 64 KiB to 1 MiB.
        blocksize = (blocksize.min(1 << 18) * typesize).clamp(1 << 16, 1 << 20);
    }
    blocksize = blocksize.min(nbytes);
    if blocksize > typesize {
        blocksize = blocksize / typesize * typesize;
    }
    blocksize
}

/// Whether a block is split into one stream per byte of the type (c-blosc's
/// forward-compatible rule, which its readers also apply to buffers without the flag).
fn splits(typesize: usize, blocksize: usize) -> bool {
    typesize <= MAX_SPLITS && blocksize / typesize >= MIN_BUFFER
}

/// Blosc's byte shuffle: byte `b` of element `i` goes to `out[b * n + i]` for the `n` whole
/// elements; trailing bytes of a partial element stay where they are.
fn byte_shuffle(src: &[u8], typesize: usize, out: &mut [u8]) {
    let n = src.len() / typesize;
    match typesize {
        2 => shuffle_n::<2>(src, n, out),
        4 => shuffle_n::<4>(src, n, out),
        8 => shuffle_8(src, n, out),
        _ => {
            for (i, element) in src.chunks_exact(typesize).enumerate() {
                for (b, &byte) in element.iter().enumerate() {
                    out[b * n + i] = byte;
                }
            }
        }
    }
    out[n * typesize..].copy_from_slice(&src[n * typesize..]);
}

/// The shuffle for a type size known at compile time (the event columns' 2 bytes).
fn shuffle_n<const T: usize>(src: &[u8], n: usize, out: &mut [u8]) {
    let (planes, _) = out.split_at_mut(n * T);
    let mut planes: Vec<&mut [u8]> = planes.chunks_exact_mut(n).collect();
    for (i, element) in src.chunks_exact(T).enumerate() {
        for b in 0..T {
            planes[b][i] = element[b];
        }
    }
}

/// The shuffle of 8-byte elements (timestamps), 8 elements at a time: their bytes as an 8x8
/// matrix, transposed in three rounds of block swaps (4x4, 2x2, 1x1) inside u64 words.
fn shuffle_8(src: &[u8], n: usize, out: &mut [u8]) {
    let whole = n / 8 * 8;
    let mut planes: Vec<std::slice::ChunksExactMut<u8>> = out[..8 * n]
        .chunks_exact_mut(n)
        .map(|p| p[..whole].chunks_exact_mut(8))
        .collect();
    for block in src[..whole * 8].chunks_exact(64) {
        let mut w = [0u64; 8];
        for (word, bytes) in w.iter_mut().zip(block.chunks_exact(8)) {
            *word = u64::from_le_bytes(bytes.try_into().unwrap());
        }
        for (shift, mask, step) in [
            (32, 0x0000_0000_ffff_ffff_u64, 4),
            (16, 0x0000_ffff_0000_ffff, 2),
            (8, 0x00ff_00ff_00ff_00ff, 1),
        ] {
            for k in (0..8).filter(|k| k & step == 0) {
                let t = ((w[k] >> shift) ^ w[k + step]) & mask;
                w[k] ^= t << shift;
                w[k + step] ^= t;
            }
        }
        for (plane, word) in planes.iter_mut().zip(w) {
            plane.next().unwrap().copy_from_slice(&word.to_le_bytes());
        }
    }
    for i in whole..n {
        for b in 0..8 {
            out[b * n + i] = src[i * 8 + b];
        }
    }
}

/// Decodes a buffer [`Compressor::compress_chunk`] wrote (LZ4, byte shuffle or none, split or not); for
/// the tests' round trips and the fuzzing of the layout. `None` if it is not one.
#[cfg(any(test, feature = "check"))]
pub fn decompress_chunk(buf: &[u8]) -> Option<Vec<u8>> {
    let u32_at = |at: usize| crate::bytes::u32_at(buf, at);
    let (flags, typesize) = (*buf.get(2)?, *buf.get(3)? as usize);
    let (nbytes, blocksize) = (u32_at(4)? as usize, u32_at(8)? as usize);
    if buf[0] != VERSION_FORMAT || flags >> 5 != LZ4_CODE || u32_at(12)? as usize != buf.len() {
        return None;
    }
    if flags & FLAG_MEMCPYED != 0 {
        return (buf.len() == HEADER + nbytes).then(|| buf[HEADER..].to_vec());
    }
    if typesize == 0 || blocksize == 0 {
        return None;
    }
    let split = flags & FLAG_DONT_SPLIT == 0 && splits(typesize, blocksize);
    let mut out = Vec::with_capacity(nbytes);
    for j in 0..nbytes.div_ceil(blocksize) {
        let size = blocksize.min(nbytes - j * blocksize);
        let nsplits = if split && size == blocksize {
            typesize
        } else {
            1
        };
        let mut at = u32_at(HEADER + 4 * j)? as usize;
        let mut block = Vec::with_capacity(size);
        for _ in 0..nsplits {
            let len = u32_at(at)? as usize;
            let stream = buf.get(at + 4..at + 4 + len)?;
            let want = size / nsplits;
            if len == want {
                block.extend_from_slice(stream);
            } else {
                let mut part = vec![0; want];
                let n = lz4_flex::block::decompress_into(stream, &mut part).ok()?;
                (n == want).then_some(())?;
                block.extend_from_slice(&part);
            }
            at += 4 + len;
        }
        if flags & FLAG_SHUFFLE != 0 && typesize > 1 {
            let n = size / typesize;
            let mut plain = block.clone();
            for i in 0..n {
                for b in 0..typesize {
                    plain[i * typesize + b] = block[b * n + i];
                }
            }
            block = plain;
        }
        out.extend_from_slice(&block);
    }
    Some(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn varied(n: usize, seed: u64) -> Vec<u8> {
        let mut s = seed | 1;
        (0..n)
            .map(|i| {
                s ^= s << 13;
                s ^= s >> 7;
                s ^= s << 17;
                // Mostly small steps (compressible), some noise.
                if i % 3 == 0 {
                    s as u8
                } else {
                    (i / 64) as u8
                }
            })
            .collect()
    }

    #[test]
    fn block_sizes_follow_c_blosc_for_the_event_columns() {
        // A 65,536-event chunk of each column, clevel 5: one block each.
        assert_eq!(block_size(5, 2, 1 << 17), 1 << 17);
        assert_eq!(block_size(5, 8, 1 << 19), 1 << 19);
        assert_eq!(block_size(5, 1, 1 << 16), 1 << 16);
        // Larger chunks: 128 KiB per split stream, up to 1 MiB per block.
        assert_eq!(block_size(5, 2, 1 << 22), 1 << 18);
        assert_eq!(block_size(5, 8, 1 << 22), 1 << 20);
        assert_eq!(block_size(5, 1, 1 << 22), 1 << 17);
        // Small buffers and wide types.
        assert_eq!(block_size(5, 8, 100), 96);
        assert_eq!(block_size(5, 32, 1 << 20), 4 * L1);
        assert_eq!(block_size(9, 4, 1 << 22), 1 << 20);
        assert_eq!(block_size(1, 2, 1 << 22), 1 << 16); // 16 KiB x 2, raised to 64 KiB
    }

    #[test]
    fn chunks_round_trip_for_every_type_size_and_level() {
        for typesize in [1, 2, 3, 4, 8, 16, 17, 300] {
            for n in [0, 1, 127, 128, 1000, 65_536, 300_001] {
                let data = varied(n - n % typesize, n as u64);
                for (clevel, shuffle) in [(0, true), (1, false), (5, true), (9, true)] {
                    let mut out = Vec::new();
                    match Compressor::default()
                        .compress_chunk(&data, typesize, clevel, shuffle, &mut out)
                    {
                        Filtered::Compressed => {
                            assert!(out.len() <= data.len().max(HEADER));
                            let back = decompress_chunk(&out).expect("decodes");
                            assert_eq!(back, data, "typesize {typesize} n {n} clevel {clevel}");
                        }
                        // Level 0 and tiny chunks: a copy with its header is larger.
                        Filtered::Raw => assert!(out.is_empty()),
                    }
                }
            }
        }
    }

    #[test]
    fn incompressible_chunks_are_left_raw_and_compressible_ones_shrink() {
        let mut s = 0x9e37_79b9_7f4a_7c15_u64;
        let noise: Vec<u8> = (0..1 << 17)
            .map(|_| {
                s = s
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                (s >> 56) as u8
            })
            .collect();
        let (mut c, mut out) = (Compressor::default(), Vec::new());
        assert_eq!(
            c.compress_chunk(&noise, 2, 5, true, &mut out),
            Filtered::Raw
        );
        let ramp: Vec<u8> = (0..1u64 << 16)
            .flat_map(|i| (i * 3).to_le_bytes())
            .collect();
        assert_eq!(
            c.compress_chunk(&ramp, 8, 5, true, &mut out),
            Filtered::Compressed
        );
        assert!(out.len() < ramp.len() / 8, "{} bytes", out.len());
        assert_eq!(out[..4], [2, 1, 0x21, 8]);
        assert_eq!(decompress_chunk(&out).unwrap(), ramp);
    }
}
