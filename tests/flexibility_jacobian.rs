//! The films' least-squares problem of `flexibility` (`flexibility::fit`):
//! its exact Jacobian (implicit differentiation through the bent
//! equilibrium, dual-number projections, placement) against central finite
//! differences, and the bending solves on the solver's structured tangent.
//! On the embedded default model (bushings only, no gravity).

use nalgebra::Vector2;
use osim_spine::embedded::BaseModel;
use osim_spine::flexibility::bend::BendModel;
use osim_spine::flexibility::fit::{prior_rows, sum_zero_basis, Estimated, FilmData, Problem};
use osim_spine::flexibility::place::Placement;
use osim_spine::landmarks::radiograph::{FilmPoint, Side};
use osim_spine::landmarks::{Code, LandmarkId, Level};
use osim_spine::solver::Workspace;

/// The embedded base as a bending model.
fn model() -> BendModel {
    let doc = BaseModel::Embedded.read().unwrap();
    BendModel::new(&doc.model().unwrap()).unwrap()
}

/// A film of the model bent by `loads` with multipliers `m`, placed by `place`.
fn film(bm: &BendModel, m: &[f64], loads: [f64; 3], place: &Placement) -> FilmData {
    let mut points = Vec::new();
    for l in &Level::ALL[..17] {
        for c in [Code::SR, Code::SL, Code::IR, Code::IL, Code::SEC, Code::IEC] {
            points.push(FilmPoint::Landmark(LandmarkId::new(*l, c)));
        }
    }
    for c in [Code::SR, Code::SL, Code::SEC] {
        points.push(FilmPoint::Landmark(LandmarkId::new(Level::S1, c)));
    }
    points.push(FilmPoint::FemoralHead(Side::Right));
    points.push(FilmPoint::FemoralHead(Side::Left));
    let sys = bm.with_multipliers(m).unwrap();
    let mut ws = Workspace::new(&sys);
    let q = bm
        .solve(&sys, Level::T1, loads, bm.rest.as_slice(), &mut ws)
        .unwrap();
    let (proj, _) = bm.project(&points, q.as_slice(), None).unwrap();
    FilmData {
        stem: "synthetic".into(),
        file: "synthetic.csv".into(),
        level: Level::T1,
        points,
        measured: proj.iter().map(|p| place.apply(p)).collect(),
    }
}

#[test]
fn jacobian_matches_central_differences() {
    let bm = model();
    let n = bm.joints.len();
    let truth: Vec<f64> = (0..n)
        .map(|j| (0.4 * (j as f64 * 0.7).sin()).exp())
        .collect();
    let place = Placement {
        phi: 0.03,
        t: Vector2::new(0.2, 0.9),
    };
    let f = film(&bm, &truth, [-6.0, -0.8, -2.0], &place);
    let est = Estimated {
        joints: (0..n).collect(),
        basis: sum_zero_basis(n),
        prior: prior_rows(n, Some(1.0), None),
    };
    let mut pb = Problem::new(&bm, vec![&f], vec![1.0; n], Some(est), 1e-3);
    // a point away from the optimum: every parameter matters
    let mut p: Vec<f64> = (0..n - 1).map(|k| 0.1 * (k as f64 * 1.3).cos()).collect();
    p.extend_from_slice(&[-4.0, -0.5, -1.0, 0.02, 0.19, 0.91]);
    let (_, jac) = pb.eval(&p, true).unwrap();
    let jac = jac.unwrap();
    let mut worst: f64 = 0.0;
    for c in 0..p.len() {
        let h = if c < n - 1 {
            1e-6
        } else {
            1e-6 * (1.0 + p[c].abs())
        };
        let (mut a, mut b) = (p.clone(), p.clone());
        a[c] += h;
        b[c] -= h;
        let ra = pb.eval(&a, false).unwrap().0;
        let rb = pb.eval(&b, false).unwrap().0;
        let fd = (ra - rb) / (2.0 * h);
        let col = jac.column(c);
        let scale = col.amax().max(1e-3);
        let err = (fd - col).amax() / scale;
        worst = worst.max(err);
        assert!(err < 1e-4, "column {c}: relative error {err:.2e}");
    }
    println!("largest relative column error {worst:.2e}");
}

#[test]
fn bending_solves_use_the_structured_tangent() {
    let bm = model();
    let sys = bm.with_multipliers(&vec![1.0; bm.joints.len()]).unwrap();
    let mut ws = Workspace::new(&sys);
    bm.solve(
        &sys,
        Level::T1,
        [-5.0, -1.0, 0.0],
        bm.rest.as_slice(),
        &mut ws,
    )
    .unwrap();
    assert!(ws.used_structured_tangent());
}
