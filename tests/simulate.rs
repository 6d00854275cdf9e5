//! The load-case library behind `osim-spine simulate`, on the embedded base
//! model: statics against the analytic load path of a pure moment, and the
//! experiment-format kinematics of a case against the body poses.

use osim_spine::calibrate::experiment::{parse_cases, Units};
use osim_spine::embedded::BaseModel;
use osim_spine::simulate::{
    body_pairs, case_record, kinematics_rows, poses, setup, solve_case, SimulateOptions,
};
use osim_spine::solver::{StaticOptions, Workspace};
use std::path::Path;

fn no_gravity() -> SimulateOptions {
    SimulateOptions {
        no_gravity: true,
        dt: 1e-3,
        ..SimulateOptions::default()
    }
}

/// A pure moment on L3 with gravity off: every bushing on the path from L3
/// to the fixed sacrum carries the whole moment (statics of a chain), every
/// bushing above it none.
#[test]
fn pure_moment_runs_down_the_chain_to_the_fixed_body() {
    let doc = BaseModel::locate(None).unwrap().read().unwrap();
    let st = setup(&doc, &no_gravity(), None).unwrap();
    let text = "[[case]]\nid = \"FE\"\nbody = \"lumbar3\"\nmoment = [0.0, 0.0, 5.0]\nmoment_frame = \"ground\"\n";
    let cases = parse_cases(text, Path::new("loads.toml")).unwrap();
    let mut ws = Workspace::new(&st.sys);
    let out = solve_case(&st, &cases[0], &no_gravity(), &mut ws, &mut |_| {}).unwrap();
    assert_eq!(out.info.mode, "static");
    let rec = case_record("base.osim", &st, &cases[0], out, &mut ws).unwrap();
    let below = ["L3_L4", "L4_L5", "L5_S1"];
    let mut seen = 0;
    for (name, b) in &rec.bushings {
        let t = &b.record_values[3..6];
        let torque = (t[0] * t[0] + t[1] * t[1] + t[2] * t[2]).sqrt();
        let force = b.record_values[0..3]
            .iter()
            .map(|f| f * f)
            .sum::<f64>()
            .sqrt();
        if below.iter().any(|l| name.starts_with(l)) {
            seen += 1;
            assert!(
                (torque - 5.0).abs() < 1e-6,
                "{name}: torque {torque} N*m, expected 5"
            );
            assert!(force < 1e-6, "{name}: force {force} N under a pure moment");
        } else {
            assert!(
                torque < 1e-6 && force < 1e-6,
                "{name} above the load carries {torque} N*m, {force} N"
            );
        }
    }
    assert_eq!(
        seen,
        below.len(),
        "bushings: {:?}",
        rec.bushings.keys().collect::<Vec<_>>()
    );
}

/// Kinematics rows are the relative-pose increments of each joint's two
/// bodies: zero for the unloaded case itself, and under a moment about the
/// ground Z axis (flexion-extension) the L3 row moves about z and the rows
/// above L3 do not move relative to each other.
#[test]
fn kinematics_rows_follow_the_body_poses() {
    let doc = BaseModel::locate(None).unwrap().read().unwrap();
    let opts = no_gravity();
    let st = setup(&doc, &opts, None).unwrap();
    let mut ws = Workspace::new(&st.sys);
    let sys = &st.sys;
    let rest = sys
        .solve_static(
            &sys.prepare_loads(&[]).unwrap(),
            sys.default_q().as_slice(),
            &mut ws,
            &StaticOptions::default(),
        )
        .unwrap();
    let p0 = poses(sys, rest.q.as_slice()).unwrap();
    let pairs = body_pairs(&st).unwrap();
    let units = Units {
        angle: "deg",
        length: "mm",
    };
    let zero = kinematics_rows("rest", &pairs, &p0, &p0, &units);
    assert_eq!(zero.lines().count(), pairs.len());
    for line in zero.lines() {
        for c in line.split(',').skip(3) {
            assert!(c.parse::<f64>().unwrap().abs() < 1e-12, "{line}");
        }
    }
    let text = "[[case]]\nid = \"FE\"\nbody = \"lumbar3\"\nmoment = [0.0, 0.0, 5.0]\nmoment_frame = \"ground\"\n";
    let cases = parse_cases(text, Path::new("loads.toml")).unwrap();
    let out = solve_case(&st, &cases[0], &opts, &mut ws, &mut |_| {}).unwrap();
    let p1 = poses(sys, out.q.as_slice()).unwrap();
    let rows = kinematics_rows("FE", &pairs, &p0, &p1, &units);
    let row = |upper: &str| -> Vec<f64> {
        let line = rows
            .lines()
            .find(|l| l.split(',').nth(1).map(|u| u.contains(upper)) == Some(true))
            .unwrap_or_else(|| panic!("no row for {upper} in\n{rows}"));
        line.split(',')
            .skip(3)
            .map(|c| c.parse().unwrap())
            .collect()
    };
    let l3 = row("lumbar3");
    assert!(
        l3[2].abs() > 0.1,
        "L3 flexion-extension {} deg under 5 N*m",
        l3[2]
    );
    assert!(
        l3[2].abs() > 10.0 * l3[0].abs().max(l3[1].abs()),
        "L3 row {l3:?} is not about z"
    );
    let l1 = row("lumbar1");
    assert!(
        l1.iter().all(|v| v.abs() < 1e-9),
        "L1 above the load moved {l1:?}"
    );
}
