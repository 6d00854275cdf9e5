//! Acceptance 3 of the calibration issue, timed end to end (wall clock,
//! all cores via rayon):
//! 1. an 18-parameter per-level calibration of a T12-S1 specimen on 24 load
//!    cases with a multi-start of 16 (`../shared/diagnose-dev/dev-07`;
//!    target < 5 s; the thesis: > 8 hours for 3 parameters);
//! 2. the 500-sample joint-pose sensitivity study on the same experiment
//!    (uniform parameterisation, 1 mm landmark SD; target < 2 minutes).
//!
//! `cargo bench --bench calibrate` (set `CAL_BENCH_REPEAT` for more
//! repetitions of the calibration; `CAL_BENCH_SKIP_SENSITIVITY=1` to skip 2).
//! Not a criterion bench: one iteration of 2 takes tens of seconds. Under
//! `cargo test --all-targets` (no `--bench` argument) it only checks that
//! the experiment loads and the residuals at the nominal parameters are
//! finite.

use osim_spine::calibrate::experiment::Experiment;
use osim_spine::calibrate::family::Parameterisation;
use osim_spine::calibrate::fit::{self, FitOptions};
use osim_spine::calibrate::sensitivity::{self, SensitivityOptions};
use osim_spine::calibrate::setup::{build_problem, Setup};
use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

fn main() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/diagnose-dev/dev-07");
    if !dir.exists() {
        eprintln!("SKIP: {} not found", dir.display());
        return;
    }
    let exp = Arc::new(Experiment::read(&dir).expect("dev-07"));
    let setup = Setup {
        params: Parameterisation::PerLevel,
        ..Setup::default()
    };
    let (pb, _) = build_problem(exp.clone(), &setup).expect("problem");
    if !std::env::args().any(|a| a == "--bench") {
        let nominal: Vec<f64> = pb.family.params().iter().map(|p| p.nominal).collect();
        let (r, _) = pb
            .evaluator()
            .residuals(&pb, &pb.fit_coords_of(&nominal), false)
            .expect("residuals at the nominal parameters");
        assert!(!r.is_empty() && r.iter().all(|v| v.is_finite()));
        println!(
            "test mode: {} finite residuals (time it with `cargo bench --bench calibrate`)",
            r.len()
        );
        return;
    }
    let repeat: usize = std::env::var("CAL_BENCH_REPEAT")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(3);
    println!(
        "per-level calibration: {} parameters, {} cases, {} residuals, 16 starts, {} threads",
        pb.n_params(),
        exp.cases.len(),
        pb.cells.len(),
        rayon::current_num_threads()
    );
    let mut times = Vec::new();
    for _ in 0..repeat {
        let t = Instant::now();
        let cal = fit::calibrate(&pb, &FitOptions::default()).expect("calibrates");
        let dt = t.elapsed().as_secs_f64();
        println!(
            "  {dt:.2} s ({} residual evaluations, {} local minima, cost {:.4})",
            cal.evaluations,
            cal.minima.len(),
            cal.cost
        );
        times.push(dt);
    }
    times.sort_by(|a, b| a.total_cmp(b));
    println!("  median {:.2} s (target < 5 s)", times[times.len() / 2]);
    if std::env::var("CAL_BENCH_SKIP_SENSITIVITY").is_ok() {
        return;
    }
    let t = Instant::now();
    let rep = sensitivity::run(exp, &Setup::default(), &SensitivityOptions::default())
        .expect("sensitivity");
    println!(
        "sensitivity, {} samples (uniform, 1 mm): {:.1} s (target < 120 s); {} in the reduced dataset",
        rep.samples,
        t.elapsed().as_secs_f64(),
        rep.reduced
    );
}
