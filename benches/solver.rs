//! Time of one static solve (cold start from the default pose) of a
//! spine-like chain of 6, 12, 17, 34 and 68 six-DoF joints under a 7.5 N m
//! flexion moment on the top vertebra, gravity off (acceptance 4: the cost
//! should grow about linearly with the number of joints).

use criterion::{criterion_group, criterion_main, Criterion};
use nalgebra::Vector3;
use osim_spine::solver::examples::spine_chain;
use osim_spine::solver::{Load, LoadFrame, StaticOptions, System, Workspace};
use std::hint::black_box;

fn bench_chains(c: &mut Criterion) {
    let mut g = c.benchmark_group("static_solve");
    for n in [6usize, 12, 17, 34, 68] {
        let sys = System::new(&spine_chain(n)).expect("chain");
        let mut ws = Workspace::new(&sys);
        let top = format!("v{n}");
        let loads = sys
            .prepare_loads(&[Load::Moment {
                body: top,
                vec: Vector3::new(0.0, 0.0, -7.5),
                frame: LoadFrame::Ground,
            }])
            .expect("loads");
        let q0 = sys.default_q();
        let opts = StaticOptions::default();
        g.bench_function(format!("{n}_joints"), |b| {
            b.iter(|| {
                black_box(
                    sys.solve_static(&loads, q0.as_slice(), &mut ws, &opts)
                        .expect("solve"),
                )
            })
        });
    }
    g.finish();
}

criterion_group!(benches, bench_chains);
criterion_main!(benches);
