//! The patient's own vertebrae in the model, measured on
//! `../shared/scoliosis-dev/*/segmentation/` (mesh folders and label maps):
//! for each, `osim-spine generate --segmentation SEG --base BASE
//! --geometry G --out OUT.osim` with G = base and patient, then
//! - vertebral centres (vertebral-body WrapSphere centres at the default
//!   pose) mapped into the truth's frame by the least-squares rigid fit of
//!   the model's S1_SEC/SA/SP/SR/SL markers onto `landmarks_clean.csv`'s,
//!   RMSE against `truth_centres_clean.csv` (all levels the model placed
//!   from the segmentation, and T9-L5);
//! - G = patient: each patient mesh placed in ground at the default pose
//!   and mapped the same way, its symmetric surface distance (median, 95th
//!   percentile, per level) to the segmentation's surface: the mesh of the
//!   folder, or for a label map the faces of the level's voxels (and, for
//!   reference, the mesh the map was voxelised from);
//! - the run time of each `generate`.
//!
//! Usage: `cargo run --release --example patient_geometry -- BASE_DIR [DEV_DIR]`
//! (`benches/patient_geometry.sh` builds the cyclist base first).

use nalgebra::{Isometry3, Point3};
use osim_spine::base::kin::Kinematics;
use osim_spine::evaluate::{load_model, parse_centres_csv, CentreDef};
use osim_spine::landmarks::{io, Code, Frame, LandmarkSet, Level};
use osim_spine::mesh::{self, kabsch, TriMesh};
use osim_spine::osim::model::Geometry;
use osim_spine::osim::Document;
use osim_spine::segmentation::nifti::{self, LabelMap};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

fn binary() -> PathBuf {
    let exe = std::env::current_exe().expect("current exe");
    exe.parent()
        .and_then(|d| d.parent())
        .expect("target dir")
        .join("osim-spine")
}

/// The model's S1 markers rigidly fitted onto the set's: model ground -> set.
fn s1_fit(model: &LandmarkSet, set: &LandmarkSet) -> Isometry3<f64> {
    let (mut src, mut dst) = (Vec::new(), Vec::new());
    for c in Code::SACRUM_REQUIRED {
        if let (Some(a), Some(b)) = (model.get(Level::S1, c), set.get(Level::S1, c)) {
            src.push(a);
            dst.push(b);
        }
    }
    let s = kabsch(&src, &dst).expect("S1 fit");
    Isometry3::from_parts(s.translation.into(), s.rotation)
}

/// The truth centres CSV (its `# frame:` remark and `vertebra` header
/// made readable by the centres parser).
fn truth_centres(path: &Path) -> BTreeMap<Level, Point3<f64>> {
    let text = std::fs::read_to_string(path).expect("truth centres");
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
    parse_centres_csv(&clean, path).expect("truth centres")
}

/// RMSE (mm) of the model's centres mapped by `x` against `truth`, over
/// `levels` (those the model has).
fn rmse(
    centres: &BTreeMap<Level, Point3<f64>>,
    truth: &BTreeMap<Level, Point3<f64>>,
    x: &Isometry3<f64>,
    levels: &[Level],
) -> (f64, usize) {
    let d2: Vec<f64> = levels
        .iter()
        .filter_map(|l| Some((x * centres.get(l)? - truth.get(l)?).norm_squared()))
        .collect();
    (
        (d2.iter().sum::<f64>() / d2.len().max(1) as f64).sqrt() * 1e3,
        d2.len(),
    )
}

/// Each patient mesh of the model in ground at the default pose, by level.
fn patient_meshes(osim: &Path) -> BTreeMap<Level, TriMesh> {
    let doc = Document::read(osim).expect("model");
    let model = doc.model().expect("model");
    let kin = Kinematics::new(&model).expect("kinematics");
    let poses = kin.body_poses(&kin.default_values()).expect("poses");
    let stem = osim.file_stem().unwrap().to_string_lossy().to_string();
    let mut out = BTreeMap::new();
    for b in &model.bodies {
        let Some(l) = Level::from_body_name(&b.name) else {
            continue;
        };
        for g in &b.geometry {
            let Geometry::Mesh { mesh_file, .. } = g else {
                continue;
            };
            if !mesh_file.starts_with(&format!("{stem}_")) {
                continue;
            }
            let m = mesh::read(&osim.with_file_name("Geometry").join(mesh_file)).expect("mesh");
            out.insert(l, m.transformed(&poses[&b.name]));
        }
    }
    out
}

/// A folder's level meshes (LPS mm) in OpenSim axes, metres.
fn folder_meshes(dir: &Path) -> BTreeMap<Level, TriMesh> {
    let r = Frame::Lps.to_opensim() * 1e-3;
    Level::ALL
        .into_iter()
        .filter_map(|l| {
            let m = mesh::read(&dir.join(format!("{l}.stl"))).ok()?;
            Some((
                l,
                m.affine(&nalgebra::Affine3::from_matrix_unchecked(
                    r.to_homogeneous(),
                )),
            ))
        })
        .collect()
}

/// The faces of the voxels labelled `label` (world RAS mm -> OpenSim
/// axes, metres): the label map's own staircase surface.
fn voxel_faces(map: &LabelMap, label: u16) -> TriMesh {
    let [nx, ny, nz] = map.dims;
    let at = |i: i64, j: i64, k: i64| -> bool {
        i >= 0
            && j >= 0
            && k >= 0
            && (i as usize) < nx
            && (j as usize) < ny
            && (k as usize) < nz
            && map.labels[i as usize + nx * (j as usize + ny * k as usize)] == label
    };
    let to_os = Frame::Ras.to_opensim() * 1e-3;
    let mut v = Vec::new();
    let mut t = Vec::new();
    for k in 0..nz as i64 {
        for j in 0..ny as i64 {
            for i in 0..nx as i64 {
                if !at(i, j, k) {
                    continue;
                }
                for axis in 0..3 {
                    for s in [-1i64, 1] {
                        let mut n = [i, j, k];
                        n[axis] += s;
                        if at(n[0], n[1], n[2]) {
                            continue;
                        }
                        let (u, w) = ((axis + 1) % 3, (axis + 2) % 3);
                        let base = v.len() as u32;
                        for (du, dw) in [(-0.5, -0.5), (0.5, -0.5), (0.5, 0.5), (-0.5, 0.5)] {
                            let mut c = [i as f64, j as f64, k as f64];
                            c[axis] += 0.5 * s as f64;
                            c[u] += du;
                            c[w] += dw;
                            let p = map.world(&Point3::new(c[0], c[1], c[2]));
                            v.push(Point3::from(to_os * p.coords));
                        }
                        t.push([base, base + 1, base + 2]);
                        t.push([base, base + 2, base + 3]);
                    }
                }
            }
        }
    }
    TriMesh {
        vertices: v,
        triangles: t,
    }
}

/// Which label the palpation read each level from (`label 27` in the
/// palpation report's levels).
fn level_labels(report: &Path) -> BTreeMap<Level, u16> {
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(report).expect("report")).expect("json");
    let mut out = BTreeMap::new();
    for l in v["levels"].as_array().into_iter().flatten() {
        let (Some(level), Some(origin)) = (l["level"].as_str(), l["origin"].as_str()) else {
            continue;
        };
        let (Ok(level), Some(Ok(label))) = (
            level.parse::<Level>(),
            origin
                .strip_prefix("label ")
                .map(|s| s.split([',', ' ', '+']).next().unwrap_or("").parse::<u16>()),
        ) else {
            continue;
        };
        out.insert(level, label);
    }
    out
}

/// Median and 95th percentile (mm) of surface distances.
fn stats(d: &[f64]) -> (f64, f64) {
    (
        osim_spine::util::median(d).unwrap_or(f64::NAN) * 1e3,
        osim_spine::util::quantile(d, 0.95).unwrap_or(f64::NAN) * 1e3,
    )
}

/// One run of generate; its model, wall time (s) and whether it ran.
fn run(seg: &Path, base: &Path, geometry: &str, out: &Path) -> Option<f64> {
    let t = Instant::now();
    let o = Command::new(binary())
        .args(["generate", "--segmentation"])
        .arg(seg)
        .arg("--base")
        .arg(base)
        .args(["--geometry", geometry, "--out"])
        .arg(out)
        .output()
        .expect("run osim-spine");
    let dt = t.elapsed().as_secs_f64();
    if !o.status.success() {
        println!(
            "  generate --geometry {geometry} on {} failed: {}",
            seg.display(),
            String::from_utf8_lossy(&o.stderr).trim()
        );
        return None;
    }
    Some(dt)
}

/// Surface distances of every patient level against the segmentation's
/// surfaces; prints a line per level and returns the worst median and
/// 95th percentile (mm) against the first reference.
fn surfaces(
    meshes: &BTreeMap<Level, TriMesh>,
    x: &Isometry3<f64>,
    refs: &[(&str, BTreeMap<Level, TriMesh>)],
) -> (f64, f64) {
    let mut worst = (0.0f64, 0.0f64);
    for (l, m) in meshes {
        let mapped = m.transformed(x);
        let mut line = format!("    {l:>3} {:>5} triangles", m.triangles.len());
        for (k, (name, r)) in refs.iter().enumerate() {
            let Some(rm) = r.get(l) else { continue };
            let d = mesh::distance::symmetric_surface_distances(&mapped, rm, 4000).expect("dist");
            let (med, p95) = stats(&d);
            line += &format!("  vs {name}: median {med:.3} p95 {p95:.3} mm");
            if k == 0 {
                worst = (worst.0.max(med), worst.1.max(p95));
            }
        }
        println!("{line}");
    }
    worst
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let base = PathBuf::from(
        args.get(1)
            .expect("usage: patient_geometry BASE_DIR [DEV_DIR]"),
    );
    let dev = PathBuf::from(
        args.get(2)
            .cloned()
            .unwrap_or_else(|| "../shared/scoliosis-dev".into()),
    );
    let out = tempfile::tempdir().expect("temp dir");
    let mut patients: Vec<PathBuf> = std::fs::read_dir(&dev)
        .expect("dev folder")
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.join("segmentation").is_dir())
        .collect();
    patients.sort();
    let t9_l5: Vec<Level> = Level::ALL[8..17].to_vec();
    for p in &patients {
        let name = p.file_name().unwrap().to_string_lossy().to_string();
        let truth_set = io::load(&p.join("landmarks_clean.csv")).expect("truth landmarks");
        let truth = truth_centres(&p.join("truth_centres_clean.csv"));
        let folder = folder_meshes(&p.join("segmentation/meshes"));
        for (kind, seg) in [
            ("meshes", p.join("segmentation/meshes")),
            ("labelmap", p.join("segmentation/labelmap.nii.gz")),
        ] {
            println!("## {name} {kind}");
            for geometry in ["base", "patient"] {
                let osim = out.path().join(format!("{name}_{kind}_{geometry}.osim"));
                let Some(dt) = run(&seg, &base, geometry, &osim) else {
                    continue;
                };
                let m = load_model(&osim, CentreDef::Sphere).expect("model");
                let x = s1_fit(&m.landmarks, &truth_set);
                // The landmarks the model was generated from (palpated on
                // the segmentation, in the truth's frame).
                let palpated = io::load(&osim.with_file_name(format!(
                    "{}_landmarks.csv",
                    osim.file_stem().unwrap().to_string_lossy()
                )))
                .expect("palpated landmarks");
                let xp = s1_fit(&m.landmarks, &palpated);
                let placed: Vec<Level> = palpated.levels();
                let (all, n) = rmse(&m.centres, &truth, &x, &placed);
                let (sub, ns) = rmse(&m.centres, &truth, &x, &t9_l5);
                let (allp, _) = rmse(&m.centres, &truth, &xp, &placed);
                let (subp, _) = rmse(&m.centres, &truth, &xp, &t9_l5);
                println!(
                    "  {geometry:>7}: centre RMSE {all:.2} mm over {n} levels, {sub:.2} mm over T9-L5 ({ns}) [on the palpated S1: {allp:.2} / {subp:.2} mm]; generate {dt:.2} s"
                );
                if geometry != "patient" {
                    continue;
                }
                let meshes = patient_meshes(&osim);
                let mut refs = Vec::new();
                if kind == "labelmap" {
                    let map = nifti::read(&seg).expect("label map");
                    let report = osim.with_file_name(format!(
                        "{}_landmarks_report.json",
                        osim.file_stem().unwrap().to_string_lossy()
                    ));
                    let faces: BTreeMap<Level, TriMesh> = level_labels(&report)
                        .into_iter()
                        .map(|(l, lab)| (l, voxel_faces(&map, lab)))
                        .collect();
                    let sp = map.spacing();
                    println!(
                        "    voxel {:.2} x {:.2} x {:.2} mm (half the largest {:.2} mm)",
                        sp.x,
                        sp.y,
                        sp.z,
                        0.5 * sp.max()
                    );
                    refs.push(("voxel faces", faces));
                }
                refs.push(("folder mesh", folder.clone()));
                for (label, x) in [("truth S1", &x), ("palpated S1", &xp)] {
                    println!("    mapped by the {label} landmarks:");
                    let (med, p95) = surfaces(&meshes, x, &refs);
                    println!(
                        "    worst level vs {}: median {med:.3} mm, p95 {p95:.3} mm",
                        refs[0].0
                    );
                }
            }
        }
    }
}
