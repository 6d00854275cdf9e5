//! Iterations and wall time of cold static solves of the programmatic spine
//! chains (6-68 joints, 7.5 N m on the top vertebra), structured vs dense
//! tangent: a quick profiling driver (`cargo run --release --example
//! solve_iters [REPEATS [N [auto|dense]]]`); the benchmark of record is `benches/solver.rs`.

use nalgebra::Vector3;
use osim_spine::solver::examples::spine_chain;
use osim_spine::solver::{Load, LoadFrame, StaticOptions, System, TangentMethod, Workspace};
use std::time::Instant;

fn main() -> anyhow::Result<()> {
    let reps: usize = match std::env::args().nth(1) {
        Some(s) => s.parse()?,
        None => 200,
    };
    let only: Option<usize> = match std::env::args().nth(2) {
        Some(s) => Some(s.parse()?),
        None => None,
    };
    let methods: &[TangentMethod] = match std::env::args().nth(3).as_deref() {
        Some("auto") => &[TangentMethod::Auto],
        Some("dense") => &[TangentMethod::Dense],
        _ => &[TangentMethod::Auto, TangentMethod::Dense],
    };
    for n in [6usize, 12, 17, 34, 68] {
        if only.is_some_and(|o| o != n) {
            continue;
        }
        let sys = System::new(&spine_chain(n))?;
        let loads = sys.prepare_loads(&[Load::Moment {
            body: format!("v{n}"),
            vec: Vector3::new(0.0, 0.0, -7.5),
            frame: LoadFrame::Ground,
        }])?;
        let q0 = sys.default_q();
        for &method in methods {
            let mut ws = Workspace::new(&sys);
            let opts = StaticOptions {
                tangent: method,
                ..StaticOptions::default()
            };
            let reps = if method == TangentMethod::Dense {
                reps.div_ceil(20)
            } else {
                reps
            };
            let mut sol = sys.solve_static(&loads, q0.as_slice(), &mut ws, &opts)?;
            let t = Instant::now();
            for _ in 0..reps {
                sol = sys.solve_static(&loads, q0.as_slice(), &mut ws, &opts)?;
            }
            let per = t.elapsed().as_secs_f64() / reps as f64;
            println!(
                "{n:3} joints {method:?}: {:9.1} us/solve, {} iterations, {:6.2} us/joint",
                per * 1e6,
                sol.iterations,
                per * 1e6 / n as f64
            );
        }
    }
    Ok(())
}
