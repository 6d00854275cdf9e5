//! The palpation engine on the cyclist model's vertebra meshes
//! (`../shared/data/geometry-bodyframe/`) against the landmarks and
//! vertebral centres the scoliosis-dev maker palpated on the same meshes,
//! as `scripts/scoliosis_truth_generic.py` recovers them (body frames).
//! Prints, per level, the distance of every landmark and of the centre
//! (mm), then the median and worst per code.
//!
//! Usage: `cargo run --release --example palpation_vs_truth -- TRUTH.csv`

use nalgebra::Point3;
use osim_spine::landmarks::{Code, Level};
use osim_spine::mesh;
use osim_spine::palpation::{palpate_sacrum, palpate_vertebra, FrameHint};
use std::collections::BTreeMap;
use std::path::Path;

fn mesh_name(l: Level) -> String {
    let s = l.to_string();
    match s.strip_prefix('T') {
        Some(n) => format!("thoracic{n}_s.vtp"),
        None if l.is_sacrum() => "sacrum.vtp".into(),
        None => format!("lumbar{}.vtp", &s[1..]),
    }
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let text = std::fs::read_to_string(&args[1]).expect("truth csv");
    let mut truth: BTreeMap<(Level, String), Point3<f64>> = BTreeMap::new();
    for line in text.lines().filter(|l| !l.starts_with('#')).skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        let level: Level = f[0].parse().expect("level");
        let p = Point3::new(
            f[2].parse().unwrap(),
            f[3].parse().unwrap(),
            f[4].parse().unwrap(),
        );
        truth.insert((level, f[1].to_string()), p);
    }
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/geometry-bodyframe");
    let mut per_code: BTreeMap<String, Vec<f64>> = BTreeMap::new();
    let only: Option<Level> = args.get(2).and_then(|s| s.parse().ok());
    for level in Level::ALL {
        if only.is_some_and(|o| o != level) {
            continue;
        }
        let m = mesh::read(&dir.join(mesh_name(level))).expect("mesh");
        let p = if level.is_sacrum() {
            palpate_sacrum(&m, &FrameHint::body_frame(), None)
        } else {
            palpate_vertebra(&m, level, &FrameHint::body_frame())
        };
        let p = match p {
            Ok(p) => p,
            Err(e) => {
                println!("{level}: {e}");
                continue;
            }
        };
        let mut line = format!("{level:>3}:");
        let mut row = |code: String, got: Point3<f64>| {
            if let Some(t) = truth.get(&(level, code.clone())) {
                let d = got - t;
                line.push_str(&format!(" {code} {:.1}", d.norm() * 1e3));
                if only.is_some() {
                    println!(
                        "  {code:>6} got ({:7.2} {:7.2} {:7.2}) truth ({:7.2} {:7.2} {:7.2}) mm",
                        got.x * 1e3,
                        got.y * 1e3,
                        got.z * 1e3,
                        t.x * 1e3,
                        t.y * 1e3,
                        t.z * 1e3
                    );
                }
                per_code.entry(code).or_default().push(d.norm() * 1e3);
            }
        };
        for c in Code::ALL {
            if let Some(l) = p.landmarks.get(&c) {
                row(c.to_string(), l.point);
            }
        }
        row("CENTRE".into(), p.centre);
        println!("{line}");
        for f in &p.findings {
            println!("     {f}");
        }
    }
    println!("\ncode: median / worst distance to the maker's (mm)");
    for (c, mut v) in per_code {
        v.sort_by(f64::total_cmp);
        println!(
            "{c:>6}: {:.2} / {:.2}",
            v[v.len() / 2],
            v.last().copied().unwrap_or(0.0)
        );
    }
}
