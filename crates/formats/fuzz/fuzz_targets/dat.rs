#![no_main]
//! Any bytes after a header through the dat decoder, with the properties of `check`.

use evsplat_formats::{check, Encoding};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    check::decode_checked(Encoding::Dat, data);
});
