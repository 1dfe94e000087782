#![no_main]
//! Any bytes through the ROS 1 bag reader, with the properties of `check::decode_bag_checked`.

use evsplat_formats::check;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    check::decode_bag_checked(data);
});
