//! `generate` and `evaluate` timing: a T1-S1
//! landmark set (the default base model posed into the example scoliosis,
//! all 17 vertebrae + S1, no noise) on the committed `base_model/`.
//! `generate_full` is the CLI's work without file I/O: sacral registration,
//! 17 pose fits (lsq), scaling, joints, wrap-sphere refit, self-check
//! (mesh through-bone test, equilibrium with the solver) and SVG views.
//! `evaluate` is one model against 17 truth centres with all metrics and
//! figures. Run: `cargo bench --bench generate`.

use criterion::{criterion_group, criterion_main, Criterion};
use osim_spine::base::DirMeshSource;
use osim_spine::evaluate::{evaluate, Align, CentreDef, ModelShape, Truth};
use osim_spine::generate::{example::posed_example, generate, GenerateOptions};
use osim_spine::osim::Document;
use std::path::PathBuf;

fn bench(c: &mut Criterion) {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("base_model/base.osim");
    let base = Document::read(&path).expect("base_model/base.osim");
    let (set, centres) = posed_example(&base).expect("posed example");
    let source = DirMeshSource {
        model_path: path.clone(),
        extra: vec![],
    };
    let full = GenerateOptions::default();
    c.bench_function("generate_full_T1_S1", |b| {
        b.iter(|| generate(&base, &set, "bench", &full, Some(&source)).unwrap())
    });
    let lean = GenerateOptions {
        self_check: false,
        views: false,
        ..GenerateOptions::default()
    };
    c.bench_function("generate_no_checks_T1_S1", |b| {
        b.iter(|| generate(&base, &set, "bench", &lean, None).unwrap())
    });
    let g = generate(&base, &set, "bench", &lean, None).unwrap();
    let truth = Truth {
        source: "bench".into(),
        centres,
        landmarks: Some(set.clone()),
    };
    c.bench_function("evaluate_T1_S1", |b| {
        b.iter(|| {
            let m = ModelShape::from_document(
                &g.doc,
                Some(g.report.registration.clone()),
                CentreDef::Endplates,
            )
            .unwrap();
            evaluate(&[m], &truth, Align::Rigid, None, CentreDef::Endplates).unwrap()
        })
    });
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(20);
    targets = bench
}
criterion_main!(benches);
