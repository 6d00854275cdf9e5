//! `generate --segmentation SEG --geometry patient`: the model wears the
//! segmentation's own vertebrae.
//!
//! Round trip (no shared data): the embedded base posed into a scoliotic
//! shape by the tool's own kinematics, its vertebrae written as a mesh
//! folder (LPS millimetres, as a CT export), palpated and generated with
//! the patient geometry: the model's meshes must be the posed base's
//! (1e-6 m), its joint centres and wrap-sphere centres the posed base's
//! (0.1 mm), every mesh closed and within the
//! triangle budget, no attachment inside a patient bone and no muscle path
//! through one. A label map voxelised from the same posed lumbar vertebrae
//! gives smoothed, decimated surfaces within half a voxel of the voxels'
//! faces.

mod common;

use nalgebra::{Isometry3, Point3};
use osim_spine::base::kin::{Kinematics, Values};
use osim_spine::embedded::BaseModel;
use osim_spine::generate::geometry::MAX_TRIANGLES;
use osim_spine::generate::{generate_with_geometry, GenerateOptions, Generated, PatientGeometry};
use osim_spine::landmarks::{Frame, Level};
use osim_spine::mesh::source::MeshSource;
use osim_spine::mesh::TriMesh;
use osim_spine::osim::model::Geometry;
use osim_spine::osim::Document;
use osim_spine::segmentation::{palpate, Options};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// A scoliotic pose of the base: a right thoracic and a left lumbar curve
/// (lateral bending up to 5 deg per joint), axial rotation towards the
/// convexity (up to 3 deg) and a little extra flexion.
fn scoliotic(defaults: &Values) -> Values {
    let mut q = defaults.clone();
    for (k, upper) in Level::ALL[..17].iter().enumerate() {
        let lower = upper.caudal().unwrap();
        let j = format!("{upper}_{lower}");
        let s = (k as f64 / 16.0 * std::f64::consts::TAU).sin();
        for (c, deg) in [("LB", 5.0 * s), ("AR", 3.0 * s), ("FE", 1.0)] {
            if let Some(v) = q.get_mut(&format!("{j}_{c}")) {
                *v += deg.to_radians();
            }
        }
    }
    q
}

/// Each level's base mesh (scaled as the model says) in ground at `poses`.
fn posed_meshes(
    doc: &Document,
    src: &dyn MeshSource,
    poses: &BTreeMap<String, Isometry3<f64>>,
) -> BTreeMap<Level, TriMesh> {
    let model = doc.model().unwrap();
    let mut out = BTreeMap::new();
    for b in &model.bodies {
        let Some(l) = Level::from_body_name(&b.name) else {
            continue;
        };
        let parts: Vec<TriMesh> = b
            .geometry
            .iter()
            .filter_map(|g| match g {
                Geometry::Mesh {
                    mesh_file,
                    scale_factors,
                    ..
                } => Some(src.load(mesh_file).unwrap().unwrap().scaled(scale_factors)),
                _ => None,
            })
            .collect();
        let refs: Vec<&TriMesh> = parts.iter().collect();
        out.insert(
            l,
            TriMesh::merge(&refs).unwrap().transformed(&poses[&b.name]),
        );
    }
    out
}

/// Ground (OpenSim axes, m) -> LPS millimetres, as a CT export writes.
fn to_lps_mm(m: &TriMesh) -> TriMesh {
    let r = Frame::Lps.to_opensim().transpose() * 1e3;
    TriMesh {
        vertices: m
            .vertices
            .iter()
            .map(|p| Point3::from(r * p.coords))
            .collect(),
        triangles: m.triangles.clone(),
    }
}

/// Joint centres (parent frame origin in ground) of every IVD joint.
fn joint_centres(doc: &Document, q: Option<&Values>) -> BTreeMap<String, Point3<f64>> {
    let model = doc.model().unwrap();
    let kin = Kinematics::new(&model).unwrap();
    let q = q.cloned().unwrap_or_else(|| kin.default_values());
    let poses = kin.body_poses(&q).unwrap();
    model
        .joint_frames()
        .unwrap()
        .into_iter()
        .filter(|jf| Level::from_body_name(&jf.child_body).is_some())
        .map(|jf| {
            let x = poses[&jf.parent_body] * jf.parent_in_body;
            (jf.joint, Point3::from(x.translation.vector))
        })
        .collect()
}

/// The model's own meshes (by level) in ground at its default pose.
fn model_meshes(g: &Generated) -> BTreeMap<Level, TriMesh> {
    let model = g.doc.model().unwrap();
    let kin = Kinematics::new(&model).unwrap();
    let poses = kin.body_poses(&kin.default_values()).unwrap();
    let mut out = BTreeMap::new();
    for b in &model.bodies {
        for geo in &b.geometry {
            let Geometry::Mesh { mesh_file, .. } = geo else {
                continue;
            };
            if let (Some(m), Some(l)) = (g.meshes.get(mesh_file), Level::from_body_name(&b.name)) {
                out.insert(l, m.transformed(&poses[&b.name]));
            }
        }
    }
    out
}

/// The model's S1 markers rigidly fitted onto the set's S1 landmarks
/// (model ground -> the set's frame), as the scoring maps a model.
fn s1_alignment(
    model: &osim_spine::landmarks::LandmarkSet,
    set: &osim_spine::landmarks::LandmarkSet,
) -> Isometry3<f64> {
    let (mut a, mut b) = (Vec::new(), Vec::new());
    for c in osim_spine::landmarks::Code::SACRUM_REQUIRED {
        a.push(model.get(Level::S1, c).unwrap());
        b.push(set.get(Level::S1, c).unwrap());
    }
    let s = osim_spine::mesh::kabsch(&a, &b).unwrap();
    Isometry3::from_parts(s.translation.into(), s.rotation)
}

/// Largest distance from a vertex of either mesh to the nearest vertex of
/// the other (the meshes renumber their vertices).
fn vertex_distance(a: &TriMesh, b: &TriMesh) -> f64 {
    let one_way = |a: &TriMesh, b: &TriMesh| {
        a.vertices
            .iter()
            .map(|p| {
                b.vertices
                    .iter()
                    .map(|q| (p - q).norm())
                    .fold(f64::MAX, f64::min)
            })
            .fold(0.0f64, f64::max)
    };
    one_way(a, b).max(one_way(b, a))
}

/// Palpate `seg` and generate on the embedded base with its meshes.
fn generate_patient(seg: &Path) -> (Generated, osim_spine::segmentation::Palpated) {
    let base = BaseModel::Embedded;
    let doc = base.read().unwrap();
    let p = palpate(seg, &Options::default()).unwrap();
    let pg = PatientGeometry::from_palpated(&p, "patient");
    let opts = GenerateOptions {
        views: false,
        ..GenerateOptions::default()
    };
    let g =
        generate_with_geometry(&doc, &p.set, "palpated", &opts, Some(&base), Some(&pg)).unwrap();
    (g, p)
}

#[test]
fn posed_base_round_trip_gives_back_its_meshes_and_joints() {
    let base = BaseModel::Embedded;
    let doc = base.read().unwrap();
    let model = doc.model().unwrap();
    let kin = Kinematics::new(&model).unwrap();
    let q = scoliotic(&kin.default_values());
    let poses = kin.body_poses(&q).unwrap();
    let posed = posed_meshes(&doc, &base, &poses);
    assert_eq!(posed.len(), 18);
    let dir = tempfile::tempdir().unwrap();
    for (l, m) in &posed {
        osim_spine::mesh::write(&dir.path().join(format!("{l}.vtp")), &to_lps_mm(m)).unwrap();
    }
    let (g, p) = generate_patient(dir.path());
    let geo = g.report.geometry.as_ref().expect("geometry report");
    assert_eq!(geo.patient_levels.len(), 18, "{:?}", geo.base_levels);
    // The model into the folder's frame (= the posed base's ground) by the
    // sacral-marker alignment of the scoring (model S1 markers onto the
    // palpated S1 landmarks).
    let out = g.doc.model().unwrap();
    let kin2 = Kinematics::new(&out).unwrap();
    let poses2 = kin2.body_poses(&kin2.default_values()).unwrap();
    let marks = osim_spine::base::centres::model_landmarks(&out, &poses2).unwrap();
    let x = s1_alignment(&marks, &p.set);
    // Meshes: the posed base's, vertex for vertex; and in the model's own
    // ground, as far as the sacral registration is from the identity.
    let mine = model_meshes(&g);
    let (mut worst, mut in_ground) = (0.0f64, 0.0f64);
    for (l, m) in &mine {
        assert!(m.triangles.len() <= MAX_TRIANGLES);
        assert!(m.edge_report().is_watertight() && m.signed_volume() > 0.0);
        assert_eq!(m.triangles.len(), posed[l].triangles.len(), "{l}");
        worst = worst.max(vertex_distance(&m.transformed(&x), &posed[l]));
        in_ground = in_ground.max(vertex_distance(m, &posed[l]));
    }
    // Joint centres: the posed base's.
    let want = joint_centres(&doc, Some(&q));
    let got = joint_centres(&g.doc, None);
    let mut jworst = (0.0f64, String::new());
    for (j, c) in &got {
        let d = (x * c - want[j]).norm();
        if d > jworst.0 {
            jworst = (d, j.clone());
        }
    }
    println!(
        "round trip: meshes within {worst:.2e} m after the sacral alignment ({in_ground:.2e} m in the model's ground: registration RMS {:.3} mm), joint centres within {:.4} mm ({}), {} joints at the patient's discs, {} attachments moved",
        g.report.registration.rms_mm,
        jworst.0 * 1e3,
        jworst.1,
        geo.joints_at_patient_discs.len(),
        geo.moved_attachments.len()
    );
    assert!(worst < 1e-6, "meshes differ by {worst} m");
    assert!(in_ground < 1e-4, "meshes in ground differ by {in_ground} m");
    assert_eq!(geo.joints_at_patient_discs.len(), 17);
    assert!(jworst.0 < 1e-4, "joint {} off by {} m", jworst.1, jworst.0);
    // Wrap spheres at the posed base's centres (the base's centres carried
    // by the affine surface fit, which is the identity here), markers at
    // the landmarks.
    let centres = osim_spine::base::centres::model_centres(
        &out,
        &poses2,
        osim_spine::base::centres::CentreDef::Sphere,
    )
    .unwrap();
    let base_centres = osim_spine::base::centres::model_centres(
        &model,
        &poses,
        osim_spine::base::centres::CentreDef::Sphere,
    )
    .unwrap();
    let mut cworst = 0.0f64;
    for (l, c) in base_centres.iter().filter(|(l, _)| !l.is_sacrum()) {
        let rule = geo.meshes.iter().find(|r| r.level == *l);
        assert_eq!(
            rule.and_then(|r| r.sphere_centre_rule),
            Some(osim_spine::generate::geometry::CentreRule::CarriedFromBase),
            "{l}"
        );
        cworst = cworst.max((x * centres[l] - c).norm());
    }
    println!(
        "sphere centres within {:.4} mm of the posed base's",
        cworst * 1e3
    );
    assert!(cworst < 1e-4, "sphere centre off by {cworst} m");
    let reg = g.report.registration.isometry();
    for (id, pt) in &p.set.points {
        let m = marks.get(id.level, id.code).unwrap();
        assert!((m - reg * pt).norm() < 1e-9, "{id:?} marker");
    }
    // No muscle path through a patient vertebra, no attachment inside one.
    let sc = g.report.self_check.as_ref().unwrap();
    assert!(
        sc.muscle_segments_through_vertebrae.is_empty(),
        "{:?}",
        sc.muscle_segments_through_vertebrae
    );
}

/// Copy a folder tree (files and folders only).
fn copy_tree(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        let dst = to.join(e.file_name());
        if e.file_type().unwrap().is_dir() {
            copy_tree(&e.path(), &dst);
        } else {
            std::fs::copy(e.path(), dst).unwrap();
        }
    }
}

/// The cyclist base model built as `../shared/scoliosis-dev/README.md`
/// says, once per test binary.
fn cyclist_base() -> Option<PathBuf> {
    static DIR: std::sync::OnceLock<Option<PathBuf>> = std::sync::OnceLock::new();
    DIR.get_or_init(|| {
        let model = common::shared("data/models/cyclistFullBodyMuscle.osim")?;
        let geom = common::shared("data/geometry-bodyframe")?;
        let dir = tempfile::tempdir().unwrap().keep().join("cyclist");
        common::run_ok(&[
            "base".as_ref(),
            "--generic".as_ref(),
            model.as_os_str(),
            "--geometry".as_ref(),
            geom.as_os_str(),
            "--out".as_ref(),
            dir.as_os_str(),
        ]);
        Some(dir)
    })
    .clone()
}

/// A patient model from a scoliotic patient's mesh folder
/// (`../shared/scoliosis-dev/D03_double`, on the embedded base) with the
/// default geometry of `--segmentation` (the patient's), copied to another
/// folder and the original removed: OpenSim 4.6 loads the copy with no
/// line but "Loaded model", every mesh it wears has at most 5,000
/// triangles and OpenSim's own wrapped muscle paths at the default pose
/// pass through no vertebra (its meshes the patient's).
#[test]
fn patient_model_is_self_contained_and_loads_cleanly_in_opensim() {
    let Some(seg) = common::shared("scoliosis-dev/D03_double/segmentation/meshes") else {
        return;
    };
    loads_cleanly_in_opensim(&seg, None, 18);
}

/// The same from a label map (D03's, T9-S1 in the field of view) on the
/// cyclist base: 9 patient meshes (T9-L5 and the sacrum), decimated.
#[test]
fn patient_model_from_a_label_map_on_the_cyclist_base_loads_cleanly_in_opensim() {
    let Some(seg) = common::shared("scoliosis-dev/D03_double/segmentation/labelmap.nii.gz") else {
        return;
    };
    let Some(base) = cyclist_base() else {
        return;
    };
    loads_cleanly_in_opensim(&seg, Some(&base), 9);
}

/// `generate --segmentation SEG [--base BASE]` (no `--geometry`), the output
/// folder moved, then loaded in OpenSim 4.6: see the tests above.
fn loads_cleanly_in_opensim(seg: &Path, base: Option<&Path>, expect_patient_meshes: usize) {
    let Some(py) = common::opensim_python() else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let made = tmp.path().join("made");
    let model = made.join("patient.osim");
    let mut args: Vec<&std::ffi::OsStr> = vec![
        "generate".as_ref(),
        "--segmentation".as_ref(),
        seg.as_os_str(),
        "--out".as_ref(),
        model.as_os_str(),
    ];
    if let Some(b) = base {
        args.extend(["--base".as_ref(), b.as_os_str()]);
    }
    common::run_ok(&args);
    let moved = tmp.path().join("elsewhere");
    copy_tree(&made, &moved);
    std::fs::remove_dir_all(&made).unwrap();
    let model = moved.join("patient.osim");
    // Every mesh written: within the triangle budget; the patient's as many
    // as the segmentation has levels.
    let mut patient_meshes = 0;
    for e in std::fs::read_dir(moved.join("Geometry")).unwrap() {
        let p = e.unwrap().path();
        let m = osim_spine::mesh::read(&p).unwrap();
        assert!(
            m.triangles.len() <= MAX_TRIANGLES,
            "{}: {} triangles",
            p.display(),
            m.triangles.len()
        );
        if p.file_name()
            .unwrap()
            .to_string_lossy()
            .starts_with("patient_")
        {
            patient_meshes += 1;
        }
    }
    assert_eq!(patient_meshes, expect_patient_meshes, "{}", seg.display());
    // OpenSim's log of loading the copy.
    let result = tmp.path().join("log.json");
    let o = std::process::Command::new(&py)
        .arg(common::repo_root().join("tests/py/load_log.py"))
        .arg(&result)
        .arg(&model)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let logs: serde_json::Value = serde_json::from_slice(&std::fs::read(&result).unwrap()).unwrap();
    let lines = logs[model.to_str().unwrap()].as_array().unwrap();
    assert!(!lines.is_empty(), "no log captured");
    for l in lines.iter().map(|l| l.as_str().unwrap()) {
        assert!(l.starts_with("[info] Loaded model"), "OpenSim: {l}");
    }
    // OpenSim's wrapped paths against the patient's vertebrae.
    let (crossings, worst) = common::opensim_path_crossings(&py, &model);
    println!(
        "{}: {patient_meshes} patient meshes, OpenSim log clean, {} crossings, path lengths within {:.2e} m of OpenSim's",
        seg.display(),
        crossings.len(),
        worst
    );
    assert!(crossings.is_empty(), "{crossings:?}");
}
