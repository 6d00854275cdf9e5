//! The structured O(n) statics tangent (the default) against the dense
//! reference tangent (`TangentMethod::Dense`: one dual-number pass per joint,
//! dense LU): on spine chains of 6-68 joints (and a branched tree) under
//! gravity, ground- and body-fixed moments, ground- and body-fixed point
//! forces and follower loads, both Newton solves must reach the same
//! equilibrium within 1e-12 (rad, m) (loads scaled down on long chains to
//! stay below buckling), and the factorised tangents must give
//! the same sensitivities `T^-1 b`.

use nalgebra::{
    DMatrix, Isometry3, Matrix3, Matrix6, Translation3, UnitQuaternion, Vector3, Vector6,
};
use osim_spine::solver::examples::{add_level, spine_chain, thesis_bushing};
use osim_spine::solver::{
    BodySpec, BushingModel, Load, LoadFrame, StaticOptions, StaticSolution, System, SystemSpec,
    TangentMethod, Workspace,
};

/// Load scale keeping long chains (up to 1.7 m of 25 mm levels) well below
/// their buckling loads, where Newton with a residual line search converges
/// (both tangents fail alike beyond): 1 up to 8 joints, then (8 / n)^2.
fn scale(n: usize) -> f64 {
    (8.0 / n as f64).powi(2).min(1.0)
}

fn loads_for(n: usize) -> Vec<Load> {
    let s = scale(n);
    let top = format!("v{n}");
    let mid = format!("v{}", n / 2 + 1);
    vec![
        Load::Moment {
            body: top.clone(),
            vec: Vector3::new(1.5, -1.0, -6.0) * s,
            frame: LoadFrame::Body,
        },
        Load::Moment {
            body: mid.clone(),
            vec: Vector3::new(-0.8, 0.5, 2.0) * s,
            frame: LoadFrame::Ground,
        },
        Load::Force {
            body: mid,
            point_in_body: Vector3::new(0.02, 0.01, -0.01),
            vec: Vector3::new(10.0, -40.0, 5.0) * s,
            frame: LoadFrame::Ground,
        },
        Load::Force {
            body: top.clone(),
            point_in_body: Vector3::new(-0.015, 0.005, 0.01),
            vec: Vector3::new(-4.0, -25.0, 3.0) * s,
            frame: LoadFrame::Body,
        },
        Load::Follower {
            from_body: "sacrum".into(),
            to_body: top,
            magnitude: 250.0 * s,
        },
    ]
}

fn solve(sys: &System, loads: &[Load], method: TangentMethod) -> (StaticSolution, Workspace) {
    let loads = sys.prepare_loads(loads).expect("loads");
    let mut ws = Workspace::new(sys);
    let opts = StaticOptions {
        tangent: method,
        ..StaticOptions::default()
    };
    let sol = sys
        .solve_static(&loads, sys.default_q().as_slice(), &mut ws, &opts)
        .expect("solve");
    (sol, ws)
}

/// Same equilibrium and same sensitivities from both tangents.
fn compare(sys: &System, loads: &[Load], label: &str) {
    let (st, wt) = solve(sys, loads, TangentMethod::Auto);
    let (sd, wd) = solve(sys, loads, TangentMethod::Dense);
    assert!(
        wt.used_structured_tangent(),
        "{label}: structured path not used"
    );
    assert!(!wd.used_structured_tangent());
    assert!(st.residual_norm <= 1e-9 && sd.residual_norm <= 1e-9);
    let dq = (&st.q - &sd.q).amax();
    let deflection = st.q.amax();
    println!(
        "{label}: {} dofs, iterations {} (structured) / {} (dense), max |q_s - q_d| = {dq:.2e}, max |q| = {deflection:.3}",
        sys.n_dofs(),
        st.iterations,
        sd.iterations
    );
    assert!(
        deflection > 1e-3,
        "{label}: the loads must deflect the chain"
    );
    assert!(dq <= 1e-12, "{label}: equilibria differ by {dq:e}");
    // sensitivities with the factorised tangents of the last Newton step
    let n = sys.n_dofs();
    let b = DMatrix::from_fn(n, 3, |i, j| ((i * (j + 3)) % 7) as f64 - 3.0);
    for j in 0..3 {
        let mut xs: Vec<f64> = b.column(j).iter().copied().collect();
        let mut xd = xs.clone();
        sys.tangent_solve(&wt, &mut xs).expect("structured solve");
        sys.tangent_solve(&wd, &mut xd).expect("dense solve");
        let scale = xd.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        let diff = xs
            .iter()
            .zip(&xd)
            .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
        assert!(
            diff <= 1e-8 * scale,
            "{label}: sensitivities differ by {diff:e} (scale {scale:e})"
        );
    }
}

#[test]
fn structured_and_dense_tangents_give_the_same_equilibrium_on_chains() {
    for n in [6usize, 12, 17, 34, 68] {
        let mut spec = spine_chain(n);
        spec.gravity = Vector3::new(0.0, -9.80665, 0.0) * scale(n);
        let sys = System::new(&spec).expect("system");
        compare(&sys, &loads_for(n), &format!("chain {n}"));
    }
}

#[test]
fn structured_and_dense_agree_with_general_bushing_formula() {
    // every bushing on the general (pose-based) path: the bushing wrenches
    // couple parent and child bodies in the tangent
    let mut spec = spine_chain(12);
    spec.gravity = Vector3::new(0.0, -9.80665, 0.0);
    let sys = System::new(&spec).expect("system").without_fast_paths();
    compare(&sys, &loads_for(12), "chain 12, general bushings");
}

#[test]
fn structured_and_dense_agree_on_a_branched_tree() {
    // a rib-like pair of three-body branches on v4 of a 10-joint chain, with
    // bushings on frames offset from the joint frames
    let mut spec: SystemSpec = spine_chain(10);
    spec.gravity = Vector3::new(0.0, -9.80665, 0.0);
    let iso = |x: f64, y: f64, z: f64, rx: f64, ry: f64| {
        Isometry3::from_parts(
            Translation3::new(x, y, z),
            UnitQuaternion::from_euler_angles(rx, ry, 0.0),
        )
    };
    for side in [-1.0f64, 1.0] {
        let mut parent = 4;
        for k in 0..3 {
            spec.bodies.push(BodySpec {
                name: format!("rib{}{k}", if side < 0.0 { "l" } else { "r" }),
                mass: 0.2,
                com: Vector3::new(0.0, 0.0, 0.01 * side),
                inertia: Matrix3::identity() * 1e-4,
            });
            let child = spec.bodies.len() - 1;
            add_level(
                &mut spec,
                &format!("j{child}"),
                Some(parent),
                child,
                iso(0.0, 0.004, 0.03 * side, 0.1 * side, 0.05),
                iso(0.0, -0.003, 0.0, 0.0, 0.02 * side),
                thesis_bushing(),
            );
            if let Some(b) = spec.bushings.last_mut() {
                b.frame2.transform = iso(0.002, -0.003, 0.001, 0.0, 0.03 * side);
            }
            parent = child;
        }
    }
    let sys = System::new(&spec).expect("system");
    let mut loads = loads_for(10);
    loads.push(Load::Force {
        body: "ribl2".into(),
        point_in_body: Vector3::new(0.0, 0.0, -0.02),
        vec: Vector3::new(0.0, -15.0, -5.0),
        frame: LoadFrame::Ground,
    });
    loads.push(Load::Follower {
        from_body: "v4".into(),
        to_body: "ribr2".into(),
        magnitude: 40.0,
    });
    compare(&sys, &loads, "branched tree");
}

#[test]
fn structured_and_dense_agree_with_coupled_bushings() {
    // 6x6 coupled stiffness (rotation-rotation and rotation-translation
    // coupling), on the fast path and on the general formula
    let mut k = Matrix6::from_diagonal(&Vector6::new(
        68.8, 291.0, 51.0, 149000.0, 1890000.0, 135000.0,
    ));
    k[(0, 2)] = 12.0;
    k[(2, 0)] = 9.0;
    k[(0, 5)] = 250.0;
    k[(5, 0)] = 250.0;
    k[(1, 3)] = -150.0;
    k[(3, 1)] = -120.0;
    let mut spec = spine_chain(8);
    spec.gravity = Vector3::new(0.0, -9.80665, 0.0);
    for b in spec.bushings.iter_mut() {
        b.model = BushingModel::Coupled {
            stiffness: k,
            damping: [2.3, 2.3, 2.3, 1000.0, 1000.0, 1000.0],
        };
    }
    let sys = System::new(&spec).expect("system");
    compare(&sys, &loads_for(8), "chain 8, coupled bushings");
    let sys = sys.without_fast_paths();
    compare(
        &sys,
        &loads_for(8),
        "chain 8, coupled bushings, general formula",
    );
}
