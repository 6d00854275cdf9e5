//! Fuzz the VTP reader: any bytes must give Ok(valid mesh) or Err, never a
//! panic, hang or huge allocation.
#![no_main]

use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    if let Ok(m) = osim_spine::mesh::vtp::read_bytes(data, Path::new("fuzz.vtp")) {
        m.validate().expect("reader returned an invalid mesh");
    }
});
