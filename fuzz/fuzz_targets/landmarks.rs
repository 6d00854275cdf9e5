//! Fuzz the landmark readers: the same bytes go through the CSV, TRC and
//! JSON parsers (`landmarks::io::parse_*`, which `read_path` and the CLI
//! use); whatever they accept goes through strict validation
//! (`RawLandmarks::to_set`, units/frame detection) and the checker
//! (`check::check_raw`). Any input must give Ok or a clean Err, never a
//! panic or hang. Run:
//! `cargo +nightly fuzz run landmarks -- -max_total_time=180`.
#![no_main]

use libfuzzer_sys::fuzz_target;
use osim_spine::landmarks::{check, io};
use std::path::Path;

fn exercise(raw: &io::RawLandmarks) {
    let _ = check::check_raw(raw);
    if let Ok(set) = raw.to_set() {
        // An accepted set has finite coordinates in metres.
        assert!(set
            .points
            .values()
            .all(|p| p.coords.iter().all(|x| x.is_finite())));
    }
}

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok(pals) = io::parse_csv(text, Path::new("fuzz.csv")) {
        for p in &pals {
            exercise(&p.raw);
        }
    }
    if let Ok(raw) = io::parse_trc(text, Path::new("fuzz.trc")) {
        exercise(&raw);
    }
    if let Ok(pals) = io::parse_json(text, Path::new("fuzz.json")) {
        for p in &pals {
            exercise(&p.raw);
        }
    }
});
