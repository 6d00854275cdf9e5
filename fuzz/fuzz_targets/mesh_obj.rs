//! Fuzz the OBJ reader: any bytes must give Ok(valid mesh) or Err, never a
//! panic, hang or huge allocation.
#![no_main]

use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    if let Ok(m) =
        osim_spine::mesh::read_bytes(osim_spine::mesh::Format::Obj, data, Path::new("fuzz.obj"))
    {
        m.validate().expect("reader returned an invalid mesh");
        // what is accepted is finite and bounded (mesh::check_coordinates)
        assert!(m.vertices.iter().all(|p| p
            .coords
            .iter()
            .all(|x| x.abs() <= osim_spine::mesh::MAX_COORDINATE)));
    }
});
