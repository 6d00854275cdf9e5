//! `palpate` on the scoliosis-dev segmentations (mesh folders and label
//! maps) against each patient's `landmarks_clean.csv`, scored as
//! `tests/segmentation_dev.rs` does (SR/SL/IR/IL without their component
//! along the endplate's SA->SP / IA->IP direction). Prints, per input, the
//! median and 95th percentile, then per code the median and 95th
//! percentile and the median signed error along the truth vertebra's axes
//! (X = SP->SA, Y = IEC->SEC, Z = right; mm), which shows a bias.
//!
//! Usage: `cargo run --release --example landmark_accuracy_dev -- [PATIENT [meshes|map]] [CODE]`
//! (`RIM_MIDDLE=1` palpates as `--laterals rim-middle`).

use nalgebra::Vector3;
use osim_spine::landmarks::{io, Code, LandmarkSet};
use osim_spine::segmentation::{self, Laterals, Options};
use osim_spine::util::{median, quantile};
use std::collections::BTreeMap;
use std::path::Path;

const PATIENTS: [&str; 3] = ["D01_thoracic45", "D02_lumbar55", "D03_double"];

/// Error (mm) and its components along the truth vertebra's axes.
struct Err {
    name: String,
    code: String,
    dist: f64,
    local: Vector3<f64>,
}

fn errors(got: &LandmarkSet, truth: &LandmarkSet) -> Vec<Err> {
    let mut out = Vec::new();
    for (id, p) in &got.points {
        let Some(t) = truth.points.get(id) else {
            continue;
        };
        let g = |c: Code| truth.get(id.level, c);
        let mut e = p - t;
        let pair = match id.code {
            Code::SR | Code::SL => Some((Code::SA, Code::SP)),
            Code::IR | Code::IL => Some((Code::IA, Code::IP)),
            _ => None,
        };
        if let Some((a, b)) = pair {
            let u: Vector3<f64> = (g(b).unwrap() - g(a).unwrap()).normalize();
            e -= u * e.dot(&u);
        }
        let local = match (g(Code::SA), g(Code::SP), g(Code::SEC), g(Code::IEC)) {
            (Some(sa), Some(sp), Some(sec), Some(iec)) => {
                let y = (sec - iec).normalize();
                let x0 = sa - sp;
                let x = (x0 - y * x0.dot(&y)).normalize();
                let z = x.cross(&y);
                Vector3::new(e.dot(&x), e.dot(&y), e.dot(&z)) * 1e3
            }
            _ => Vector3::zeros(),
        };
        out.push(Err {
            name: format!("{}_{}", id.level, id.code.as_str()),
            code: id.code.as_str().to_string(),
            dist: e.norm() * 1e3,
            local,
        });
    }
    out
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let dev = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/scoliosis-dev");
    let only_patient = args.first().cloned();
    let only_kind = args.get(1).cloned();
    let only_code = args.get(2).cloned();
    // As `osim-spine palpate` runs with no option; RIM_MIDDLE=1 for the
    // lateral rims' middles (`--laterals rim-middle`).
    let opts = Options {
        laterals: if std::env::var_os("RIM_MIDDLE").is_some() {
            Laterals::RimMiddle
        } else {
            Laterals::Furthest
        },
        ..Options::default()
    };
    let mut pooled: BTreeMap<&str, Vec<Err>> = BTreeMap::new();
    for patient in PATIENTS {
        if only_patient
            .as_deref()
            .is_some_and(|p| p != patient && p != "all")
        {
            continue;
        }
        let truth = io::load(&dev.join(patient).join("landmarks_clean.csv")).expect("truth");
        let seg = dev.join(patient).join("segmentation");
        for (kind, input) in [("meshes", "meshes"), ("map", "labelmap.nii.gz")] {
            if only_kind
                .as_deref()
                .is_some_and(|k| k != kind && k != "all")
            {
                continue;
            }
            let p = match segmentation::palpate(&seg.join(input), &opts) {
                Ok(p) => p,
                Err(e) => {
                    println!("{patient} {kind}: {e}");
                    continue;
                }
            };
            let e = errors(&p.set, &truth);
            let d: Vec<f64> = e.iter().map(|x| x.dist).collect();
            // Does the spread flag the landmarks over 3 mm?
            let spread = |name: &str| {
                p.levels
                    .iter()
                    .flat_map(|r| {
                        r.palpation
                            .landmarks
                            .iter()
                            .map(move |(c, l)| (format!("{}_{}", r.level, c.as_str()), l.spread))
                    })
                    .find(|(n, _)| n == name)
                    .map_or(0.0, |(_, s)| s * 1e3)
            };
            let far: Vec<&Err> = e.iter().filter(|x| x.dist > 3.0).collect();
            if std::env::var_os("MISSED").is_some() {
                for x in far.iter().filter(|x| spread(&x.name) <= 1.5) {
                    println!(
                        "   missed {:>8} {:5.2} mm (x {:6.2} y {:6.2} z {:6.2}) spread {:.2}",
                        x.name,
                        x.dist,
                        x.local.x,
                        x.local.y,
                        x.local.z,
                        spread(&x.name)
                    );
                }
            }
            let flagged: Vec<&Err> = e.iter().filter(|x| spread(&x.name) > 1.5).collect();
            println!(
                "   spread > 1.5 mm: {} of the {} over 3 mm; {} of the {} flagged are over 3 mm, {} over 2 mm",
                far.iter().filter(|x| spread(&x.name) > 1.5).count(),
                far.len(),
                flagged.iter().filter(|x| x.dist > 3.0).count(),
                flagged.len(),
                flagged.iter().filter(|x| x.dist > 2.0).count(),
            );
            println!(
                "{patient} {kind}: median {:.2} mm, 95th {:.2} mm",
                median(&d).unwrap(),
                quantile(&d, 0.95).unwrap()
            );
            if let Some(c) = &only_code {
                for x in e.iter().filter(|x| &x.code == c) {
                    println!(
                        "   {:>8} {:5.2} mm  (x {:6.2} y {:6.2} z {:6.2})",
                        x.name, x.dist, x.local.x, x.local.y, x.local.z
                    );
                }
            }
            pooled.entry(kind).or_default().extend(e);
        }
    }
    for (kind, e) in &pooled {
        let d: Vec<f64> = e.iter().map(|x| x.dist).collect();
        println!(
            "\n{kind} pooled: median {:.2}, 95th {:.2}; per code: median / 95th / worst (median signed x y z)",
            median(&d).unwrap(),
            quantile(&d, 0.95).unwrap()
        );
        let mut by: BTreeMap<&str, Vec<&Err>> = BTreeMap::new();
        for x in e {
            by.entry(&x.code).or_default().push(x);
        }
        let over = quantile(&d, 0.95).unwrap();
        for (c, v) in by {
            let dd: Vec<f64> = v.iter().map(|x| x.dist).collect();
            let comp =
                |k: usize| median(&v.iter().map(|x| x.local[k]).collect::<Vec<_>>()).unwrap();
            let n_over = dd.iter().filter(|&&x| x > over).count();
            println!(
                "  {c:>4}: {:5.2} / {:5.2} / {:5.2}  ({:6.2} {:6.2} {:6.2})  {n_over} over the pooled 95th",
                median(&dd).unwrap(),
                quantile(&dd, 0.95).unwrap(),
                dd.iter().copied().fold(0.0, f64::max),
                comp(0),
                comp(1),
                comp(2)
            );
        }
    }
}
