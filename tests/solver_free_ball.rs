//! FreeJoint and BallJoint generalised speeds as OpenSim 4.6 defines them:
//! the rotational speeds are the angular velocity of the child frame M in
//! the parent frame F, expressed in F (Simbody's Free/Ball mobilizers with
//! Euler angles), so `qdot = N(q) u != u`. OpenSim builds random chains that
//! mix FreeJoint, BallJoint, GimbalJoint (u = qdot) and 6-DoF CustomJoint
//! joints with random bushings (`tests/py/free_ball_chains.py`); the solver
//! reads the same .osim files and must reproduce, at random (q, u):
//! - OpenSim's `udot` and `qdot` within 1e-9 relative to the largest entry,
//!   and its bushing record values (with damping) within 1e-9 relative;
//! - the kinetic energy `1/2 u^T M u` equal to `sum 1/2 m v^2 + 1/2 w^T I w`
//!   over OpenSim's own body velocities (1e-9 relative), and the solver's
//!   `Energy::kinetic` equal to it;
//! - a 0.05 s forward simulation from a random (q, u) ending in OpenSim's
//!   state (RungeKuttaMerson at accuracy 1e-12) within 1e-7 (Richardson
//!   extrapolation of the implicit-midpoint runs at dt = 2e-5 and 1e-5;
//!   the raw dt = 1e-5 run within 1e-6, converging at second order);
//! - OpenSim's static equilibrium under (reduced) gravity within 1e-8.

mod common;

use nalgebra::{DMatrix, DVector, Matrix3, Vector3};
use osim_spine::solver::dynamics::Integrator;
use osim_spine::solver::{DofIndex, LoadSet, StaticOptions, System, SystemSpec, Workspace};
use serde_json::Value;

fn by_name(sys: &System, map: &Value) -> Vec<f64> {
    (0..sys.n_dofs())
        .map(|i| {
            map[sys.dof_name(DofIndex(i))]
                .as_f64()
                .unwrap_or_else(|| panic!("{} missing", sys.dof_name(DofIndex(i))))
        })
        .collect()
}

fn vec3(v: &Value) -> Vector3<f64> {
    let a: Vec<f64> = v
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect();
    Vector3::new(a[0], a[1], a[2])
}

fn max_abs(v: &[f64]) -> f64 {
    v.iter().fold(0.0f64, |s, x| s.max(x.abs()))
}

/// Kinetic energy from OpenSim's body velocities and mass properties.
fn ke_from_bodies(bodies: &Value) -> f64 {
    let mut ke = 0.0;
    for (_, b) in bodies.as_object().unwrap() {
        let m = b["mass"].as_f64().unwrap();
        let w = vec3(&b["w"]);
        let v = vec3(&b["v_com"]);
        let i: Vec<f64> = b["inertia"]
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_f64().unwrap())
            .collect();
        // OpenSim's inertia is about the centre of mass, body axes
        let ib = Matrix3::new(i[0], i[3], i[4], i[3], i[1], i[5], i[4], i[5], i[2]);
        let rows: Vec<Vector3<f64>> = b["R"].as_array().unwrap().iter().map(vec3).collect();
        let r = Matrix3::from_rows(&[
            rows[0].transpose(),
            rows[1].transpose(),
            rows[2].transpose(),
        ]);
        let ig = r * ib * r.transpose();
        ke += 0.5 * m * v.norm_squared() + 0.5 * w.dot(&(ig * w));
    }
    ke
}

/// Largest differences from OpenSim over every model and state.
#[derive(Default)]
struct Worst {
    udot: f64,
    qdot: f64,
    kinetic: f64,
    simulation: f64,
    equilibrium: f64,
    raw_simulation: f64,
    records: f64,
}

#[test]
fn free_and_ball_joints_match_opensim() {
    let Some(py) = common::opensim_python() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path().to_str().unwrap();
    let out = common::run_py(&py, "free_ball_chains.py", &[d, "20250611", "4"]);
    let mut worst = Worst::default();
    let mut n_states = 0;
    let mut n_mapped = 0;
    for m in out["models"].as_array().unwrap() {
        let file = std::path::PathBuf::from(m["file"].as_str().unwrap());
        let sys = System::new(&SystemSpec::read_osim(&file).unwrap()).unwrap();
        let mut ws = Workspace::new(&sys);
        assert_eq!(sys.n_dofs() as u64, m["n_dofs"].as_u64().unwrap());
        // exactly the FreeJoint/BallJoint rotations have angular-velocity speeds
        n_mapped += check_angular_velocity_speeds(&sys, m, &file);
        // qdot, udot, bushing records and kinetic energy at every state
        for st in m["states"].as_array().unwrap() {
            check_state(&sys, &mut ws, st, &file, &mut worst);
            n_states += 1;
        }
        // a forward simulation, then the equilibrium under reduced gravity
        check_simulation(&sys, &mut ws, &m["simulation"], &file, &mut worst);
        check_statics(&m["statics"], &file, &mut worst);
    }
    assert!(n_mapped > 0);
    eprintln!(
        "free/ball chains: {n_states} states ({n_mapped} angular-velocity speeds); max rel qdot diff {:.2e}, \
         udot {:.2e}, kinetic energy {:.2e}, bushing records {:.2e}; 0.05 s simulation max diff {:.2e} \
         (extrapolated; raw dt = 1e-5: {:.2e}); \
         equilibrium max diff {:.2e}",
        worst.qdot,
        worst.udot,
        worst.kinetic,
        worst.records,
        worst.simulation,
        worst.raw_simulation,
        worst.equilibrium
    );
}

/// Exactly the rotations of the FreeJoints and BallJoints of model `m` have
/// angular-velocity speeds; returns how many.
fn check_angular_velocity_speeds(sys: &System, m: &Value, file: &std::path::Path) -> usize {
    let kinds: Vec<&str> = m["kinds"]
        .as_array()
        .unwrap()
        .iter()
        .map(|k| k.as_str().unwrap())
        .collect();
    let want_mapped: usize = kinds
        .iter()
        .map(|k| if matches!(*k, "free" | "ball") { 3 } else { 0 })
        .sum();
    let mapped = (0..sys.n_dofs())
        .filter(|&i| sys.dof_speed_is_angular_velocity(DofIndex(i)))
        .count();
    assert_eq!(mapped, want_mapped, "{}: {kinds:?}", file.display());
    mapped
}

/// One state `st` of OpenSim: `qdot = N(q) u` (and back), `udot`, the
/// bushing records and the kinetic energy agree.
fn check_state(
    sys: &System,
    ws: &mut Workspace,
    st: &Value,
    file: &std::path::Path,
    worst: &mut Worst,
) {
    let n = sys.n_dofs();
    let q = by_name(sys, &st["q"]);
    let u = by_name(sys, &st["u"]);
    // OpenSim's Coordinate::getSpeedValue is the generalised speed u
    assert_eq!(by_name(sys, &st["speed_value"]), u);
    // qdot = N(q) u
    let want_qd = by_name(sys, &st["qdot"]);
    let mut qd = vec![0.0; n];
    sys.qdot(&q, &u, &mut qd).unwrap();
    let s = max_abs(&want_qd);
    for i in 0..n {
        let rel = (qd[i] - want_qd[i]).abs() / s;
        worst.qdot = worst.qdot.max(rel);
        assert!(
            rel < 1e-9,
            "{}: qdot {} = {} vs OpenSim {} (rel {rel:e})",
            file.display(),
            sys.dof_name(DofIndex(i)),
            qd[i],
            want_qd[i]
        );
    }
    let mut back = vec![0.0; n];
    sys.speeds_from_qdot(&q, &qd, &mut back).unwrap();
    for i in 0..n {
        assert!((back[i] - u[i]).abs() < 1e-12 * (1.0 + u[i].abs()));
    }
    // udot
    let want = by_name(sys, &st["udot"]);
    let mut a = vec![0.0; n];
    sys.accelerations(&q, &u, &LoadSet::empty(), ws, &mut a)
        .unwrap();
    let s = max_abs(&want);
    for i in 0..n {
        let rel = (a[i] - want[i]).abs() / s;
        worst.udot = worst.udot.max(rel);
        assert!(
            rel < 1e-9,
            "{}: udot {} = {} vs OpenSim {} (rel {rel:e})",
            file.display(),
            sys.dof_name(DofIndex(i)),
            a[i],
            want[i]
        );
    }
    check_records(sys, ws, st, &q, &u, file, worst);
    // kinetic energy: 1/2 u^T M u vs OpenSim's body velocities
    let mass = sys.mass_matrix(&q, ws).unwrap();
    let uv = DVector::from_vec(u.clone());
    let ke_m = 0.5 * uv.dot(&(&mass * &uv));
    let ke_b = ke_from_bodies(&st["bodies"]);
    let ke_e = sys.energy(&q, &u, ws).unwrap().kinetic;
    let rel = ((ke_m - ke_b).abs()).max((ke_e - ke_b).abs()) / ke_b;
    worst.kinetic = worst.kinetic.max(rel);
    assert!(
        rel < 1e-9,
        "{}: kinetic energy 1/2 u^T M u = {ke_m}, Energy::kinetic = {ke_e}, from OpenSim's body velocities {ke_b}",
        file.display()
    );
}

/// Bushing records at `(q, u)` (damping through the deflection rates)
/// against OpenSim's, relative to the largest.
fn check_records(
    sys: &System,
    ws: &mut Workspace,
    st: &Value,
    q: &[f64],
    u: &[f64],
    file: &std::path::Path,
    worst: &mut Worst,
) {
    let recs = sys.bushing_records(q, Some(u), ws).unwrap();
    let want_rec = st["bushing_records"].as_object().unwrap();
    assert_eq!(recs.len(), want_rec.len());
    let scale = want_rec
        .values()
        .flat_map(|v| {
            v.as_array()
                .unwrap()
                .iter()
                .map(|x| x.as_f64().unwrap().abs())
        })
        .fold(0.0f64, f64::max);
    for (bn, rec) in &recs {
        for (k, v) in rec.record_values.iter().enumerate() {
            let w = want_rec[bn][k].as_f64().unwrap();
            let rel = (v - w).abs() / scale;
            worst.records = worst.records.max(rel);
            assert!(
                rel < 1e-9,
                "{}: {bn} record[{k}] = {v}, OpenSim {w}",
                file.display()
            );
        }
    }
}

/// Forward simulation: implicit midpoint at dt = 2e-5 and 1e-5; the
/// method is symmetric (error in even powers of dt), so Richardson
/// extrapolation (4 x_{dt/2} - x_dt) / 3 removes the O(dt^2) term and
/// leaves the dynamics themselves to compare with OpenSim.
fn check_simulation(
    sys: &System,
    ws: &mut Workspace,
    sim: &Value,
    file: &std::path::Path,
    worst: &mut Worst,
) {
    let n = sys.n_dofs();
    let q0 = by_name(sys, &sim["q0"]);
    let u0 = by_name(sys, &sim["u0"]);
    let duration = sim["duration"].as_f64().unwrap();
    let mut finals = Vec::new();
    for dt in [2e-5, 1e-5] {
        let mut integ = Integrator::new(sys, dt);
        let traj = integ
            .run(sys, &LoadSet::empty(), ws, &q0, &u0, duration, 1_000_000)
            .unwrap();
        let last = traj.last().unwrap().clone();
        assert!((last.time - duration).abs() < 1e-12);
        finals.push(last);
    }
    let want_q = by_name(sys, &sim["q"]);
    let want_u = by_name(sys, &sim["u"]);
    let u_scale = max_abs(&want_u).max(1.0);
    let (mut err_coarse, mut err_fine) = (0.0f64, 0.0f64);
    for i in 0..n {
        let (c, f) = (&finals[0], &finals[1]);
        let xq = (4.0 * f.q[i] - c.q[i]) / 3.0;
        let xu = (4.0 * f.u[i] - c.u[i]) / 3.0;
        err_coarse = err_coarse
            .max((c.q[i] - want_q[i]).abs())
            .max((c.u[i] - want_u[i]).abs() / u_scale);
        err_fine = err_fine
            .max((f.q[i] - want_q[i]).abs())
            .max((f.u[i] - want_u[i]).abs() / u_scale);
        let dq = (xq - want_q[i]).abs();
        let du = (xu - want_u[i]).abs() / u_scale;
        worst.simulation = worst.simulation.max(dq).max(du);
        assert!(
            dq < 1e-7 && du < 1e-7,
            "{}: after {duration} s {}: q {xq} vs OpenSim {}, u {xu} vs OpenSim {}",
            file.display(),
            sys.dof_name(DofIndex(i)),
            want_q[i],
            want_u[i]
        );
    }
    // the raw dt = 1e-5 run is within 1e-6, and second order
    assert!(
        err_fine < 1e-6,
        "{}: dt = 1e-5 error {err_fine:e}",
        file.display()
    );
    let ratio = err_coarse / err_fine;
    assert!(
        (3.0..5.0).contains(&ratio),
        "{}: halving dt divides the error by {ratio} (second order: 4)",
        file.display()
    );
    worst.raw_simulation = worst.raw_simulation.max(err_fine);
}

/// Static equilibrium of the model in `file` under OpenSim's reduced
/// gravity `sc["gravity"]` against OpenSim's.
fn check_statics(sc: &Value, file: &std::path::Path, worst: &mut Worst) {
    assert!(
        sc["residual"].as_f64().unwrap() < 1e-9,
        "OpenSim's Newton did not converge"
    );
    let mut spec = SystemSpec::read_osim(file).unwrap();
    spec.gravity = vec3(&sc["gravity"]);
    let sys = System::new(&spec).unwrap();
    let mut ws = Workspace::new(&sys);
    let sol = sys
        .solve_static(
            &LoadSet::empty(),
            sys.default_q().as_slice(),
            &mut ws,
            &StaticOptions::default(),
        )
        .unwrap();
    let want = by_name(&sys, &sc["q"]);
    for (i, (got, w)) in sol.q.iter().zip(&want).enumerate() {
        let dq = (got - w).abs();
        worst.equilibrium = worst.equilibrium.max(dq);
        assert!(
            dq < 1e-8,
            "{}: equilibrium {} = {got} vs OpenSim {w}",
            file.display(),
            sys.dof_name(DofIndex(i)),
        );
    }
}

/// The same chains without OpenSim: the mass matrix in the speeds is the
/// kinetic-energy metric of body velocities obtained by differentiating
/// the body poses along `qdot = N(q) u` (central differences).
#[test]
fn kinetic_energy_matches_body_velocities_by_finite_differences() {
    let Some(py) = common::opensim_python() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path().to_str().unwrap();
    // the script only serves to build the .osim files here
    let out = common::run_py(&py, "free_ball_chains.py", &[d, "7", "1"]);
    let m = &out["models"][0];
    let file = std::path::PathBuf::from(m["file"].as_str().unwrap());
    let spec = SystemSpec::read_osim(&file).unwrap();
    let sys = System::new(&spec).unwrap();
    let mut ws = Workspace::new(&sys);
    let n = sys.n_dofs();
    for st in m["states"].as_array().unwrap() {
        let q = by_name(&sys, &st["q"]);
        let u = by_name(&sys, &st["u"]);
        let mut qd = vec![0.0; n];
        sys.qdot(&q, &u, &mut qd).unwrap();
        let h = 1e-6;
        let at = |s: f64| -> Vec<f64> { q.iter().zip(&qd).map(|(a, b)| a + s * b).collect() };
        let xp = sys.body_transforms(&at(h)).unwrap();
        let xm = sys.body_transforms(&at(-h)).unwrap();
        let x0 = sys.body_transforms(&q).unwrap();
        let mut ke = 0.0;
        for (k, (name, x)) in x0.iter().enumerate() {
            let b = spec.bodies.iter().find(|b| &b.name == name).unwrap();
            let r = x.rotation.to_rotation_matrix().into_inner();
            let rp = xp[k].1.rotation.to_rotation_matrix().into_inner();
            let rm = xm[k].1.rotation.to_rotation_matrix().into_inner();
            let rdot = (rp - rm) / (2.0 * h);
            let wx = rdot * r.transpose();
            let w = Vector3::new(
                wx[(2, 1)] - wx[(1, 2)],
                wx[(0, 2)] - wx[(2, 0)],
                wx[(1, 0)] - wx[(0, 1)],
            ) * 0.5;
            let cp = xp[k].1 * nalgebra::Point3::from(b.com);
            let cm = xm[k].1 * nalgebra::Point3::from(b.com);
            let v = (cp - cm) / (2.0 * h);
            let ig = r * b.inertia * r.transpose();
            ke += 0.5 * b.mass * v.norm_squared() + 0.5 * w.dot(&(ig * w));
        }
        let mass: DMatrix<f64> = sys.mass_matrix(&q, &mut ws).unwrap();
        let uv = DVector::from_vec(u.clone());
        let ke_m = 0.5 * uv.dot(&(&mass * &uv));
        assert!(
            (ke_m - ke).abs() < 1e-7 * ke,
            "1/2 u^T M u = {ke_m} vs body velocities {ke}"
        );
        // with u taken as the coordinate rates the energy differs (the map matters)
        let qv = DVector::from_vec(qd.clone());
        let ke_wrong = 0.5 * qv.dot(&(&mass * &qv));
        assert!((ke_wrong - ke).abs() > 1e-4 * ke);
    }
}
