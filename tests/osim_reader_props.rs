//! Property tests of the .osim reader (the `cargo test` companion of the
//! cargo-fuzz target in `fuzz/`): random bytes and random mutations of a
//! valid model never panic; whatever parses is written back to text that
//! re-reads to the same text (the writer is a fixed point), and the typed
//! model either builds or gives an error.

use osim_spine::osim::Document;
use proptest::prelude::*;

fn base() -> String {
    std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/corpus/osim/valid_base.osim"
    ))
    .unwrap()
}

fn check(text: &str) {
    if let Ok(doc) = Document::parse(text, "prop.osim") {
        let _ = doc.model();
        let out = doc.to_xml_string();
        let again =
            Document::parse(&out, "prop-rewritten.osim").expect("written document re-reads");
        assert!(again.to_xml_string() == out, "writer is not a fixed point");
    }
}

const SNIPPETS: [&str; 14] = [
    "<",
    ">",
    "</",
    "/>",
    "&",
    "&amp;",
    "&#x0;",
    "<![CDATA[",
    "]]>",
    "<!--",
    "-->",
    "<?x ?>",
    "\"",
    "NaN",
];

proptest! {
    #![proptest_config(ProptestConfig { cases: 1500, .. ProptestConfig::default() })]

    #[test]
    fn random_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..512)) {
        let text = String::from_utf8_lossy(&bytes);
        check(&text);
    }

    #[test]
    fn mutated_model_never_panics(
        cut in 0usize..10_000,
        at in 0usize..10_000,
        which in 0usize..SNIPPETS.len(),
        drop_len in 0usize..40,
    ) {
        let b = base();
        let n = b.len();
        // Truncate.
        let mut cut = cut % (n + 1);
        while !b.is_char_boundary(cut) { cut -= 1; }
        check(&b[..cut]);
        // Insert a markup snippet.
        let mut at = at % (n + 1);
        while !b.is_char_boundary(at) { at -= 1; }
        let mut ins = b.clone();
        ins.insert_str(at, SNIPPETS[which]);
        check(&ins);
        // Delete a run of bytes.
        let mut end = (at + drop_len).min(n);
        while !b.is_char_boundary(end) { end -= 1; }
        let mut del = b.clone();
        del.replace_range(at..end, "");
        check(&del);
    }
}

#[test]
fn corpus_files_never_panic() {
    let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/corpus/osim");
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if let Ok(t) = std::fs::read_to_string(&p) {
            check(&t);
        }
    }
}
