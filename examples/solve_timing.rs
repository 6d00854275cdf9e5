//! Times the built-in static solver on an .osim file (used by
//! `benches/opensim_side_by_side.py`).
//!
//! usage: solve_timing MODEL BODY MX MY MZ REPEATS
//! Gravity off; a ground-fixed moment (MX, MY, MZ) N m on BODY; every solve
//! starts cold from the default pose. Prints JSON: median and minimum time of
//! one solve, Newton iterations, the equilibrium coordinates by name.

use nalgebra::Vector3;
use osim_spine::solver::{Load, LoadFrame, StaticOptions, System, SystemSpec, Workspace};
use std::time::Instant;

fn main() -> anyhow::Result<()> {
    let a: Vec<String> = std::env::args().collect();
    if a.len() != 7 {
        anyhow::bail!("usage: solve_timing MODEL BODY MX MY MZ REPEATS");
    }
    let mut spec = SystemSpec::read_osim(std::path::Path::new(&a[1]))?;
    spec.gravity = Vector3::zeros();
    let sys = System::new(&spec)?;
    let m = Vector3::new(a[3].parse()?, a[4].parse()?, a[5].parse()?);
    let reps: usize = a[6].parse()?;
    let loads = sys.prepare_loads(&[Load::Moment {
        body: a[2].clone(),
        vec: m,
        frame: LoadFrame::Ground,
    }])?;
    let mut ws = Workspace::new(&sys);
    let q0 = sys.default_q();
    let opts = StaticOptions::default();
    let mut sol = sys.solve_static(&loads, q0.as_slice(), &mut ws, &opts)?;
    let mut times = Vec::with_capacity(reps);
    for _ in 0..reps.max(1) {
        let t = Instant::now();
        sol = sys.solve_static(&loads, q0.as_slice(), &mut ws, &opts)?;
        times.push(t.elapsed().as_secs_f64());
    }
    times.sort_by(f64::total_cmp);
    let full = sys.full_coordinates(sol.q.as_slice());
    let coords: serde_json::Map<String, serde_json::Value> = sys
        .coordinates()
        .iter()
        .zip(full)
        .map(|(c, v)| (c.name.clone(), v.into()))
        .collect();
    let out = serde_json::json!({
        "median_s": times[times.len() / 2],
        "min_s": times[0],
        "repeats": times.len(),
        "iterations": sol.iterations,
        "residual_norm": sol.residual_norm,
        "dofs": sys.n_dofs(),
        "coordinates": coords,
    });
    println!("{out}");
    Ok(())
}
