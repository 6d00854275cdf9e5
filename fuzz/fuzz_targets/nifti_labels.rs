//! Fuzz the NIfTI-1 label-map reader (`segmentation::nifti::parse`, which
//! `read` calls on the gate's bytes after a capped gunzip): any bytes must
//! give Ok(consistent map) or a clean Err, never a panic, hang or huge
//! allocation. Run:
//! `cargo +nightly fuzz run nifti_labels -- -max_total_time=300`.
#![no_main]

use libfuzzer_sys::fuzz_target;
use osim_spine::segmentation::nifti;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    if let Ok(map) = nifti::parse(data, Path::new("fuzz.nii")) {
        // An accepted map holds exactly the voxels its dimensions announce.
        assert_eq!(map.labels.len(), map.dims.iter().product::<usize>());
        assert!(map.affine.iter().all(|x| x.is_finite()));
    }
});
