//! Unit tests of the solver core against analytic solutions and invariants.

use super::examples::*;
use super::spec::*;
use super::*;
use nalgebra::{Isometry3, Matrix3, Vector3};

fn one_level(gravity: bool, bushing: BushingModel) -> SystemSpec {
    let mut spec = SystemSpec {
        bodies: vec![],
        joints: vec![],
        coordinates: vec![],
        bushings: vec![],
        gravity: if gravity {
            Vector3::new(0.0, -9.80665, 0.0)
        } else {
            Vector3::zeros()
        },
    };
    spec.bodies.push(BodySpec {
        name: "top".into(),
        mass: 1.0,
        com: Vector3::new(-0.01, 0.0, 0.0),
        inertia: ellipsoid_inertia(1.0, 0.04, 0.0175, 0.05),
    });
    add_level(
        &mut spec,
        "j",
        None,
        0,
        Isometry3::identity(),
        Isometry3::identity(),
        bushing,
    );
    spec
}

#[test]
fn pure_moment_rotates_bushing_joint_by_m_over_k() {
    // Ground-fixed moment about Z on a body hanging on an XYZ joint with its
    // bushing on the joint frames: equilibrium rz = M / Kz, nothing else moves.
    let sys = System::new(&one_level(false, thesis_bushing())).unwrap();
    let mut ws = Workspace::new(&sys);
    for m in [-7.5, -1.0, 2.5, 5.0] {
        let loads = sys
            .prepare_loads(&[Load::Moment {
                body: "top".into(),
                vec: Vector3::new(0.0, 0.0, m),
                frame: LoadFrame::Ground,
            }])
            .unwrap();
        let sol = sys
            .solve_static(
                &loads,
                sys.default_q().as_slice(),
                &mut ws,
                &StaticOptions::default(),
            )
            .unwrap();
        let q = &sol.q;
        assert!(
            (q[2] - m / 51.0).abs() < 1e-12,
            "rz {} vs {}",
            q[2],
            m / 51.0
        );
        for i in [0, 1, 3, 4, 5] {
            assert!(q[i].abs() < 1e-12);
        }
        assert!(sol.residual_norm < 1e-9);
    }
}

#[test]
fn body_fixed_moment_about_x_after_z_rotation() {
    // Moment about the body's own X axis: for R = Rx Ry Rz with the bushing
    // generalised force -K q on the joint coordinates, equilibrium satisfies
    // H^T m = K q with m = R e_x * M. Check the residual at the solution by an
    // independent evaluation: moments balance -K q through N^T.
    let sys = System::new(&one_level(false, thesis_bushing())).unwrap();
    let mut ws = Workspace::new(&sys);
    let loads = sys
        .prepare_loads(&[Load::Moment {
            body: "top".into(),
            vec: Vector3::new(3.0, 0.0, 4.0),
            frame: LoadFrame::Body,
        }])
        .unwrap();
    let sol = sys
        .solve_static(
            &loads,
            sys.default_q().as_slice(),
            &mut ws,
            &StaticOptions::default(),
        )
        .unwrap();
    // independent check: the body's moment equilibrium: bushing moment on
    // body 2 is R N^T f with f = -K q; the load is R (3,0,4)
    let q = &sol.q;
    let qr = Vector3::new(q[0], q[1], q[2]);
    let f = Vector3::new(-68.8 * q[0], -291.0 * q[1], -51.0 * q[2]);
    let r = scalar::from_body_xyz(&qr);
    let m_bushing = r * forces::n_transpose_mul(&qr, &f);
    let m_load = r * Vector3::new(3.0, 0.0, 4.0);
    assert!(
        (m_bushing + m_load).norm() < 1e-10,
        "{}",
        (m_bushing + m_load).norm()
    );
}

#[test]
fn tangent_matches_finite_differences() {
    let mut spec = spine_chain(4);
    spec.gravity = Vector3::new(0.0, -9.80665, 0.0);
    let sys = System::new(&spec).unwrap();
    let mut ws = Workspace::new(&sys);
    let loads = sys
        .prepare_loads(&[
            Load::Moment {
                body: "v4".into(),
                vec: Vector3::new(1.0, -2.0, 3.0),
                frame: LoadFrame::Body,
            },
            Load::Force {
                body: "v3".into(),
                point_in_body: Vector3::new(0.01, 0.02, 0.0),
                vec: Vector3::new(5.0, -50.0, 2.0),
                frame: LoadFrame::Ground,
            },
            Load::Follower {
                from_body: "sacrum".into(),
                to_body: "v4".into(),
                magnitude: 300.0,
            },
        ])
        .unwrap();
    let n = sys.n_dofs();
    let q: Vec<f64> = (0..n)
        .map(|i| 0.05 * ((i * 7 % 11) as f64 / 11.0 - 0.5) * if i % 6 < 3 { 1.0 } else { 0.02 })
        .collect();
    let jac = sys.static_tangent(&q, &loads, &mut ws).unwrap();
    let mut max_err: f64 = 0.0;
    let mut max_val: f64 = 0.0;
    for j in 0..n {
        let h = 1e-6 * if j % 6 < 3 { 1.0 } else { 0.01 };
        let mut qp = q.clone();
        qp[j] += h;
        let rp = sys.static_residual(&qp, &loads, &mut ws).unwrap().to_vec();
        let mut qm = q.clone();
        qm[j] -= h;
        let rm = sys.static_residual(&qm, &loads, &mut ws).unwrap().to_vec();
        for i in 0..n {
            let fd = (rp[i] - rm[i]) / (2.0 * h);
            max_err = max_err.max((fd - jac[(i, j)]).abs());
            max_val = max_val.max(jac[(i, j)].abs());
        }
    }
    assert!(
        max_err < 1e-5 * max_val,
        "tangent error {max_err} (scale {max_val})"
    );
}

fn pendulum(l: f64) -> SystemSpec {
    // A point-ish mass on a pin (about Z) at distance l along -Y, gravity -Y.
    SystemSpec {
        bodies: vec![BodySpec {
            name: "bob".into(),
            mass: 2.0,
            com: Vector3::new(0.0, -l, 0.0),
            inertia: Matrix3::from_diagonal(&Vector3::new(0.01, 0.02, 0.03)),
        }],
        joints: vec![JointSpec {
            name: "pin".into(),
            parent: None,
            child: 0,
            x_pf: Isometry3::identity(),
            x_bm: Isometry3::identity(),
            kind: JointKind::Pin { coord: 0 },
        }],
        coordinates: vec![CoordinateSpec {
            name: "theta".into(),
            default: 0.0,
            range: [-10.0, 10.0],
            clamped: false,
            locked: false,
        }],
        bushings: vec![],
        gravity: Vector3::new(0.0, -9.81, 0.0),
    }
}

#[test]
fn pendulum_acceleration_is_analytic() {
    let l = 0.7;
    let sys = System::new(&pendulum(l)).unwrap();
    let mut ws = Workspace::new(&sys);
    let mut a = [0.0];
    for (th, w) in [(0.3, 0.0), (-1.2, 2.0), (2.5, -4.0)] {
        sys.accelerations(&[th], &[w], &LoadSet::empty(), &mut ws, &mut a)
            .unwrap();
        let i_pivot = 0.03 + 2.0 * l * l;
        let expect = -2.0 * 9.81 * l * f64::sin(th) / i_pivot;
        assert!(
            (a[0] - expect).abs() < 1e-12 * expect.abs().max(1.0),
            "{} vs {}",
            a[0],
            expect
        );
    }
}

#[test]
fn accelerations_satisfy_lagrange_equations() {
    // M(q) udot + C(q,u) = tau: check udot against a finite-difference
    // Lagrangian: d/dt dT/du - dT/dq = Q with T = 1/2 u^T M u, using the
    // mass matrix of the CRBA at nearby states.
    let mut spec = spine_chain(3);
    spec.gravity = Vector3::new(0.0, -9.80665, 0.0);
    for b in spec.bushings.iter_mut() {
        b.model = BushingModel::Linear {
            rot_stiffness: Vector3::new(10.0, 20.0, 30.0),
            trans_stiffness: Vector3::new(1e3, 2e3, 3e3),
            rot_damping: Vector3::zeros(),
            trans_damping: Vector3::zeros(),
        };
    }
    let sys = System::new(&spec).unwrap();
    let mut ws = Workspace::new(&sys);
    let n = sys.n_dofs();
    let q: Vec<f64> = (0..n)
        .map(|i| {
            0.3 * (((i * 5 + 3) % 13) as f64 / 13.0 - 0.5) * if i % 6 < 3 { 1.0 } else { 0.05 }
        })
        .collect();
    let u: Vec<f64> = (0..n)
        .map(|i| 2.0 * (((i * 3 + 1) % 7) as f64 / 7.0 - 0.5) * if i % 6 < 3 { 1.0 } else { 0.05 })
        .collect();
    let mut a = vec![0.0; n];
    sys.accelerations(&q, &u, &LoadSet::empty(), &mut ws, &mut a)
        .unwrap();
    // Lagrangian check: M a + (dM/dt) u - 1/2 d(u^T M u)/dq = tau_static(q)
    let m0 = sys.mass_matrix(&q, &mut ws).unwrap();
    let h = 1e-6;
    let qp: Vec<f64> = q.iter().zip(&u).map(|(a, b)| a + h * b).collect();
    let qm: Vec<f64> = q.iter().zip(&u).map(|(a, b)| a - h * b).collect();
    let mdot = (sys.mass_matrix(&qp, &mut ws).unwrap() - sys.mass_matrix(&qm, &mut ws).unwrap())
        / (2.0 * h);
    let uv = nalgebra::DVector::from_vec(u.clone());
    let mut lhs = &m0 * nalgebra::DVector::from_vec(a.clone()) + &mdot * &uv;
    for j in 0..n {
        let mut qp = q.clone();
        qp[j] += h;
        let mut qm = q.clone();
        qm[j] -= h;
        let tp = uv.dot(&(sys.mass_matrix(&qp, &mut ws).unwrap() * &uv));
        let tm = uv.dot(&(sys.mass_matrix(&qm, &mut ws).unwrap() * &uv));
        lhs[j] -= 0.5 * (tp - tm) / (2.0 * h);
    }
    let tau = sys
        .static_residual(&q, &LoadSet::empty(), &mut ws)
        .unwrap()
        .to_vec();
    let scale = tau.iter().fold(1.0f64, |m, v| m.max(v.abs()));
    for j in 0..n {
        assert!(
            (lhs[j] - tau[j]).abs() < 1e-5 * scale,
            "dof {j}: {} vs {}",
            lhs[j],
            tau[j]
        );
    }
}

#[test]
fn no_load_no_gravity_no_motion() {
    let sys = System::new(&spine_chain(5)).unwrap();
    let mut ws = Workspace::new(&sys);
    let n = sys.n_dofs();
    let q0 = sys.default_q();
    let mut a = vec![1.0; n];
    sys.accelerations(
        q0.as_slice(),
        &vec![0.0; n],
        &LoadSet::empty(),
        &mut ws,
        &mut a,
    )
    .unwrap();
    assert!(a.iter().all(|v| v.abs() < 1e-12), "{a:?}");
    let sol = sys
        .solve_static(
            &LoadSet::empty(),
            q0.as_slice(),
            &mut ws,
            &StaticOptions::default(),
        )
        .unwrap();
    assert!(sol.q.iter().all(|v| v.abs() < 1e-14));
    let mut integ = dynamics::Integrator::new(&sys, 1e-3);
    let traj = integ
        .run(
            &sys,
            &LoadSet::empty(),
            &mut ws,
            q0.as_slice(),
            &vec![0.0; n],
            0.05,
            10,
        )
        .unwrap();
    let last = traj.last().unwrap();
    assert!(last.q.iter().all(|v| v.abs() < 1e-14));
}

#[test]
fn energy_is_conserved_without_damping() {
    // Chain with gravity, bushings without damping, started away from rest.
    let mut spec = spine_chain(3);
    spec.gravity = Vector3::new(0.0, -9.80665, 0.0);
    for b in spec.bushings.iter_mut() {
        if let BushingModel::Linear {
            rot_damping,
            trans_damping,
            ..
        } = &mut b.model
        {
            *rot_damping = Vector3::zeros();
            *trans_damping = Vector3::zeros();
        }
    }
    let sys = System::new(&spec).unwrap();
    let mut ws = Workspace::new(&sys);
    let n = sys.n_dofs();
    let q0: Vec<f64> = (0..n)
        .map(|i| {
            if i % 6 < 3 {
                0.05 * ((i % 3) as f64 - 1.0)
            } else {
                0.0
            }
        })
        .collect();
    let u0 = vec![0.0; n];
    let e0 = sys.energy(&q0, &u0, &mut ws).unwrap().total();
    let mut integ = dynamics::Integrator::new(&sys, 2e-4);
    let traj = integ
        .run(&sys, &LoadSet::empty(), &mut ws, &q0, &u0, 0.2, 50)
        .unwrap();
    let scale = sys.energy(&q0, &u0, &mut ws).unwrap().bushing;
    let mut worst: f64 = 0.0;
    for s in &traj {
        let e = sys
            .energy(s.q.as_slice(), s.u.as_slice(), &mut ws)
            .unwrap()
            .total();
        worst = worst.max((e - e0).abs());
    }
    // stated tolerance: 1e-3 of the initial elastic energy at dt = 2e-4 s
    assert!(
        worst < 1e-3 * scale,
        "energy drift {worst} vs scale {scale}"
    );
}

#[test]
fn damping_dissipates_energy() {
    let sys = System::new(&spine_chain(3)).unwrap();
    let mut ws = Workspace::new(&sys);
    let n = sys.n_dofs();
    let q0: Vec<f64> = (0..n)
        .map(|i| if i % 6 == 2 { 0.05 } else { 0.0 })
        .collect();
    let u0 = vec![0.0; n];
    let e0 = sys.energy(&q0, &u0, &mut ws).unwrap().total();
    let mut integ = dynamics::Integrator::new(&sys, 1e-3);
    let traj = integ
        .run(&sys, &LoadSet::empty(), &mut ws, &q0, &u0, 0.5, 100)
        .unwrap();
    let mut prev = e0;
    for s in &traj[1..] {
        let e = sys
            .energy(s.q.as_slice(), s.u.as_slice(), &mut ws)
            .unwrap()
            .total();
        assert!(
            e <= prev + 1e-12 * e0.abs().max(1e-9),
            "energy grew: {e} > {prev}"
        );
        prev = e;
    }
    assert!(prev < 0.01 * e0);
}

#[test]
fn dynamics_settles_to_static_equilibrium() {
    let sys = System::new(&spine_chain(3)).unwrap();
    let mut ws = Workspace::new(&sys);
    let n = sys.n_dofs();
    let loads = sys
        .prepare_loads(&[Load::Moment {
            body: "v3".into(),
            vec: Vector3::new(0.0, 0.0, 2.0),
            frame: LoadFrame::Ground,
        }])
        .unwrap();
    let q0 = sys.default_q();
    let st = sys
        .solve_static(&loads, q0.as_slice(), &mut ws, &StaticOptions::default())
        .unwrap();
    let mut integ = dynamics::Integrator::new(&sys, 2e-3);
    let traj = integ
        .run(
            &sys,
            &loads,
            &mut ws,
            q0.as_slice(),
            &vec![0.0; n],
            3.0,
            1000,
        )
        .unwrap();
    let last = traj.last().unwrap();
    let err = (&last.q - &st.q).amax();
    assert!(
        err < 1e-6,
        "settled state differs from equilibrium by {err}"
    );
}

#[test]
fn mirror_symmetric_model_and_load_give_mirror_answers() {
    // Mirror about the sagittal plane (z -> -z): a chain without lateral
    // asymmetry under +Mx vs -Mx, +My vs -My gives rx, ry, tz negated and
    // rz, tx, ty equal.
    let spec = spine_chain(5);
    let sys = System::new(&spec).unwrap();
    let mut ws = Workspace::new(&sys);
    let q0 = sys.default_q();
    for m in [
        Vector3::new(4.0, 0.0, 0.0),
        Vector3::new(0.0, 3.0, 0.0),
        Vector3::new(2.0, 1.0, 1.5),
    ] {
        let mirrored = Vector3::new(-m.x, -m.y, m.z);
        let a = sys
            .solve_static(
                &sys.prepare_loads(&[Load::Moment {
                    body: "v5".into(),
                    vec: m,
                    frame: LoadFrame::Ground,
                }])
                .unwrap(),
                q0.as_slice(),
                &mut ws,
                &StaticOptions::default(),
            )
            .unwrap();
        let b = sys
            .solve_static(
                &sys.prepare_loads(&[Load::Moment {
                    body: "v5".into(),
                    vec: mirrored,
                    frame: LoadFrame::Ground,
                }])
                .unwrap(),
                q0.as_slice(),
                &mut ws,
                &StaticOptions::default(),
            )
            .unwrap();
        for i in 0..sys.n_dofs() {
            let sign = match i % 6 {
                0 | 1 | 5 => -1.0,
                _ => 1.0,
            };
            assert!(
                (a.q[i] - sign * b.q[i]).abs() < 1e-12,
                "dof {} {} vs {}",
                sys.dof_name(i),
                a.q[i],
                b.q[i]
            );
        }
    }
}

#[test]
fn unknown_body_and_gimbal_lock_are_errors() {
    let sys = System::new(&spine_chain(2)).unwrap();
    let err = sys
        .prepare_loads(&[Load::Moment {
            body: "nope".into(),
            vec: Vector3::x(),
            frame: LoadFrame::Ground,
        }])
        .unwrap_err();
    assert!(err.to_string().contains("nope"));
    let mut spec = spine_chain(2);
    spec.bushings[0].frame2.transform =
        iso([0.0, -0.0125, 0.0], [0.0, std::f64::consts::FRAC_PI_2, 0.0]);
    let sys = System::new(&spec).unwrap();
    let mut ws = Workspace::new(&sys);
    let err = sys
        .solve_static(
            &LoadSet::empty(),
            sys.default_q().as_slice(),
            &mut ws,
            &StaticOptions::default(),
        )
        .unwrap_err();
    assert!(err.to_string().contains("gimbal"), "{err}");
}

#[test]
fn too_large_load_is_an_error() {
    let sys = System::new(&spine_chain(3)).unwrap();
    let mut ws = Workspace::new(&sys);
    let loads = sys
        .prepare_loads(&[Load::Moment {
            body: "v3".into(),
            vec: Vector3::new(0.0, 0.0, 5000.0),
            frame: LoadFrame::Ground,
        }])
        .unwrap();
    let err = sys
        .solve_static(
            &loads,
            sys.default_q().as_slice(),
            &mut ws,
            &StaticOptions::default(),
        )
        .unwrap_err();
    assert!(matches!(err, crate::Error::Numerical { .. }), "{err}");
}

#[test]
fn sensitivities_match_finite_differences() {
    let spec = spine_chain(3);
    let sys = System::new(&spec).unwrap();
    let mut ws = Workspace::new(&sys);
    let loads = sys
        .prepare_loads(&[Load::Moment {
            body: "v3".into(),
            vec: Vector3::new(1.0, 2.0, -3.0),
            frame: LoadFrame::Body,
        }])
        .unwrap();
    let opts = StaticOptions::default();
    let sol = sys
        .solve_static(&loads, sys.default_q().as_slice(), &mut ws, &opts)
        .unwrap();
    let n = sys.n_dofs();
    let mut dr = nalgebra::DMatrix::zeros(n, 18);
    sys.dtau_dstiffness(sol.q.as_slice(), &mut ws, &mut dr)
        .unwrap();
    // re-solve to get the tangent factorised at the solution
    let sol = sys
        .solve_static(&loads, sol.q.as_slice(), &mut ws, &opts)
        .unwrap();
    for p in [2usize, 7, 15] {
        let mut col: Vec<f64> = dr.column(p).iter().map(|v| -v).collect();
        sys.tangent_solve(&ws, &mut col).unwrap();
        // finite difference on the stiffness
        let mut spec2 = spec.clone();
        let h = 1e-4;
        let (bi, k) = (p / 6, p % 6);
        if let BushingModel::Linear {
            rot_stiffness,
            trans_stiffness,
            ..
        } = &mut spec2.bushings[bi].model
        {
            let base = if k < 3 {
                &mut rot_stiffness[k]
            } else {
                &mut trans_stiffness[k - 3]
            };
            let rel = h * *base;
            *base += rel;
            let sys2 = System::new(&spec2).unwrap();
            let mut ws2 = Workspace::new(&sys2);
            let s2 = sys2
                .solve_static(&loads, sol.q.as_slice(), &mut ws2, &opts)
                .unwrap();
            for i in 0..n {
                let fd = (s2.q[i] - sol.q[i]) / rel;
                assert!(
                    (fd - col[i]).abs() < 1e-3 * col.iter().fold(1e-12f64, |m, v| m.max(v.abs())),
                    "p {p} dof {i}: fd {fd} vs {}",
                    col[i]
                );
            }
        }
    }
}

#[test]
fn fast_bushing_path_equals_general_formula() {
    let mut spec = spine_chain(4);
    spec.gravity = Vector3::new(0.0, -9.80665, 0.0);
    let fast = System::new(&spec).unwrap();
    assert!(fast.bushings.iter().all(|b| b.fast.is_some()));
    let slow = System::new(&spec).unwrap().without_fast_paths();
    let mut wf = Workspace::new(&fast);
    let mut wsl = Workspace::new(&slow);
    let loads = fast
        .prepare_loads(&[Load::Moment {
            body: "v4".into(),
            vec: Vector3::new(1.0, -2.0, 3.0),
            frame: LoadFrame::Body,
        }])
        .unwrap();
    let n = fast.n_dofs();
    let q: Vec<f64> = (0..n)
        .map(|i| {
            0.4 * (((i * 7 + 2) % 11) as f64 / 11.0 - 0.5) * if i % 6 < 3 { 1.0 } else { 0.02 }
        })
        .collect();
    let u: Vec<f64> = (0..n)
        .map(|i| (((i * 3 + 1) % 7) as f64 / 7.0 - 0.5) * if i % 6 < 3 { 1.0 } else { 0.02 })
        .collect();
    let rf = fast.static_residual(&q, &loads, &mut wf).unwrap().to_vec();
    let rs = slow.static_residual(&q, &loads, &mut wsl).unwrap().to_vec();
    for i in 0..n {
        assert!(
            (rf[i] - rs[i]).abs() < 1e-9 * (1.0 + rs[i].abs()),
            "{i}: {} vs {}",
            rf[i],
            rs[i]
        );
    }
    let tf = fast.static_tangent(&q, &loads, &mut wf).unwrap();
    let ts = slow.static_tangent(&q, &loads, &mut wsl).unwrap();
    assert!((&tf - &ts).amax() < 1e-8 * ts.amax());
    let mut af = vec![0.0; n];
    let mut asl = vec![0.0; n];
    fast.accelerations(&q, &u, &loads, &mut wf, &mut af)
        .unwrap();
    slow.accelerations(&q, &u, &loads, &mut wsl, &mut asl)
        .unwrap();
    let scale = asl.iter().fold(1.0f64, |m, v| m.max(v.abs()));
    for i in 0..n {
        assert!(
            (af[i] - asl[i]).abs() < 1e-9 * scale,
            "{i}: {} vs {}",
            af[i],
            asl[i]
        );
    }
}

/// Every force law: the fast path (bushing on its joint's frames) equals the
/// general formula (deflection from the frames, moment through N^T) in the
/// static residual, its tangent, the accelerations with damping, and the
/// stiffness sensitivities equal finite differences of the residual.
#[test]
fn every_law_fast_path_equals_general_formula_and_sensitivities() {
    for law in non_linear_laws() {
        // A 3-level chain with the law on every bushing, with and without
        // the fast path.
        let mut spec = spine_chain(3);
        for b in spec.bushings.iter_mut() {
            b.model = law.clone();
        }
        let fast = System::new(&spec).unwrap();
        assert!(fast.bushings.iter().all(|b| b.fast.is_some()));
        let slow = System::new(&spec).unwrap().without_fast_paths();
        // A deflected, moving state.
        let n = fast.n_dofs();
        let q: Vec<f64> = (0..n)
            .map(|i| {
                0.3 * (((i * 7 + 2) % 11) as f64 / 11.0 - 0.5) * if i % 6 < 3 { 1.0 } else { 0.02 }
            })
            .collect();
        let u: Vec<f64> = (0..n)
            .map(|i| (((i * 3 + 1) % 7) as f64 / 7.0 - 0.5) * if i % 6 < 3 { 1.0 } else { 0.02 })
            .collect();
        // Residual, tangent and accelerations agree.
        assert_fast_path_equals_general(&law, &fast, &slow, &q, &u);
        // d tau / d p against central differences of the residual.
        assert_eq!(fast.n_stiffness_params(), 3 * law.n_stiffness_params());
        for sys in [&fast, &slow] {
            assert_sensitivities_are_differences(&law, &spec, sys, &q);
        }
    }
}

/// A per-DoF law (every curve kind), a coupled 6x6 law and an expression
/// law, with damping.
fn non_linear_laws() -> Vec<BushingModel> {
    let mut k = nalgebra::Matrix6::from_diagonal(&nalgebra::Vector6::new(
        68.8, 291.0, 51.0, 149000.0, 1890000.0, 135000.0,
    ));
    k[(0, 2)] = 8.0;
    k[(2, 0)] = 8.0;
    k[(1, 3)] = -300.0;
    k[(3, 1)] = -300.0;
    let damping = [2.3, 2.3, 2.3, 1000.0, 1000.0, 1000.0];
    vec![
        BushingModel::PerDof {
            curves: Box::new([
                Curve::Sinh { k: 68.8, a: 0.05 },
                Curve::Cubic { k: 291.0, c: 500.0 },
                Curve::Bilinear {
                    k_neg: 40.0,
                    k_pos: 60.0,
                },
                Curve::Linear { k: 149000.0 },
                Curve::Function(Function::PiecewiseLinear {
                    x: vec![-0.01, 0.0, 0.01],
                    y: vec![-20000.0, 0.0, 15000.0],
                }),
                Curve::Linear { k: 135000.0 },
            ]),
            damping,
        },
        BushingModel::Coupled {
            stiffness: k,
            damping,
        },
        BushingModel::Expression {
            exprs: Box::new(
                [
                    "68.8*theta_x*(1+100*max(0,-delta_y))",
                    "291*theta_y+2*theta_x",
                    "51*sinh(theta_z)",
                    "149000*delta_x",
                    "1890000*delta_y",
                    "135000*delta_z+1e9*delta_z^3",
                ]
                .map(|s| Expr::parse(s).unwrap()),
            ),
            damping,
        },
    ]
}

/// The static residual, its tangent and the accelerations of `fast` and
/// `slow` (the same system without fast paths) agree at `(q, u)` under a
/// body moment.
fn assert_fast_path_equals_general(
    law: &BushingModel,
    fast: &System,
    slow: &System,
    q: &[f64],
    u: &[f64],
) {
    let n = fast.n_dofs();
    let mut wf = Workspace::new(fast);
    let mut wsl = Workspace::new(slow);
    let loads = fast
        .prepare_loads(&[Load::Moment {
            body: "v3".into(),
            vec: Vector3::new(1.0, -2.0, 3.0),
            frame: LoadFrame::Body,
        }])
        .unwrap();
    let rf = fast.static_residual(q, &loads, &mut wf).unwrap().to_vec();
    let rs = slow.static_residual(q, &loads, &mut wsl).unwrap().to_vec();
    for i in 0..n {
        assert!(
            (rf[i] - rs[i]).abs() < 1e-9 * (1.0 + rs[i].abs()),
            "{law:?} {i}"
        );
    }
    let tf = fast.static_tangent(q, &loads, &mut wf).unwrap();
    let ts = slow.static_tangent(q, &loads, &mut wsl).unwrap();
    assert!((&tf - &ts).amax() < 1e-8 * ts.amax());
    let mut af = vec![0.0; n];
    let mut asl = vec![0.0; n];
    fast.accelerations(q, u, &loads, &mut wf, &mut af).unwrap();
    slow.accelerations(q, u, &loads, &mut wsl, &mut asl)
        .unwrap();
    for i in 0..n {
        assert!((af[i] - asl[i]).abs() < 1e-7 * (1.0 + asl[i].abs()), "{i}");
    }
}

/// The columns of the first bushing's parameters in `sys.dtau_dstiffness`
/// at `q` equal central differences of the unloaded residual of `spec`
/// with that bushing's law `law` re-parameterised.
fn assert_sensitivities_are_differences(
    law: &BushingModel,
    spec: &SystemSpec,
    sys: &System,
    q: &[f64],
) {
    let n = sys.n_dofs();
    let mut ws = Workspace::new(sys);
    let mut d = nalgebra::DMatrix::zeros(n, sys.n_stiffness_params());
    sys.dtau_dstiffness(q, &mut ws, &mut d).unwrap();
    let p0 = law.stiffness_params();
    for j in 0..p0.len() {
        // the coupled law is linear in K: any step is exact
        let h = if matches!(law, BushingModel::Coupled { .. }) {
            1.0
        } else {
            1e-6 * p0[j].abs().max(1e-2)
        };
        let with = |delta: f64| {
            let mut s2 = spec.clone();
            let mut p = p0.clone();
            p[j] += delta;
            s2.bushings[0].model = with_stiffness_params(law, &p);
            let s2 = System::new(&s2).unwrap();
            let mut w2 = Workspace::new(&s2);
            s2.static_residual(q, &LoadSet::empty(), &mut w2)
                .unwrap()
                .to_vec()
        };
        let (a, b) = (with(h), with(-h));
        for row in 0..n {
            let fd = (a[row] - b[row]) / (2.0 * h);
            assert!(
                (fd - d[(row, j)]).abs() < 1e-5 * (1.0 + fd.abs()),
                "param {j} row {row}: {fd} vs {}",
                d[(row, j)]
            );
        }
    }
}

/// `law` with its stiffness parameters replaced by `p` (in the order of
/// `stiffness_params`; function curves and expressions are kept).
fn with_stiffness_params(law: &BushingModel, p: &[f64]) -> BushingModel {
    match law {
        BushingModel::PerDof { curves, damping } => {
            let mut c = curves.clone();
            let mut off = 0;
            for cv in c.iter_mut() {
                let m = cv.params().len();
                let pp = &p[off..off + m];
                let new = match &*cv {
                    Curve::Linear { .. } => Curve::Linear { k: pp[0] },
                    Curve::Cubic { .. } => Curve::Cubic { k: pp[0], c: pp[1] },
                    Curve::Sinh { .. } => Curve::Sinh { k: pp[0], a: pp[1] },
                    Curve::Bilinear { .. } => Curve::Bilinear {
                        k_neg: pp[0],
                        k_pos: pp[1],
                    },
                    other => other.clone(),
                };
                *cv = new;
                off += m;
            }
            BushingModel::PerDof {
                curves: c,
                damping: *damping,
            }
        }
        BushingModel::Coupled { damping, .. } => BushingModel::Coupled {
            stiffness: nalgebra::Matrix6::from_row_slice(p),
            damping: *damping,
        },
        other => other.clone(),
    }
}

/// Ground -> FreeJoint (bushing on the joint frames: the fast path) ->
/// BallJoint (bushing on offset frames) -> FreeJoint (offset frames), with
/// full inertias, soft bushings, optional damping and gravity.
fn free_ball_chain(damped: bool) -> SystemSpec {
    let c = if damped { 1.0 } else { 0.0 };
    let law = BushingModel::Linear {
        rot_stiffness: Vector3::new(8.0, 5.0, 6.0),
        trans_stiffness: Vector3::new(900.0, 1500.0, 700.0),
        rot_damping: Vector3::new(0.05, 0.04, 0.03) * c,
        trans_damping: Vector3::new(3.0, 2.0, 4.0) * c,
    };
    let mut spec = SystemSpec {
        bodies: vec![],
        joints: vec![],
        coordinates: vec![],
        bushings: vec![],
        gravity: Vector3::new(1.0, -9.0, 2.0),
    };
    let coord = |spec: &mut SystemSpec, name: String| {
        spec.coordinates.push(CoordinateSpec {
            name,
            default: 0.0,
            range: [-10.0, 10.0],
            clamped: false,
            locked: false,
        });
        spec.coordinates.len() - 1
    };
    for i in 0..3 {
        let r = nalgebra::Rotation3::from_euler_angles(0.3 * i as f64, -0.2, 0.5);
        let ib = ellipsoid_inertia(1.0 + 0.3 * i as f64, 0.08, 0.05, 0.1);
        spec.bodies.push(BodySpec {
            name: format!("b{i}"),
            mass: 1.0 + 0.3 * i as f64,
            com: Vector3::new(0.02, -0.01 * i as f64, 0.015),
            inertia: r.matrix() * ib * r.matrix().transpose(),
        });
        let x_pf = iso([0.01, 0.05, -0.01], [0.2, -0.3 + 0.1 * i as f64, 0.4]);
        let x_bm = iso([0.0, -0.02, 0.0], [-0.1, 0.25, 0.15 * i as f64]);
        let kind = if i == 1 {
            JointKind::Ball {
                coords: std::array::from_fn(|k| coord(&mut spec, format!("j{i}_{k}"))),
            }
        } else {
            JointKind::Free {
                coords: std::array::from_fn(|k| coord(&mut spec, format!("j{i}_{k}"))),
            }
        };
        let parent = (i > 0).then(|| i - 1);
        spec.joints.push(JointSpec {
            name: format!("j{i}"),
            parent,
            child: i,
            x_pf,
            x_bm,
            kind,
        });
        let (f1, f2) = if i == 0 {
            (x_pf, x_bm)
        } else {
            (
                iso([0.01, 0.05, -0.01], [0.25, -0.3, 0.4]),
                iso([0.001, -0.02, 0.0], [-0.1, 0.3, 0.0]),
            )
        };
        spec.bushings.push(BushingSpec {
            name: format!("bu{i}"),
            frame1: FrameSpec {
                body: parent,
                transform: f1,
            },
            frame2: FrameSpec {
                body: Some(i),
                transform: f2,
            },
            model: law.clone(),
        });
    }
    spec
}

fn free_ball_state(n: usize, seed: usize) -> (Vec<f64>, Vec<f64>) {
    let wave = |i: usize, k: usize| (((i * 7 + k * 3 + seed) % 11) as f64 / 11.0 - 0.5) * 2.0;
    // dofs per joint: 6 (free), 3 (ball), 6 (free); rotations first
    let rot = |i: usize| i < 3 || (6..9).contains(&i) || (9..12).contains(&i);
    let q = (0..n)
        .map(|i| {
            if rot(i) {
                0.6 * wave(i, 1)
            } else {
                0.01 * wave(i, 2)
            }
        })
        .collect();
    let u = (0..n)
        .map(|i| {
            if rot(i) {
                2.0 * wave(i, 3)
            } else {
                0.1 * wave(i, 4)
            }
        })
        .collect();
    (q, u)
}

#[test]
fn free_and_ball_speeds_are_angular_velocities() {
    let sys = System::new(&free_ball_chain(true)).unwrap();
    assert_eq!(sys.n_dofs(), 15);
    assert!(sys.has_angular_velocity_speeds());
    assert!(sys.bushing_on_joint_frames(0));
    let mapped: Vec<usize> = (0..15)
        .filter(|&i| sys.dof_speed_is_angular_velocity(i))
        .collect();
    assert_eq!(mapped, vec![0, 1, 2, 6, 7, 8, 9, 10, 11]);
    let (q, u) = free_ball_state(15, 0);
    let mut qd = vec![0.0; 15];
    sys.qdot(&q, &u, &mut qd).unwrap();
    // the angular velocity of M in F (F axes) from the joint transform's
    // finite-difference derivative along qdot equals the speeds
    for (j, s) in [("j0", 0usize), ("j1", 6), ("j2", 9)] {
        let h = 1e-6;
        let at = |e: f64| -> Vec<f64> { q.iter().zip(&qd).map(|(a, b)| a + e * b).collect() };
        let r = |e: f64| {
            sys.joint_transform(j, &at(e))
                .unwrap()
                .rotation
                .to_rotation_matrix()
                .into_inner()
        };
        let wx = (r(h) - r(-h)) / (2.0 * h) * r(0.0).transpose();
        let w = Vector3::new(wx[(2, 1)], wx[(0, 2)], wx[(1, 0)]);
        for k in 0..3 {
            assert!(
                (w[k] - u[s + k]).abs() < 1e-7,
                "{j}: w {w:?} vs u {:?}",
                &u[s..s + 3]
            );
        }
    }
    // translations keep u = qdot
    assert_eq!(&qd[3..6], &u[3..6]);
    assert_eq!(&qd[12..15], &u[12..15]);
    // round trip
    let mut back = vec![0.0; 15];
    sys.speeds_from_qdot(&q, &qd, &mut back).unwrap();
    for i in 0..15 {
        assert!((back[i] - u[i]).abs() < 1e-13, "{i}");
    }
    // gimbal lock of a Free joint: an error, not a panic or a NaN
    let mut ql = q.clone();
    ql[1] = std::f64::consts::FRAC_PI_2;
    assert!(sys.qdot(&ql, &u, &mut qd).is_err());
    // a CustomJoint system has coordinate-rate speeds
    assert!(!System::new(&spine_chain(2))
        .unwrap()
        .has_angular_velocity_speeds());
}

#[test]
fn free_and_ball_kinetic_energy_equals_body_velocity_energy() {
    let spec = free_ball_chain(true);
    let sys = System::new(&spec).unwrap();
    let mut ws = Workspace::new(&sys);
    let n = sys.n_dofs();
    for seed in 0..4 {
        let (q, u) = free_ball_state(n, seed);
        let mut qd = vec![0.0; n];
        sys.qdot(&q, &u, &mut qd).unwrap();
        // body velocities by central differences of the poses along qdot
        let h = 1e-6;
        let at = |e: f64| -> Vec<f64> { q.iter().zip(&qd).map(|(a, b)| a + e * b).collect() };
        let (xp, xm, x0) = (
            sys.body_transforms(&at(h)).unwrap(),
            sys.body_transforms(&at(-h)).unwrap(),
            sys.body_transforms(&q).unwrap(),
        );
        let mut ke = 0.0;
        for (k, (name, x)) in x0.iter().enumerate() {
            let b = spec.bodies.iter().find(|b| &b.name == name).unwrap();
            let r = x.rotation.to_rotation_matrix().into_inner();
            let rdot = (xp[k].1.rotation.to_rotation_matrix().into_inner()
                - xm[k].1.rotation.to_rotation_matrix().into_inner())
                / (2.0 * h);
            let wx = rdot * r.transpose();
            let w = Vector3::new(
                wx[(2, 1)] - wx[(1, 2)],
                wx[(0, 2)] - wx[(2, 0)],
                wx[(1, 0)] - wx[(0, 1)],
            ) * 0.5;
            let c = |x: &Isometry3<f64>| x * nalgebra::Point3::from(b.com);
            let v = (c(&xp[k].1) - c(&xm[k].1)) / (2.0 * h);
            let ig = r * b.inertia * r.transpose();
            ke += 0.5 * b.mass * v.norm_squared() + 0.5 * w.dot(&(ig * w));
        }
        let m = sys.mass_matrix(&q, &mut ws).unwrap();
        let uv = nalgebra::DVector::from_vec(u.clone());
        let ke_m = 0.5 * uv.dot(&(&m * &uv));
        let ke_e = sys.energy(&q, &u, &mut ws).unwrap().kinetic;
        assert!((ke_m - ke).abs() < 1e-8 * ke, "{ke_m} vs {ke}");
        assert!((ke_e - ke).abs() < 1e-8 * ke, "{ke_e} vs {ke}");
        // reading the speeds as coordinate rates would give another energy
        let qv = nalgebra::DVector::from_vec(qd.clone());
        assert!((0.5 * qv.dot(&(&m * &qv)) - ke).abs() > 1e-3 * ke);
    }
}

#[test]
fn free_and_ball_power_balance_and_energy_conservation() {
    // undamped: d/dt (T + V) = 0 at every state, i.e. u . (M udot) equals
    // the power of the conservative forces; checked through the energy
    // along a short simulation (implicit midpoint: O(dt^2) drift)
    let sys = System::new(&free_ball_chain(false)).unwrap();
    let mut ws = Workspace::new(&sys);
    let n = sys.n_dofs();
    let (q0, u0) = free_ball_state(n, 2);
    let e0 = sys.energy(&q0, &u0, &mut ws).unwrap();
    // instantaneous power: dE/dt along (qdot, udot) by central differences
    let mut qd = vec![0.0; n];
    sys.qdot(&q0, &u0, &mut qd).unwrap();
    let mut a = vec![0.0; n];
    sys.accelerations(&q0, &u0, &LoadSet::empty(), &mut ws, &mut a)
        .unwrap();
    let h = 1e-6;
    let step = |e: f64| -> (Vec<f64>, Vec<f64>) {
        (
            q0.iter().zip(&qd).map(|(x, d)| x + e * d).collect(),
            u0.iter().zip(&a).map(|(x, d)| x + e * d).collect(),
        )
    };
    let (qp, up) = step(h);
    let (qm, um) = step(-h);
    let de = (sys.energy(&qp, &up, &mut ws).unwrap().total()
        - sys.energy(&qm, &um, &mut ws).unwrap().total())
        / (2.0 * h);
    assert!(
        de.abs() < 1e-6 * e0.kinetic,
        "dE/dt = {de} (kinetic energy {})",
        e0.kinetic
    );
    let mut worst = 0.0f64;
    for dt in [2e-4, 1e-4] {
        let mut integ = dynamics::Integrator::new(&sys, dt);
        let traj = integ
            .run(&sys, &LoadSet::empty(), &mut ws, &q0, &u0, 0.1, 10)
            .unwrap();
        let drift = traj.iter().fold(0.0f64, |m, s| {
            let e = sys.energy(s.q.as_slice(), s.u.as_slice(), &mut ws).unwrap();
            m.max((e.total() - e0.total()).abs())
        });
        assert!(drift < 1e-3 * e0.kinetic, "dt {dt}: drift {drift}");
        if worst > 0.0 {
            // second order: halving dt divides the drift by about 4
            assert!(worst / drift > 3.0, "{worst} -> {drift}");
        }
        worst = drift;
    }
}

/// Spec order and system order are two index spaces: a spec listing the
/// child before its parent gets the parent first in the system, and every
/// body index the system hands out (body by name, parent, bushing bodies,
/// body of a dof, coordinate -> dof) is in system order.
#[test]
fn spec_indices_are_mapped_to_system_order() {
    let body = |name: &str| BodySpec {
        name: name.into(),
        mass: 1.0,
        com: Vector3::zeros(),
        inertia: Matrix3::identity() * 1e-3,
    };
    let mut spec = SystemSpec {
        bodies: vec![body("child"), body("parent")],
        joints: vec![],
        coordinates: vec![],
        bushings: vec![],
        gravity: Vector3::zeros(),
    };
    let x = iso([0.0, 0.02, 0.0], [0.0; 3]);
    // spec indices: parent = 1 (on ground), child = 0 (on parent)
    add_level(&mut spec, "upper", Some(1), 0, x, x, thesis_bushing());
    add_level(&mut spec, "lower", None, 1, x, x, thesis_bushing());
    let sys = System::new(&spec).unwrap();
    let (parent, child) = (BodyIndex(0), BodyIndex(1));
    assert_eq!(sys.body_index("parent"), Some(parent));
    assert_eq!(sys.body_index("child"), Some(child));
    assert_eq!(sys.parent_of(child), Some(parent));
    assert_eq!(sys.parent_of(parent), None);
    // bushing 0 ("upper") joins the parent (frame 1) to the child (frame 2)
    assert_eq!(sys.bushing_bodies(0), Some((Some(parent), Some(child))));
    assert_eq!(sys.bushing_bodies(1), Some((None, Some(parent))));
    // dofs are numbered joint by joint in system order: the parent's first
    assert_eq!(sys.dof_of("lower_rx"), Some(0));
    assert_eq!(sys.dof_of("upper_rx"), Some(6));
    assert_eq!(sys.dof_body(0), Some(parent));
    assert_eq!(sys.dof_body(6), Some(child));
    assert_eq!(sys.dof_name(6), "upper_rx");
}
