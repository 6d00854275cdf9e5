//! Time of one static solve of a spine-like chain of 6, 12, 17, 34 and 68
//! six-DoF joints under a 7.5 N m flexion moment on the top vertebra, gravity
//! off (acceptance 4: the cost should grow about linearly with the number of
//! joints):
//! - `static_solve/N_joints`: cold start from the default pose (structured
//!   O(n) tangent, the default);
//! - `static_solve_warm/N_joints`: warm start from the equilibrium under
//!   7.0 N m (what calibration and load sweeps do);
//! - `static_solve_dense/N_joints`: cold start with the dense reference
//!   tangent (`TangentMethod::Dense`), for comparison;
//! - `static_solve_loaded/{cold,warm}_N_joints` (6 and 12 joints): a
//!   non-linear case, gravity on, the moment plus a 300 N follower load;
//!   warm from the equilibrium under 7.0 N m;
//! - `static_solve_gravity/68_joints`: 68 joints under full gravity, no
//!   other load, cold: far beyond the column's buckling load, plain Newton's
//!   line search stalls and the load-continuation fallback solves it (the
//!   Newton iterations and continuation steps are printed).

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use nalgebra::{DVector, Vector3};
use osim_spine::solver::examples::spine_chain;
use osim_spine::solver::{
    Load, LoadFrame, LoadSet, StaticOptions, System, TangentMethod, Workspace,
};
use std::hint::black_box;

const SIZES: [usize; 5] = [6, 12, 17, 34, 68];

fn setup(n: usize, moment: f64) -> (System, LoadSet) {
    setup_with(n, moment, false)
}

fn setup_with(n: usize, moment: f64, loaded: bool) -> (System, LoadSet) {
    let mut spec = spine_chain(n);
    let mut loads = vec![Load::Moment {
        body: format!("v{n}"),
        vec: Vector3::new(0.0, 0.0, moment),
        frame: LoadFrame::Ground,
    }];
    if loaded {
        spec.gravity = Vector3::new(0.0, -9.80665, 0.0);
        loads.push(Load::Follower {
            from_body: "sacrum".into(),
            to_body: format!("v{n}"),
            magnitude: 300.0,
        });
    }
    let sys = System::new(&spec).expect("chain");
    let loads = sys.prepare_loads(&loads).expect("loads");
    (sys, loads)
}

fn bench_chains(c: &mut Criterion) {
    let opts = StaticOptions::default();
    let mut g = c.benchmark_group("static_solve");
    for n in SIZES {
        let (sys, loads) = setup(n, -7.5);
        let mut ws = Workspace::new(&sys);
        let q0 = sys.default_q();
        g.bench_function(BenchmarkId::from_parameter(format!("{n}_joints")), |b| {
            b.iter(|| {
                black_box(
                    sys.solve_static(&loads, q0.as_slice(), &mut ws, &opts)
                        .expect("solve"),
                )
            })
        });
    }
    g.finish();

    let mut g = c.benchmark_group("static_solve_warm");
    for n in SIZES {
        let (sys, loads) = setup(n, -7.5);
        let (_, near) = setup(n, -7.0);
        let mut ws = Workspace::new(&sys);
        let q_near: DVector<f64> = sys
            .solve_static(&near, sys.default_q().as_slice(), &mut ws, &opts)
            .expect("solve")
            .q;
        g.bench_function(BenchmarkId::from_parameter(format!("{n}_joints")), |b| {
            b.iter(|| {
                black_box(
                    sys.solve_static(&loads, q_near.as_slice(), &mut ws, &opts)
                        .expect("solve"),
                )
            })
        });
    }
    g.finish();

    let mut g = c.benchmark_group("static_solve_loaded");
    for n in [6usize, 12] {
        let (sys, loads) = setup_with(n, -7.5, true);
        let (_, near) = setup_with(n, -7.0, true);
        let mut ws = Workspace::new(&sys);
        let q0 = sys.default_q();
        let q_near: DVector<f64> = sys
            .solve_static(&near, q0.as_slice(), &mut ws, &opts)
            .expect("solve")
            .q;
        for (label, start) in [("cold", &q0), ("warm", &q_near)] {
            let it = sys
                .solve_static(&loads, start.as_slice(), &mut ws, &opts)
                .expect("solve")
                .iterations;
            eprintln!("static_solve_loaded {label} {n} joints: {it} Newton iterations");
            g.bench_function(
                BenchmarkId::from_parameter(format!("{label}_{n}_joints")),
                |b| {
                    b.iter(|| {
                        black_box(
                            sys.solve_static(&loads, start.as_slice(), &mut ws, &opts)
                                .expect("solve"),
                        )
                    })
                },
            );
        }
    }
    g.finish();

    let mut g = c.benchmark_group("static_solve_gravity");
    g.sample_size(20);
    {
        let mut spec = spine_chain(68);
        spec.gravity = Vector3::new(0.0, -9.80665, 0.0);
        let sys = System::new(&spec).expect("chain");
        let loads = LoadSet::empty();
        let mut ws = Workspace::new(&sys);
        let q0 = sys.default_q();
        let sol = sys
            .solve_static(&loads, q0.as_slice(), &mut ws, &opts)
            .expect("solve");
        eprintln!(
            "static_solve_gravity 68 joints: {} Newton iterations, {} continuation steps, stable {:?}",
            sol.iterations, sol.continuation_steps, sol.stable
        );
        g.bench_function(BenchmarkId::from_parameter("68_joints"), |b| {
            b.iter(|| {
                black_box(
                    sys.solve_static(&loads, q0.as_slice(), &mut ws, &opts)
                        .expect("solve"),
                )
            })
        });
    }
    g.finish();

    let mut g = c.benchmark_group("static_solve_dense");
    g.sample_size(10);
    for n in SIZES {
        let (sys, loads) = setup(n, -7.5);
        let mut ws = Workspace::new(&sys);
        let dense = StaticOptions {
            tangent: TangentMethod::Dense,
            ..opts
        };
        let q0 = sys.default_q();
        g.bench_function(BenchmarkId::from_parameter(format!("{n}_joints")), |b| {
            b.iter(|| {
                black_box(
                    sys.solve_static(&loads, q0.as_slice(), &mut ws, &dense)
                        .expect("solve"),
                )
            })
        });
    }
    g.finish();
}

criterion_group!(benches, bench_chains);
criterion_main!(benches);
