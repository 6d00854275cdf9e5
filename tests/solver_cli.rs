//! `osim-spine simulate`: results against the OpenSim oracle, output format,
//! and bad input (unknown body, gimbal-locked bushing, loads too large):
//! clear error, non-zero exit, no output.

mod common;

use std::path::Path;
use std::process::Command;

fn simulate(model: &Path, load: &str, out: &Path, extra: &[&str]) -> std::process::Output {
    let dir = out.parent().unwrap();
    let lf = dir.join("load.toml");
    std::fs::write(&lf, load).unwrap();
    Command::new(common::bin())
        .arg("simulate")
        .arg(model)
        .arg("--load")
        .arg(&lf)
        .arg("--out")
        .arg(out)
        .args(extra)
        .output()
        .unwrap()
}

const FE5: &str = "[[case]]\nid = \"FE_pos_5\"\nbody = \"L3\"\nmoment = [0.0, 0.0, 5.0]\nmoment_frame = \"ground\"\n";

#[test]
fn static_case_matches_oracle_and_writes_sto_and_json() {
    let (Some(model), Some(case)) = (
        common::shared("oracle/chain.osim"),
        common::shared("oracle/cases/moment_flexext_Z_pos5Nm_groundframe.json"),
    ) else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    let o = simulate(&model, FE5, &out, &[]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("FE_pos_5.json")).unwrap()).unwrap();
    let oracle: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(case).unwrap()).unwrap();
    let want = oracle["static_equilibrium"]["coordinates"]
        .as_object()
        .unwrap();
    for (k, v) in want {
        let got = json["coordinates"][k].as_f64().unwrap();
        assert!((got - v.as_f64().unwrap()).abs() < 1e-8, "{k}");
    }
    assert_eq!(json["fixed_body"], "sacrum");
    let sto = std::fs::read_to_string(out.join("FE_pos_5.sto")).unwrap();
    let lines: Vec<&str> = sto.lines().collect();
    assert_eq!(lines[1], "version=1");
    assert!(lines.contains(&"inDegrees=no") && lines.contains(&"endheader"));
    let header_end = lines.iter().position(|l| *l == "endheader").unwrap();
    let cols: Vec<&str> = lines[header_end + 1].split('\t').collect();
    assert_eq!(cols[0], "time");
    assert_eq!(cols.len(), 19);
    let row: Vec<f64> = lines[header_end + 2]
        .split('\t')
        .map(|x| x.parse().unwrap())
        .collect();
    let i = cols.iter().position(|c| *c == "L4_L3_rz").unwrap();
    assert!((row[i] - want["L4_L3_rz"].as_f64().unwrap()).abs() < 1e-8);
    // deterministic: a second run gives byte-identical files
    let out2 = tmp.path().join("out2");
    assert!(simulate(&model, FE5, &out2, &[]).status.success());
    for f in ["FE_pos_5.json", "FE_pos_5.sto"] {
        let a = std::fs::read_to_string(out.join(f))
            .unwrap()
            .replace(out.to_str().unwrap(), "");
        let b = std::fs::read_to_string(out2.join(f))
            .unwrap()
            .replace(out2.to_str().unwrap(), "");
        assert_eq!(a, b, "{f} differs between runs");
    }
}

#[test]
fn dynamic_run_writes_a_trajectory() {
    let Some(model) = common::shared("oracle/chain.osim") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    let o = simulate(
        &model,
        FE5,
        &out,
        &["--dynamic", "0.05", "--dt", "0.001", "--no-gravity"],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let sto = std::fs::read_to_string(out.join("FE_pos_5.sto")).unwrap();
    assert!(sto.contains("nRows=6\n"), "{sto}");
}

fn assert_fails(o: &std::process::Output, out: &Path, needle: &str) {
    assert!(!o.status.success(), "should fail");
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains(needle),
        "stderr does not mention '{needle}': {err}"
    );
    assert!(
        !out.exists() || std::fs::read_dir(out).unwrap().next().is_none(),
        "output written despite the error"
    );
}

#[test]
fn unknown_body_is_an_error_without_output() {
    let Some(model) = common::shared("oracle/chain.osim") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    let load = format!("{FE5}[[case]]\nid = \"bad\"\nbody = \"L9\"\nmoment = [1.0, 0.0, 0.0]\nmoment_frame = \"body\"\n");
    let o = simulate(&model, &load, &out, &[]);
    assert_fails(&o, &out, "no body named 'L9'");
}

#[test]
fn too_large_load_is_an_error_without_output() {
    let Some(model) = common::shared("oracle/chain.osim") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    let load = "[[case]]\nid = \"huge\"\nbody = \"L3\"\nmoment = [0.0, 0.0, 5000.0]\nmoment_frame = \"ground\"\n";
    let o = simulate(&model, load, &out, &[]);
    assert_fails(&o, &out, "case 'huge'");
}

#[test]
fn gimbal_locked_bushing_is_an_error_without_output() {
    let Some(model) = common::shared("oracle/chain_bushing_ownframes.osim") else {
        return;
    };
    let text = std::fs::read_to_string(&model).unwrap();
    // make the first joint's frames and the bushing's frames unrotated, then
    // turn the bushing's frame 2 by exactly 90 degrees about Y: its middle
    // deflection angle is 90 degrees in the default pose
    let sac = "<orientation>0.10000000000000001 0.049999999999999996 -0.12</orientation>";
    let l5 = "<orientation>0 0.089999999999999983 0.049999999999999996</orientation>";
    let zero = "<orientation>0 0 0</orientation>";
    let text = text.replace(sac, zero);
    let start = text
        .find("<BushingForce name=\"sacrum_L5_bushing\">")
        .unwrap();
    let at = start + text[start..].find(l5).unwrap();
    let mut edited = text.clone();
    edited.replace_range(
        at..at + l5.len(),
        "<orientation>0 1.5707963267948966 0</orientation>",
    );
    let edited = edited.replace(l5, zero);
    let tmp = tempfile::tempdir().unwrap();
    let m = tmp.path().join("gimbal.osim");
    std::fs::write(&m, edited).unwrap();
    let out = tmp.path().join("out");
    let o = simulate(&m, FE5, &out, &[]);
    assert_fails(&o, &out, "gimbal lock");
}
