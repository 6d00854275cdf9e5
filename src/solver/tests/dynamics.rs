//! Dynamics: accelerations against analytic pendulums and Lagrange's equations, energy conservation and dissipation, settling to the static equilibrium, free and ball joints.

use super::*;

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
    let mut integ = crate::solver::dynamics::Integrator::new(&sys, 1e-3);
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
    let mut integ = crate::solver::dynamics::Integrator::new(&sys, 2e-4);
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
    let mut integ = crate::solver::dynamics::Integrator::new(&sys, 1e-3);
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
    let mut integ = crate::solver::dynamics::Integrator::new(&sys, 2e-3);
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
    assert!(sys.bushing_on_joint_frames(BushingIndex(0)));
    let mapped: Vec<usize> = (0..15)
        .filter(|&i| sys.dof_speed_is_angular_velocity(DofIndex(i)))
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
        let mut integ = crate::solver::dynamics::Integrator::new(&sys, dt);
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
