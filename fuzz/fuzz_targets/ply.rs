#![no_main]
//! The ply reader on arbitrary bytes, then validation (see common.rs).

use libfuzzer_sys::fuzz_target;
use subdfit::io::Format;

fuzz_target!(|data: &[u8]| {
    subdfit_fuzz::check(data, Format::Ply, "fuzz.ply");
});
