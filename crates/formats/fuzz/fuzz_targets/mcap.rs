#![no_main]
//! Any bytes through the MCAP reader, with the properties of `check::decode_mcap_checked`.

use evsplat_formats::check;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    check::decode_mcap_checked(data);
});
