use osim_spine::calibrate::experiment::Experiment;
use osim_spine::diagnose::family::{Family, Kind};
use osim_spine::diagnose::fit::{fit, Weights};
use osim_spine::diagnose::sim::Sim;
fn main() {
    let dir = std::env::args().nth(1).unwrap();
    let exp = Experiment::read(&dir).unwrap();
    let sim = Sim::new(&exp).unwrap();
    let cases: Vec<usize> = (0..sim.loads.len()).collect();
    let cells: Vec<usize> = (0..sim.cells.len()).collect();
    let w = Weights {
        rot: 1.0,
        trans: 1.0,
    };
    let t = std::time::Instant::now();
    let b = fit(
        &sim,
        Family::new(Kind::Baseline, &sim, [0.0; 3]),
        &cells,
        &cases,
        w,
        50,
    )
    .unwrap();
    let sse = |f: &osim_spine::diagnose::fit::Fitted| {
        cells
            .iter()
            .map(|&c| f.residual(&sim, c).powi(2))
            .sum::<f64>()
    };
    println!(
        "baseline {:?} sse {} it {} {:?}",
        b.x,
        sse(&b),
        b.iterations,
        t.elapsed()
    );
    let g = [b.x[0], b.x[1], b.x[2]];
    for k in [
        Kind::LevelScalar,
        Kind::LevelPerDof,
        Kind::NonlinearSinh,
        Kind::NonlinearCubic,
        Kind::AsymmetricBilinear,
        Kind::CoupledUniform,
        Kind::CoupledPerLevel,
        Kind::JointRotation,
        Kind::JointPose,
        Kind::Preload,
    ] {
        let t = std::time::Instant::now();
        match fit(&sim, Family::new(k, &sim, g), &cells, &cases, w, 50) {
            Ok(f) => println!(
                "{:?} sse {:.5} it {} n {} {:?}",
                k,
                sse(&f),
                f.iterations,
                f.x.len(),
                t.elapsed()
            ),
            Err(e) => println!("{k:?} error {e}"),
        }
    }
}
