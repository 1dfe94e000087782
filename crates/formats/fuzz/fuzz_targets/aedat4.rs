#![no_main]
//! A compression byte and AEDAT 4 packets through the reader, with the properties of
//! `check::decode_aedat_checked`.

use evsplat_formats::check;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    check::decode_aedat_checked(data);
});
