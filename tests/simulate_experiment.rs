//! `simulate` with a load file in the experiment format uses its
//! `[specimen]` table (gravity off, sacrum fixed), prints per case whether
//! it converged, the largest displacement and stability, and writes
//! `kinematics.csv` in the format of `../shared/formats/experiment.md`,
//! checked against the OpenSim-made measurements of a labelled experiment.

mod common;

use std::collections::BTreeMap;
use std::process::Command;

/// (case, upper, lower) -> [rx, ry, rz] from a kinematics.csv text.
fn rotations(text: &str) -> BTreeMap<(String, String, String), [f64; 3]> {
    let mut out = BTreeMap::new();
    for l in text.lines().skip(1) {
        let c: Vec<&str> = l.split(',').collect();
        let r = [c[3], c[4], c[5]].map(|x| x.parse::<f64>().unwrap());
        out.insert((c[0].to_string(), c[1].to_string(), c[2].to_string()), r);
    }
    out
}

#[test]
fn experiment_load_file_uses_its_specimen_table_and_writes_kinematics() {
    let Some(dir) = common::shared("diagnose-dev/dev-07") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("sim");
    let o = Command::new(common::bin())
        .arg("simulate")
        .arg(dir.join("specimen.osim"))
        .arg("--load")
        .arg(dir.join("experiment.toml"))
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    // The [specimen] table: gravity off, sacrum fixed.
    assert!(
        stdout.contains("gravity off, fixed body sacrum"),
        "{stdout}"
    );
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("FE_neg_5.json")).unwrap()).unwrap();
    assert_eq!(json["gravity"], serde_json::json!([0.0, 0.0, 0.0]));
    // One line per case: converged, largest displacement, stability.
    let measured = std::fs::read_to_string(dir.join("kinematics.csv")).unwrap();
    let meas = rotations(&measured);
    let n_cases = meas
        .keys()
        .map(|k| k.0.clone())
        .collect::<std::collections::BTreeSet<_>>();
    for c in &n_cases {
        let line = stdout
            .lines()
            .find(|l| l.starts_with(&format!("case {c}:")))
            .unwrap_or_else(|| panic!("no line for {c}:\n{stdout}"));
        assert!(
            line.contains("converged") && line.contains("largest displacement"),
            "{line}"
        );
        assert!(line.contains("stab"), "{line}");
    }
    // kinematics.csv: the measured rows' keys, same signs and sizes as
    // OpenSim's measurements of the truth specimen, which is linear and
    // uniform like the nominal one, with rotational stiffness x0.63-0.94 of
    // it (truth.toml): simulated / measured rotation lies in that range.
    let sim = rotations(&std::fs::read_to_string(out.join("kinematics.csv")).unwrap());
    for (k, m) in &meas {
        let s = sim
            .get(k)
            .unwrap_or_else(|| panic!("no simulated row {k:?}"));
        let (i, big) =
            (0..3)
                .map(|i| (i, m[i].abs()))
                .fold((0, 0.0), |a, b| if b.1 > a.1 { b } else { a });
        if big > 1.0 {
            assert_eq!(s[i].signum(), m[i].signum(), "{k:?}: {s:?} vs {m:?}");
            let ratio = s[i] / m[i];
            assert!((0.55..1.05).contains(&ratio), "{k:?}: {s:?} vs {m:?}");
        }
    }
    // A pure flexion moment with gravity off bends the spine in flexion,
    // not sideways (gravity on, it buckled sideways).
    let (mut side, mut flex) = (0.0f64, 0.0f64);
    for ((c, _, _), r) in &sim {
        if c == "FE_neg_5" {
            side = side.max(r[0].abs());
            flex = flex.max(r[2].abs());
        }
    }
    assert!(
        side < 0.2 * flex,
        "side bend {side} deg vs flexion {flex} deg"
    );
}
