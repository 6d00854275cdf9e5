//! Fuzz the .osim reader: any bytes must give Ok or a clean Err from the
//! XML parser, the document checks (and legacy upgrade), the typed model,
//! and the writer must re-read what it wrote. Run:
//! `cargo +nightly fuzz run osim_reader -- -max_total_time=300`.
#![no_main]

use libfuzzer_sys::fuzz_target;
use osim_spine::osim::Document;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok(doc) = Document::parse(text, "fuzz.osim") {
        let _ = doc.model();
        let out = doc.to_xml_string();
        let again =
            Document::parse(&out, "fuzz-rewritten.osim").expect("written document re-reads");
        assert!(again.to_xml_string() == out, "writer is not a fixed point");
    }
});
