//! The HDF5 event file's chunks compressed in Rust (`evsplat_formats::blosc`) for Python's
//! writer, without the GIL.

use numpy::PyReadonlyArray1;
use pyo3::prelude::*;
use pyo3::types::PyBytes;

use crate::errors::value_err;
use evsplat_formats::blosc::{Compressor, Filtered};

/// The HDF5 chunks of a column's bytes `data` (elements of `typesize` bytes), `chunk` bytes
/// each (the last one zero-padded to `chunk`, as HDF5 pads an edge chunk), compressed as the
/// HDF5 Blosc filter does with LZ4 at `clevel`, byte-shuffled if `shuffle`: a list of (bytes,
/// filter mask) for `H5Dwrite_chunk` (mask 1: the chunk as it is, the filter skipped, as HDF5
/// stores a chunk Blosc cannot shrink). Compressed without the GIL, on `threads` threads.
#[pyfunction]
#[pyo3(signature = (data, typesize, chunk, clevel, shuffle, threads = 1))]
fn blosc_chunks<'py>(
    py: Python<'py>,
    data: PyReadonlyArray1<'py, u8>,
    typesize: usize,
    chunk: usize,
    clevel: u8,
    shuffle: bool,
    threads: usize,
) -> PyResult<Vec<(Bound<'py, PyBytes>, u32)>> {
    if typesize == 0
        || chunk == 0
        || !chunk.is_multiple_of(typesize)
        || chunk > i32::MAX as usize / 2
    {
        return Err(value_err(format!(
            "blosc_chunks: a chunk of {chunk} bytes is not a whole number (>= 1) of \
             {typesize}-byte elements under 1 GiB"
        )));
    }
    let data = data.as_slice()?;
    let pieces: Vec<&[u8]> = data.chunks(chunk).collect();
    let encode = |pieces: &[&[u8]]| -> Vec<(Vec<u8>, u32)> {
        let mut compressor = Compressor::default();
        let mut padded = Vec::new();
        pieces
            .iter()
            .map(|&piece| {
                let piece = if piece.len() < chunk {
                    padded.clear();
                    padded.extend_from_slice(piece);
                    padded.resize(chunk, 0);
                    &padded[..]
                } else {
                    piece
                };
                let mut out = Vec::with_capacity(chunk / 2);
                match compressor.compress_chunk(piece, typesize, clevel, shuffle, &mut out) {
                    Filtered::Compressed => (out, 0),
                    Filtered::Raw => (piece.to_vec(), 1),
                }
            })
            .collect()
    };
    let done: Vec<(Vec<u8>, u32)> = py.detach(|| {
        let per = pieces.len().div_ceil(threads.max(1)).max(1);
        if threads <= 1 || pieces.len() <= 1 {
            return encode(&pieces);
        }
        std::thread::scope(|s| {
            let parts: Vec<_> = pieces
                .chunks(per)
                .map(|part| s.spawn(move || encode(part)))
                .collect();
            parts
                .into_iter()
                .flat_map(|h| h.join().expect("a Blosc thread panicked"))
                .collect()
        })
    });
    Ok(done
        .into_iter()
        .map(|(bytes, mask)| (PyBytes::new(py, &bytes), mask))
        .collect())
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(blosc_chunks, m)?)?;
    Ok(())
}
