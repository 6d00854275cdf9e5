//! Fuzz the stiffness-table readers (`personalise::table::parse_toml` and
//! `parse_csv`, which `read_table` and the CLI use). The same bytes go to
//! both; an accepted table is resolved against the embedded base model
//! (`personalise::resolve`: level names, forms, curves, expressions, SPD
//! checks) and written into a copy of it (`personalise::apply`). Any input
//! must give Ok or a clean Err. Run:
//! `cargo +nightly fuzz run stiffness_table -- -max_total_time=180`.
#![no_main]

use libfuzzer_sys::fuzz_target;
use osim_spine::osim::Document;
use osim_spine::personalise::{self, table};
use std::path::Path;
use std::sync::OnceLock;

fn base() -> &'static Document {
    static DOC: OnceLock<Document> = OnceLock::new();
    DOC.get_or_init(|| {
        Document::parse(include_str!("../../base_model/base.osim"), "base.osim")
            .expect("the embedded base model parses")
    })
}

fn exercise(t: &table::Table) {
    for allow_softening in [false, true] {
        if let Ok(laws) = personalise::resolve(t, base(), allow_softening) {
            let mut doc = base().clone();
            let _ = personalise::apply(&mut doc, &laws);
        }
    }
}

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok(t) = table::parse_toml(text, Path::new("fuzz.toml")) {
        exercise(&t);
    }
    if let Ok(t) = table::parse_csv(text, Path::new("fuzz.csv")) {
        exercise(&t);
    }
});
