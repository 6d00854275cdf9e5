//! `check` on a 17-level set (T1..L5 + S1): parsing + detection + all
//! checks from CSV text, and the anatomical checks alone.
//! Target (acceptance): well under 50 ms.

use criterion::{criterion_group, criterion_main, Criterion};
use osim_spine::landmarks::check::{check_raw, check_set};
use osim_spine::landmarks::io::{csv_string, parse_csv};
use osim_spine::landmarks::synth::{generate, SpineShape, SynthOptions};
use osim_spine::landmarks::{Frame, Level, Units};
use std::hint::black_box;
use std::path::Path;

fn bench(c: &mut Criterion) {
    let set = generate(&SynthOptions {
        top: Level::T1,
        shape: SpineShape::lumbar_scoliosis(75.0),
        noise_sd: 0.001,
        seed: 1,
    })
    .expect("synthetic set");
    let text = csv_string(&set, Units::Millimetre, Frame::Lps);
    c.bench_function("check_17_levels_from_csv_text", |b| {
        b.iter(|| {
            let pal = parse_csv(black_box(&text), Path::new("bench.csv")).expect("parses");
            check_raw(&pal[0].raw)
        })
    });
    let lines = Default::default();
    c.bench_function("check_set_17_levels", |b| {
        b.iter(|| check_set(black_box(&set), &lines))
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
