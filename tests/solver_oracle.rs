//! Acceptance 1: every oracle case of `../shared/oracle/cases/` (OpenSim 4.6
//! static equilibria of the 3-joint chain) is reproduced by the built-in
//! solver within 1e-8 in every coordinate and 1e-6 in every bushing record.

mod common;

use nalgebra::Vector3;
use osim_spine::solver::{Load, LoadFrame, StaticOptions, System, SystemSpec, Workspace};
use serde_json::Value;

fn vec3(v: &Value) -> Vector3<f64> {
    let a: Vec<f64> = v
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect();
    Vector3::new(a[0], a[1], a[2])
}

fn case_loads(load: &Value) -> Vec<Load> {
    let frame = if load["expressed_in"] == "ground" {
        LoadFrame::Ground
    } else {
        LoadFrame::Body
    };
    let body = load["body"].as_str().unwrap_or("").to_string();
    match load["type"].as_str().unwrap() {
        "none" => vec![],
        "pure_moment" => vec![Load::Moment {
            body,
            vec: vec3(&load["torque"]),
            frame,
        }],
        "point_force" => vec![Load::Force {
            body,
            point_in_body: vec3(&load["point_in_body"]),
            vec: vec3(&load["force"]),
            frame,
        }],
        t => panic!("unknown load type {t}"),
    }
}

#[test]
fn oracle_cases_match_opensim() {
    let (Some(model), Some(cases)) = (
        common::shared("oracle/chain.osim"),
        common::shared("oracle/cases"),
    ) else {
        return;
    };
    let index: Vec<String> =
        serde_json::from_str(&std::fs::read_to_string(cases.join("index.json")).unwrap()).unwrap();
    assert!(index.len() >= 49, "expected the full oracle case list");
    let spec = SystemSpec::read_osim(&model).unwrap();
    let sys = System::new(&spec).unwrap();
    let mut ws = Workspace::new(&sys);
    let opts = StaticOptions::default();
    let (mut worst_q, mut worst_rec) = (0.0f64, 0.0f64);
    for name in &index {
        let case: Value = serde_json::from_str(
            &std::fs::read_to_string(cases.join(format!("{name}.json"))).unwrap(),
        )
        .unwrap();
        assert_eq!(vec3(&case["gravity"]), sys.gravity(), "{name}: gravity");
        let loads = sys.prepare_loads(&case_loads(&case["load"])).unwrap();
        let sol = sys
            .solve_static(&loads, sys.default_q().as_slice(), &mut ws, &opts)
            .unwrap();
        let se = &case["static_equilibrium"];
        let full = sys.full_coordinates(sol.q.as_slice());
        for (c, v) in sys.coordinates().iter().zip(&full) {
            let want = se["coordinates"][&c.name]
                .as_f64()
                .unwrap_or_else(|| panic!("{name}: {} missing", c.name));
            let d = (v - want).abs();
            worst_q = worst_q.max(d);
            assert!(
                d < 1e-8,
                "{name}: coordinate {} = {v}, OpenSim {want} (diff {d:e})",
                c.name
            );
        }
        let recs = sys
            .bushing_records(sol.q.as_slice(), None, &mut ws)
            .unwrap();
        for (bn, rec) in &recs {
            let want = &se["bushings"][bn];
            for (k, v) in rec.record_values.iter().enumerate() {
                let w = want["record_values"][k].as_f64().unwrap();
                let d = (v - w).abs();
                worst_rec = worst_rec.max(d);
                assert!(d < 1e-6, "{name}: {bn} record[{k}] = {v}, OpenSim {w}");
            }
            for (k, v) in rec.deflection_rx_ry_rz_tx_ty_tz.iter().enumerate() {
                let w = want["deflection_rx_ry_rz_tx_ty_tz"][k].as_f64().unwrap();
                assert!((v - w).abs() < 1e-8, "{name}: {bn} deflection[{k}]");
            }
        }
        let poses = sys.body_poses(sol.q.as_slice(), &mut ws).unwrap();
        for (bn, p) in &poses {
            let want = vec3(&se["bodies"][bn]["origin_in_ground"]);
            assert!(
                (Vector3::from(p.origin_in_ground) - want).amax() < 1e-9,
                "{name}: {bn} origin"
            );
        }
    }
    eprintln!(
        "{} oracle cases: max |dq| = {worst_q:.2e}, max |d record| = {worst_rec:.2e}",
        index.len()
    );
}

#[test]
fn bushing_owning_its_frames_gives_the_same_equilibrium() {
    let (Some(a), Some(b)) = (
        common::shared("oracle/chain.osim"),
        common::shared("oracle/chain_bushing_ownframes.osim"),
    ) else {
        return;
    };
    let sa = System::new(&SystemSpec::read_osim(&a).unwrap()).unwrap();
    let sb = System::new(&SystemSpec::read_osim(&b).unwrap()).unwrap();
    let mut wa = Workspace::new(&sa);
    let mut wb = Workspace::new(&sb);
    let l = vec![Load::Moment {
        body: "L3".into(),
        vec: Vector3::new(2.0, -3.0, 5.0),
        frame: LoadFrame::Body,
    }];
    let qa = sa
        .solve_static(
            &sa.prepare_loads(&l).unwrap(),
            sa.default_q().as_slice(),
            &mut wa,
            &StaticOptions::default(),
        )
        .unwrap();
    let qb = sb
        .solve_static(
            &sb.prepare_loads(&l).unwrap(),
            sb.default_q().as_slice(),
            &mut wb,
            &StaticOptions::default(),
        )
        .unwrap();
    assert!((&qa.q - &qb.q).amax() < 1e-10);
}
