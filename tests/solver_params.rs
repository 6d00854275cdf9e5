//! The solver's model/data split: a `System` never changes once built.
//! Parameter variants (bushing laws, joint frames) are new systems made by
//! `with_*`; they share the structure, so one `Workspace` and one `LoadSet`
//! serve them all, and the factorised tangent cached in the workspace knows
//! which system it belongs to.
//!
//! Truth: a `System` built fresh from a spec that carries the same
//! parameters. Equilibria must agree to 1e-12 (rad, m) and the sensitivities
//! `T^-1 b` from the cached factorisation to 1e-12 (relative).

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use osim_spine::solver::examples::{spine_chain, thesis_bushing};
use osim_spine::solver::{
    BushingIndex, BushingModel, Load, LoadFrame, StaticOptions, System, SystemSpec, Workspace,
};

const N: usize = 8;

fn loads() -> Vec<Load> {
    vec![
        Load::Moment {
            body: format!("v{N}"),
            vec: Vector3::new(1.5, -0.8, -4.0),
            frame: LoadFrame::Ground,
        },
        Load::Follower {
            from_body: "sacrum".into(),
            to_body: format!("v{N}"),
            magnitude: 150.0,
        },
    ]
}

/// Stiffer, anisotropic law for level `i` (a variant of the thesis bushing).
fn law(i: usize) -> BushingModel {
    let BushingModel::Linear {
        rot_stiffness,
        trans_stiffness,
        rot_damping,
        trans_damping,
    } = thesis_bushing()
    else {
        unreachable!("the thesis bushing is linear");
    };
    let f = 1.0 + 0.3 * i as f64;
    BushingModel::Linear {
        rot_stiffness: rot_stiffness.component_mul(&Vector3::new(f, 2.0, 0.7 * f)),
        trans_stiffness: trans_stiffness * 1.5,
        rot_damping,
        trans_damping,
    }
}

/// A joint-frame offset of a few degrees and millimetres.
fn offset(i: usize) -> Isometry3<f64> {
    let a = 0.02 + 0.01 * i as f64;
    Isometry3::from_parts(
        Translation3::new(0.002, -0.001 * i as f64, 0.0015),
        UnitQuaternion::from_euler_angles(a, -0.5 * a, 0.7 * a),
    )
}

/// The same parameters written into the spec (the fresh build).
fn spec_with(levels: &[usize]) -> SystemSpec {
    let mut spec = spine_chain(N);
    for &i in levels {
        let b = &mut spec.bushings[i];
        b.model = law(i);
        b.frame1.transform *= offset(i);
        b.frame2.transform *= offset(i);
        let j = spec
            .joints
            .iter_mut()
            .find(|j| j.name == b.name.trim_end_matches("_bushing"))
            .expect("joint of the bushing");
        j.x_pf = b.frame1.transform;
        j.x_bm = b.frame2.transform;
    }
    spec
}

/// The same parameters applied to a built system by `with_*`.
fn variant_of(sys: &System, levels: &[usize]) -> System {
    let mut out = sys.clone();
    for &i in levels {
        let b = BushingIndex(i);
        let (x1, x2) = out.bushing_frames(b).expect("bushing");
        out = out
            .with_bushing_model(b, law(i))
            .and_then(|s| s.with_bushing_joint_frames(b, &(x1 * offset(i)), &(x2 * offset(i))))
            .expect("variant");
    }
    out
}

fn solve(sys: &System, ws: &mut Workspace, loads: &osim_spine::solver::LoadSet) -> Vec<f64> {
    sys.solve_static(
        loads,
        sys.default_q().as_slice(),
        ws,
        &StaticOptions::default(),
    )
    .expect("equilibrium")
    .q
    .as_slice()
    .to_vec()
}

fn max_diff(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}

#[test]
fn variants_between_solves_match_fresh_systems() {
    let base = System::new(&spine_chain(N)).expect("system");
    let prepared = base.prepare_loads(&loads()).expect("loads");
    // one workspace, reused across every variant (the cached factorisation in play)
    let mut ws = Workspace::new(&base);
    let q_base = solve(&base, &mut ws, &prepared);
    let mut seen_change = false;
    for levels in [vec![0usize], vec![2, 5], vec![1, 3, 4, 6, 7]] {
        let variant = variant_of(&base, &levels);
        // follower guide points sit on the joint frames: place them on the variant's
        let var_loads = variant.prepare_loads(&loads()).expect("loads");
        let q_var = solve(&variant, &mut ws, &var_loads);
        // fresh system and loads with the same parameters in the spec
        let fresh = System::new(&spec_with(&levels)).expect("fresh system");
        let fresh_loads = fresh.prepare_loads(&loads()).expect("loads");
        let mut fresh_ws = Workspace::new(&fresh);
        let q_fresh = solve(&fresh, &mut fresh_ws, &fresh_loads);
        let d = max_diff(&q_var, &q_fresh);
        assert!(
            d < 1e-12,
            "levels {levels:?}: variant vs fresh differ by {d:e}"
        );
        seen_change |= max_diff(&q_var, &q_base) > 1e-3;
        // sensitivities from the cached factorisation agree with the fresh one
        let rhs: Vec<f64> = (0..variant.n_dofs())
            .map(|i| 1.0 + (i % 7) as f64)
            .collect();
        let (mut a, mut b) = (rhs.clone(), rhs);
        variant.tangent_solve(&ws, &mut a).expect("tangent");
        fresh.tangent_solve(&fresh_ws, &mut b).expect("tangent");
        let scale = b.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        assert!(
            max_diff(&a, &b) < 1e-12 * scale,
            "levels {levels:?}: T^-1 b differs"
        );
    }
    assert!(seen_change, "the variants must move the equilibrium");
    // the base system is unchanged by its variants
    let mut ws2 = Workspace::new(&base);
    assert_eq!(solve(&base, &mut ws2, &prepared), q_base);
}

#[test]
fn stale_factorisation_is_refused() {
    let base = System::new(&spine_chain(N)).expect("system");
    let prepared = base.prepare_loads(&loads()).expect("loads");
    let mut ws = Workspace::new(&base);
    solve(&base, &mut ws, &prepared);
    let variant = variant_of(&base, &[3]);
    let mut rhs = vec![1.0; base.n_dofs()];
    let err = variant.tangent_solve(&ws, &mut rhs).expect_err("stale");
    assert!(err.to_string().contains("another parameter set"), "{err}");
    base.tangent_solve(&ws, &mut rhs)
        .expect("own factorisation");
}

#[test]
fn foreign_workspace_and_loads_are_errors_not_panics() {
    let small = System::new(&spine_chain(3)).expect("system");
    let big = System::new(&spine_chain(N)).expect("system");
    let mut ws_small = Workspace::new(&small);
    let loads_big = big.prepare_loads(&loads()).expect("loads");
    let q = big.default_q();
    let err = big
        .solve_static(
            &loads_big,
            q.as_slice(),
            &mut ws_small,
            &StaticOptions::default(),
        )
        .expect_err("foreign workspace");
    assert!(err.to_string().contains("another system"), "{err}");
    let loads_small = small
        .prepare_loads(&[Load::Moment {
            body: "v3".into(),
            vec: Vector3::new(0.0, 0.0, 1.0),
            frame: LoadFrame::Ground,
        }])
        .expect("loads");
    let mut ws_big = Workspace::new(&big);
    let err = big
        .solve_static(
            &loads_small,
            q.as_slice(),
            &mut ws_big,
            &StaticOptions::default(),
        )
        .expect_err("foreign loads");
    assert!(err.to_string().contains("another system"), "{err}");
    // the same structure built separately shares workspaces and loads, but
    // not a factorisation
    let twin = System::new(&spine_chain(N)).expect("system");
    let a = big
        .static_residual(q.as_slice(), &loads_big, &mut ws_big)
        .expect("own")
        .to_vec();
    let b = twin
        .static_residual(q.as_slice(), &loads_big, &mut ws_big)
        .expect("twin")
        .to_vec();
    assert_eq!(a, b);
    big.solve_static(
        &loads_big,
        q.as_slice(),
        &mut ws_big,
        &StaticOptions::default(),
    )
    .expect("solve");
    let mut rhs = vec![1.0; big.n_dofs()];
    twin.tangent_solve(&ws_big, &mut rhs)
        .expect_err("a twin's factorisation is not its own");
}

/// Reference body order: repeated sweeps over the bodies in spec order,
/// each placing the bodies whose parent is placed (the order outputs have
/// always used).
fn sweep_order(spec: &SystemSpec) -> Vec<String> {
    let nb = spec.bodies.len();
    let parent = |b: usize| {
        spec.joints
            .iter()
            .find(|j| j.child == b)
            .and_then(|j| j.parent)
    };
    let mut placed = vec![false; nb];
    let mut order = Vec::new();
    while order.len() < nb {
        for b in 0..nb {
            if !placed[b] && parent(b).is_none_or(|p| placed[p]) {
                placed[b] = true;
                order.push(spec.bodies[b].name.clone());
            }
        }
    }
    order
}

/// Random trees in shuffled spec order keep the sweep order.
#[test]
fn body_order_is_the_sweep_order_on_shuffled_trees() {
    use rand::seq::SliceRandom;
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    for n in [1usize, 2, 5, 17, 40] {
        let mut spec = spine_chain(n);
        // rewire to a random tree: each body's parent is an earlier body (or ground)
        for b in 1..spec.bodies.len() {
            let p = rng.random_range(0..b);
            let j = spec
                .joints
                .iter_mut()
                .find(|j| j.child == b)
                .expect("joint");
            j.parent = Some(p);
            spec.bushings.retain(|bs| bs.frame2.body != Some(b));
        }
        // shuffle the spec's body indices
        let mut perm: Vec<usize> = (0..spec.bodies.len()).collect();
        perm.shuffle(&mut rng);
        let mut bodies = spec.bodies.clone();
        for (old, &new) in perm.iter().enumerate() {
            bodies[new] = spec.bodies[old].clone();
        }
        spec.bodies = bodies;
        for j in spec.joints.iter_mut() {
            j.child = perm[j.child];
            j.parent = j.parent.map(|p| perm[p]);
        }
        let sys = System::new(&spec).expect("system");
        let names: Vec<String> = sys.body_names().map(String::from).collect();
        assert_eq!(names, sweep_order(&spec), "n = {n}");
    }
}
