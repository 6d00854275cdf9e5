//! Forces: the bushing fast path (on the joint's frames) against the general formula for every law, with the sensitivities against finite differences.

use super::*;

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
