//! Fuzz one level of a segmentation folder as `palpate` reads it: the
//! first byte picks the mesh format (STL, OBJ, PLY, VTP), the rest is the
//! file; an accepted mesh must pass the closed-surface check
//! (`segmentation::folder::closed`), the shape screen and then go through
//! the palpation engine as L3 and as the sacrum. Any input must give Ok or
//! a clean Err, never a panic or hang. Run:
//! `cargo +nightly fuzz run segmentation_level -- -max_total_time=300`.
#![no_main]

use libfuzzer_sys::fuzz_target;
use osim_spine::landmarks::Level;
use osim_spine::mesh::{self, Format};
use osim_spine::palpation::{palpate_vertebra, FrameHint};
use osim_spine::segmentation::{checks, folder};
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let Some((&pick, bytes)) = data.split_first() else {
        return;
    };
    let format = [Format::Stl, Format::Obj, Format::Ply, Format::Vtp][pick as usize % 4];
    let path = Path::new("fuzz-level");
    let Ok(m) = mesh::read_bytes(format, bytes, path) else {
        return;
    };
    let Ok((m, _turned)) = folder::closed(m, path) else {
        return;
    };
    let _ = checks::check_shape(Level::L3, &m);
    for level in [Level::L3, Level::S1] {
        if let Ok(p) = palpate_vertebra(&m, level, &FrameHint::body_frame()) {
            assert!(p
                .landmarks
                .values()
                .all(|l| l.point.coords.iter().all(|x| x.is_finite())));
        }
    }
});
