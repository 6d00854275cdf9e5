//! Stress cases of the static solver (long chains under full gravity, the
//! base model under gravity and large pure moments on T1): iterations,
//! outcome and wall time of one cold solve each. A quick driver
//! (`cargo run --release --example solve_stress`); the benchmark of record is
//! `benches/solver.rs`.

use nalgebra::Vector3;
use osim_spine::solver::examples::spine_chain;
use osim_spine::solver::{Load, LoadFrame, StaticOptions, System, SystemSpec, Workspace};
use std::time::Instant;

fn run(label: &str, sys: &System, loads: &[Load]) -> anyhow::Result<()> {
    let loads = sys.prepare_loads(loads)?;
    let mut ws = Workspace::new(sys);
    let q0 = sys.default_q();
    let t = Instant::now();
    let r = if std::env::var("CONTINUATION").is_ok() {
        sys.solve_static_continuation(&loads, q0.as_slice(), &mut ws, &StaticOptions::default())
    } else {
        sys.solve_static(&loads, q0.as_slice(), &mut ws, &StaticOptions::default())
    };
    let dt = t.elapsed().as_secs_f64();
    match r {
        Ok(s) => {
            let t = sys.static_tangent(s.q.as_slice(), &loads, &mut ws)?;
            let asym = (&t - t.transpose()).amax() / t.amax();
            let eig = (-(&t + t.transpose()) * 0.5).symmetric_eigenvalues();
            let mut e: Vec<f64> = eig.iter().copied().collect();
            e.sort_by(|a, b| a.total_cmp(b));
            println!(
                "    dense tangent: asym {asym:.1e}, smallest eigenvalues of -T {:?}",
                &e[..3]
            );
            println!(
                "{label:40} ok   {:4} it {:3} cont  res {:9.2e}  {:8.2} ms  stable {:?}",
                s.iterations,
                s.continuation_steps,
                s.residual_norm,
                dt * 1e3,
                s.stable
            )
        }
        Err(e) => println!("{label:40} FAIL {:8.2} ms  {e}", dt * 1e3),
    }
    Ok(())
}

fn main() -> anyhow::Result<()> {
    let g = Vector3::new(0.0, -9.80665, 0.0);
    for n in [6usize, 12, 17, 34, 68] {
        let mut spec = spine_chain(n);
        spec.gravity = g;
        let sys = System::new(&spec)?;
        run(&format!("chain {n} gravity"), &sys, &[])?;
    }
    let path = std::path::Path::new("base_model/base.osim");
    let spec = SystemSpec::read_osim(path)?;
    let sys = System::new(&spec)?;
    run("base gravity", &sys, &[])?;
    for m in [10.0, 20.0, 30.0, 40.0] {
        for (ax, v) in [
            ("x", Vector3::x()),
            ("z", Vector3::z()),
            ("-z", -Vector3::z()),
        ] {
            run(
                &format!("base gravity + {m} N m {ax} on T1"),
                &sys,
                &[Load::Moment {
                    body: "thoracic1".into(),
                    vec: v * m,
                    frame: LoadFrame::Ground,
                }],
            )?;
        }
    }
    Ok(())
}
