//! Statics: equilibria against analytic solutions, the tangent and the stiffness sensitivities against finite differences, symmetry, refused inputs.

use super::*;

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
    let r = crate::osim::model::body_fixed_xyz(&qr).into_inner();
    let m_bushing = r * crate::solver::forces::n_transpose_mul(&qr, &f);
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
                sys.dof_name(DofIndex(i)),
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
    assert!(
        matches!(
            err.solver_error(),
            Some(crate::solver::SolverError::GimbalLock { .. })
        ),
        "{err}"
    );
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
    assert!(
        matches!(
            err.solver_error(),
            // the load continuation stopped short of the full load
            Some(crate::solver::SolverError::ContinuationStopped { reached, .. }) if *reached < 1.0
        ),
        "{err}"
    );
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
