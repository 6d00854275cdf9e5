//! Accuracy of generated models on `../shared/scoliosis-dev/`, scored as that folder's README says: for every set,
//! `osim-spine generate --base BASE --landmarks SET --out OUT.osim`; the
//! vertebral centres are the vertebral-body WrapSphere centres at the
//! model's default pose, mapped into the set's frame by the least-squares
//! rigid fit of the model's S1_SEC/SA/SP/SR/SL markers onto the set's;
//! 3-D RMSE against `truth_centres_<set>.csv`; Cobb angle (end vertebrae
//! found automatically), lumbar lordosis and apex from the model's
//! markers and centres in its ground ([`osim_spine::evaluate::metrics`]),
//! against `truth.json` `metrics`.
//!
//! With `--segmentation`, every patient's `segmentation/labelmap.nii.gz`
//! and `segmentation/meshes` instead: `osim-spine generate --base BASE
//! --segmentation SEG --out OUT.osim`, scored against the `clean` set's
//! truth (the segmentations are in its frame) over the levels from the
//! top one measured to L5 (a label map cut by the field of view is scored
//! on what it shows; Cobb and lordosis of the truth recomputed over the
//! same levels from `landmarks_clean.csv`).
//!
//! Usage (see `benches/scoliosis_dev.sh`, which builds both bases):
//! `cargo run --release --example scoliosis_dev -- BASE_DIR [DEV_DIR] [--segmentation]`

use nalgebra::{Isometry3, Point3};
use osim_spine::evaluate::{load_model, parse_centres_csv, CentreDef, ModelShape};
use osim_spine::landmarks::LandmarkSet;
use osim_spine::landmarks::{io, Code, Level};
use osim_spine::mesh::kabsch;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

/// One scored set.
struct Score {
    name: String,
    rmse_mm: f64,
    cobb_err: f64,
    lordosis_err: f64,
    apex_ok: bool,
    apex: String,
}

fn binary() -> PathBuf {
    let exe = std::env::current_exe().expect("current exe");
    exe.parent()
        .and_then(|d| d.parent())
        .expect("target dir")
        .join("osim-spine")
}

/// The model's S1 markers rigidly fitted onto the set's: model ground -> set.
fn s1_fit(m: &ModelShape, set: &osim_spine::landmarks::LandmarkSet) -> Isometry3<f64> {
    let (mut src, mut dst) = (Vec::new(), Vec::new());
    for c in Code::SACRUM_REQUIRED {
        if let (Some(a), Some(b)) = (m.landmarks.get(Level::S1, c), set.get(Level::S1, c)) {
            src.push(a);
            dst.push(b);
        }
    }
    let s = kabsch(&src, &dst).expect("S1 fit");
    Isometry3::from_parts(s.translation.into(), s.rotation)
}

/// Shape metrics by `truth.json`'s `definitions`, from endplate
/// landmarks and vertebral centres in the OpenSim ground (X anterior, Y
/// up, Z right).
mod shape {
    use super::*;

    /// Frontal tilt (deg) of the L->R endplate line: atan2(dy, dz).
    pub fn frontal(set: &LandmarkSet, l: Level, sup: bool) -> Option<f64> {
        let (r, lf) = if sup {
            (Code::SR, Code::SL)
        } else {
            (Code::IR, Code::IL)
        };
        let d = set.get(l, r)? - set.get(l, lf)?;
        Some(d.y.atan2(d.z).to_degrees())
    }

    /// Sagittal tilt (deg) of the P->A superior endplate line: atan2(dy, dx).
    fn sagittal(set: &LandmarkSet, l: Level) -> Option<f64> {
        let d = set.get(l, Code::SA)? - set.get(l, Code::SP)?;
        Some(d.y.atan2(d.x).to_degrees())
    }

    /// Signed Cobb angle (largest magnitude over U cranial-or-equal to L
    /// of tilt(U superior) - tilt(L inferior)), with its end vertebrae.
    pub fn cobb(set: &LandmarkSet) -> Option<(f64, Level, Level)> {
        let levels: Vec<Level> = set
            .levels()
            .into_iter()
            .filter(|l| !l.is_sacrum())
            .collect();
        let mut best: Option<(f64, Level, Level)> = None;
        for (i, u) in levels.iter().enumerate() {
            for w in &levels[i..] {
                if let (Some(a), Some(b)) = (frontal(set, *u, true), frontal(set, *w, false)) {
                    let c = a - b;
                    if best.is_none_or(|x| c.abs() > x.0.abs()) {
                        best = Some((c, *u, *w));
                    }
                }
            }
        }
        best
    }

    /// Lumbar lordosis: sagittal tilt of S1's superior endplate minus L1's.
    pub fn lordosis(set: &LandmarkSet) -> Option<f64> {
        Some(sagittal(set, Level::S1)? - sagittal(set, Level::L1)?)
    }

    /// Apex: the centre with the largest |Z| from the vertical through S1_SEC.
    pub fn apex(centres: &BTreeMap<Level, Point3<f64>>, set: &LandmarkSet) -> Option<Level> {
        let s1 = set.get(Level::S1, Code::SEC)?;
        centres
            .iter()
            .filter(|(l, _)| !l.is_sacrum())
            .max_by(|a, b| (a.1.z - s1.z).abs().total_cmp(&(b.1.z - s1.z).abs()))
            .map(|(l, _)| *l)
    }
}

/// The set's landmarks and centres carried into the truth's ground
/// (`ground_m_to_set_mm` inverted): the scorer checked on the truth itself.
fn truth_in_ground(
    set: &LandmarkSet,
    centres: &BTreeMap<Level, Point3<f64>>,
    info: &serde_json::Value,
) -> (LandmarkSet, BTreeMap<Level, Point3<f64>>) {
    let m = &info["ground_m_to_set_mm"];
    let a = nalgebra::Matrix3::from_fn(|i, j| m[i][j].as_f64().unwrap());
    let t = nalgebra::Vector3::from_fn(|i, _| m[i][3].as_f64().unwrap());
    let inv = a.try_inverse().unwrap();
    // Sets are read into metres in the OpenSim frame; the matrix maps
    // ground metres to the set's LPS millimetres (A_OS2LPS, x1000, R, t).
    let os2lps = nalgebra::Matrix3::new(0.0, 0.0, -1.0, -1.0, 0.0, 0.0, 0.0, 1.0, 0.0);
    let r = inv * os2lps * 1e3;
    let tt = -(inv * t);
    let g = set.transformed(&r, &tt);
    let to_g = |p: &Point3<f64>| Point3::from(r * p.coords + tt);
    (g, centres.iter().map(|(l, p)| (*l, to_g(p))).collect())
}

/// What a model is generated from: a landmark set of the patient's folder
/// (`clean`, `noise2mm_1`, ...) or one of its segmentations (scored
/// against the `clean` set, whose frame the segmentations share).
enum Input {
    Set(String),
    Segmentation { label: String, path: PathBuf },
}

impl Input {
    /// The set whose truth scores the model.
    fn truth_set(&self) -> &str {
        match self {
            Input::Set(s) => s,
            Input::Segmentation { .. } => "clean",
        }
    }
    fn label(&self) -> &str {
        match self {
            Input::Set(s) => s,
            Input::Segmentation { label, .. } => label,
        }
    }
}

/// Run `generate` on `input`; the model written.
fn generate(base: &Path, dir: &Path, input: &Input, out: &Path) -> Result<PathBuf, String> {
    let osim = out.join(format!(
        "{}_{}.osim",
        dir.file_name().unwrap().to_string_lossy(),
        input.label().replace(['/', '.'], "_")
    ));
    let mut cmd = Command::new(binary());
    cmd.args(["generate", "--base"]).arg(base);
    match input {
        Input::Set(set) => cmd
            .arg("--landmarks")
            .arg(dir.join(format!("landmarks_{set}.csv"))),
        Input::Segmentation { path, .. } => cmd.arg("--segmentation").arg(path),
    };
    let o = cmd
        .arg("--out")
        .arg(&osim)
        .args(
            std::env::var("SCOLIOSIS_DEV_ARGS")
                .unwrap_or_default()
                .split_whitespace(),
        )
        .output()
        .map_err(|e| e.to_string())?;
    if !o.status.success() {
        return Err(format!(
            "generate failed on {}: {}",
            input.label(),
            String::from_utf8_lossy(&o.stderr)
        ));
    }
    Ok(osim)
}

/// The levels scored: every level of a landmark set; for a segmentation,
/// from the top vertebra the model measured (or filled) to L5.
fn scored_levels(input: &Input, osim: &Path) -> Result<Vec<Level>, String> {
    if let Input::Set(_) = input {
        return Ok(Level::ALL.to_vec());
    }
    let rp = osim_spine::evaluate::report_path(osim);
    let v: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&rp).map_err(|e| e.to_string())?)
            .map_err(|e| e.to_string())?;
    let top = v["levels_from_landmarks"]
        .as_array()
        .and_then(|a| a.first())
        .and_then(|l| l.as_str())
        .and_then(|l| l.parse::<Level>().ok())
        .ok_or("no vertebra measured")?;
    Ok(Level::ALL[top.index()..].to_vec())
}

fn score_set(
    base: &Path,
    dir: &Path,
    input: &Input,
    truth: &serde_json::Value,
    out: &Path,
) -> Result<Score, String> {
    let set = input.truth_set();
    let osim = generate(base, dir, input, out)?;
    let levels = scored_levels(input, &osim)?;
    let whole = levels.len() == Level::ALL.len();
    let lm = dir.join(format!("landmarks_{set}.csv"));
    let m = load_model(&osim, CentreDef::Sphere).map_err(|e| e.to_string())?;
    let landmarks = io::load(&lm).map_err(|e| e.to_string())?;
    let tc = truth_centres(&dir.join(format!("truth_centres_{set}.csv")))?;
    // Diagnostic (SCOLIOSIS_DEV_S1=palpated): the S1 fit onto the
    // palpated landmarks written beside the model instead of the set's.
    let x = match (input, std::env::var("SCOLIOSIS_DEV_S1").as_deref()) {
        (Input::Segmentation { .. }, Ok("palpated")) => {
            let stem = osim.file_stem().unwrap().to_string_lossy().to_string();
            let p = osim.with_file_name(format!("{stem}_landmarks.csv"));
            s1_fit(&m, &io::load(&p).map_err(|e| e.to_string())?)
        }
        _ => s1_fit(&m, &landmarks),
    };
    let d2: Vec<f64> = tc
        .iter()
        .filter(|(l, _)| levels.contains(l))
        .filter_map(|(l, t)| m.centres.get(l).map(|c| (x * c - t).norm_squared()))
        .collect();
    let rmse_mm = (d2.iter().sum::<f64>() / d2.len() as f64).sqrt() * 1e3;
    let tm = &truth["metrics"];
    let debug = std::env::var("SCOLIOSIS_DEV_DEBUG").is_ok_and(|d| input.label().contains(&d));
    let (g, gc) = truth_in_ground(&landmarks, &tc, &truth["sets"][set]);
    let (g, gc) = (
        only(&g, &levels),
        gc.into_iter().filter(|(l, _)| levels.contains(l)).collect(),
    );
    let truth_cobb = shape::cobb(&g).map(|c| c.0).unwrap_or(f64::NAN);
    let truth_lordosis = shape::lordosis(&g).unwrap_or(f64::NAN);
    let truth_apex = shape::apex(&gc, &g)
        .map(|l| l.to_string())
        .unwrap_or_default();
    if (set == "clean" && matches!(input, Input::Set(_))) || debug {
        // The scorer on the truth itself must give truth.json's metrics.
        println!(
            "scorer check {}: Cobb {:+.3} (truth.json {:+.3}), lordosis {:+.3} ({:+.3}), apex {truth_apex} ({})",
            dir.display(),
            truth_cobb,
            tm["cobb_deg"].as_f64().unwrap_or(f64::NAN),
            truth_lordosis,
            tm["lumbar_lordosis_deg"].as_f64().unwrap_or(f64::NAN),
            tm["apex"].as_str().unwrap_or("")
        );
        if debug {
            let s1 = |set: &LandmarkSet| set.get(Level::S1, Code::SEC).unwrap();
            for l in m.landmarks.levels() {
                let f = |set: &LandmarkSet, sup| shape::frontal(set, l, sup).unwrap_or(f64::NAN);
                println!(
                    "  {l:>3}: sup tilt {:+6.2} model {:+6.2}  inf tilt {:+6.2} model {:+6.2}  centre-z (mm) truth {:+7.2} model {:+7.2}",
                    f(&g, true), f(&m.landmarks, true), f(&g, false), f(&m.landmarks, false),
                    gc.get(&l).map(|c| (c.z - s1(&g).z) * 1e3).unwrap_or(f64::NAN),
                    m.centres.get(&l).map(|c| (c.z - s1(&m.landmarks).z) * 1e3).unwrap_or(f64::NAN),
                );
            }
        }
    }
    // Over the whole spine the truth is truth.json's; over part of it,
    // the truth landmarks' own metrics over the same levels.
    let (t_cobb, t_lordosis, t_apex) = if whole {
        (
            tm["cobb_deg"].as_f64().unwrap_or(f64::NAN),
            tm["lumbar_lordosis_deg"].as_f64().unwrap_or(f64::NAN),
            tm["apex"].as_str().unwrap_or("").to_string(),
        )
    } else {
        (truth_cobb, truth_lordosis, truth_apex)
    };
    let model_set = only(&m.landmarks, &levels);
    let model_centres: BTreeMap<Level, Point3<f64>> = m
        .centres
        .iter()
        .filter(|(l, _)| levels.contains(l))
        .map(|(l, c)| (*l, *c))
        .collect();
    let cobb = shape::cobb(&model_set).map(|c| c.0).unwrap_or(f64::NAN);
    let lordosis = shape::lordosis(&model_set).unwrap_or(f64::NAN);
    let apex_m = shape::apex(&model_centres, &model_set)
        .map(|l| l.to_string())
        .unwrap_or_default();
    let span = if whole {
        String::new()
    } else {
        format!(" ({}-L5)", levels[0])
    };
    Ok(Score {
        name: format!(
            "{}/{}{span}",
            dir.file_name().unwrap().to_string_lossy(),
            input.label()
        ),
        rmse_mm,
        cobb_err: cobb - t_cobb,
        lordosis_err: lordosis - t_lordosis,
        apex_ok: t_apex == apex_m,
        apex: apex_m,
    })
}

/// The landmarks of `set` at `levels` only.
fn only(set: &LandmarkSet, levels: &[Level]) -> LandmarkSet {
    let mut out = LandmarkSet::new();
    for (id, p) in &set.points {
        if levels.contains(&id.level) {
            out.insert(id.level, id.code, *p);
        }
    }
    out
}

/// The truth centres CSV; its `# frame:` line carries a parenthetical
/// remark after the frame label, dropped here.
fn truth_centres(path: &Path) -> Result<BTreeMap<Level, Point3<f64>>, String> {
    let text = std::fs::read_to_string(path).map_err(|e| e.to_string())?;
    let clean: String = text
        .lines()
        .map(|l| match l.strip_prefix("# frame:") {
            Some(rest) => format!(
                "# frame: {}\n",
                rest.split_whitespace().next().unwrap_or("")
            ),
            None if l.starts_with("vertebra,") => l.replacen("vertebra", "level", 1) + "\n",
            None => format!("{l}\n"),
        })
        .collect();
    parse_centres_csv(&clean, path).map_err(|e| e.to_string())
}

fn median(v: &[f64]) -> f64 {
    osim_spine::util::median(v).unwrap_or(f64::NAN)
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let base = PathBuf::from(
        args.get(1)
            .expect("usage: scoliosis_dev BASE_DIR [DEV_DIR]"),
    );
    let segmentation = args.iter().any(|a| a == "--segmentation");
    let rest: Vec<&String> = args
        .iter()
        .skip(2)
        .filter(|a| !a.starts_with("--"))
        .collect();
    let dev = PathBuf::from(
        rest.first()
            .map(|s| s.to_string())
            .unwrap_or_else(|| "../shared/scoliosis-dev".into()),
    );
    let out = tempfile::tempdir().expect("temp dir");
    let mut patients: Vec<PathBuf> = std::fs::read_dir(&dev)
        .expect("dev dir")
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.join("truth.json").is_file())
        .collect();
    patients.sort();
    let mut scores = Vec::new();
    for p in &patients {
        let truth: serde_json::Value =
            serde_json::from_slice(&std::fs::read(p.join("truth.json")).unwrap()).unwrap();
        let inputs: Vec<Input> = if segmentation {
            ["labelmap.nii.gz", "meshes"]
                .iter()
                .map(|s| Input::Segmentation {
                    label: s.to_string(),
                    path: p.join("segmentation").join(s),
                })
                .filter(|i| matches!(i, Input::Segmentation { path, .. } if path.exists()))
                .collect()
        } else {
            set_names(p).into_iter().map(Input::Set).collect()
        };
        for s in inputs {
            match score_set(&base, p, &s, &truth, out.path()) {
                Ok(sc) => scores.push(sc),
                Err(e) => println!("FAILED {}/{}: {e}", p.display(), s.label()),
            }
        }
    }
    print_table(&scores);
}

/// The landmark sets of a patient's folder (`landmarks_<set>.csv`).
fn set_names(p: &Path) -> Vec<String> {
    let mut sets: Vec<String> = std::fs::read_dir(p)
        .unwrap()
        .filter_map(|e| {
            e.ok()?
                .file_name()
                .to_str()?
                .strip_prefix("landmarks_")?
                .strip_suffix(".csv")
                .map(String::from)
        })
        .collect();
    sets.sort();
    sets
}

fn print_table(scores: &[Score]) {
    println!("| set | centre RMSE (mm) | Cobb error (deg) | lordosis error (deg) | apex |");
    println!("|---|---|---|---|---|");
    for s in scores {
        let ok = if s.apex_ok { "right" } else { "WRONG" };
        println!(
            "| {} | {:.2} | {:+.2} | {:+.2} | {} ({ok}) |",
            s.name, s.rmse_mm, s.cobb_err, s.lordosis_err, s.apex
        );
    }
    let col = |f: fn(&Score) -> f64| scores.iter().map(f).collect::<Vec<f64>>();
    println!(
        "\nsets: {}; median centre RMSE {:.2} mm (max {:.2}); median |Cobb error| {:.2} deg; median |lordosis error| {:.2} deg; apex right in {}/{}",
        scores.len(),
        median(&col(|s| s.rmse_mm)),
        col(|s| s.rmse_mm).into_iter().fold(0.0, f64::max),
        median(&col(|s| s.cobb_err.abs())),
        median(&col(|s| s.lordosis_err.abs())),
        scores.iter().filter(|s| s.apex_ok).count(),
        scores.len()
    );
}
