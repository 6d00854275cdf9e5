//! Acceptance tests of `osim-spine base` on the cyclist model (OpenSim 4.6
//! through `tests/py/`), the sphere fits on the dense vertebral bodies, the
//! palpation on dense whole vertebrae, and bad inputs.

mod common;

use nalgebra::{Isometry3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};
use osim_spine::base::kin::Kinematics;
use osim_spine::mesh::{anterior_body_nodes, fit_sphere, AnatomicalFrame, MeshQuery, TriMesh};
use osim_spine::osim::Document;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

fn run_base(args: &[&str]) -> std::process::Output {
    Command::new(common::bin())
        .arg("base")
        .args(args)
        .output()
        .expect("run osim-spine")
}

fn cyclist_inputs() -> Option<(PathBuf, PathBuf, PathBuf, PathBuf)> {
    Some((
        common::shared("data/models/cyclistFullBodyMuscle.osim")?,
        common::shared("data/geometry-bodyframe")?,
        common::shared("data/geometry/sacrumv.vtp")?,
        common::shared("data/geometry")?,
    ))
}

/// Acceptance 1, 3 and 4 on one build.
#[test]
fn cyclist_base_model_in_opensim() {
    let Some((model, geom, sacrum, _)) = cyclist_inputs() else {
        return;
    };
    let out = tempfile::tempdir().unwrap();
    let od = out.path().join("OUT");
    let t0 = std::time::Instant::now();
    let o = run_base(&[
        "--generic",
        model.to_str().unwrap(),
        "--geometry",
        geom.to_str().unwrap(),
        "--sacrum",
        sacrum.to_str().unwrap(),
        "--out",
        od.to_str().unwrap(),
    ]);
    let secs = t0.elapsed().as_secs_f64();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    println!("osim-spine base: {secs:.2} s (test build profile)");
    let base = od.join("base.osim");
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(od.join("base_report.json")).unwrap()).unwrap();

    // Acceptance 4: markers re-read from the written model, checked
    // against the written meshes (not the builder's own numbers).
    let doc = Document::read(&base).unwrap();
    let m = doc.model().unwrap();
    let mut per_body: BTreeMap<String, Vec<(String, Point3<f64>)>> = BTreeMap::new();
    for mk in m.markers.iter().filter(|mk| !mk.name.starts_with("FH_")) {
        let (body, x) = m.marker_frame(mk).unwrap();
        per_body
            .entry(body)
            .or_default()
            .push((mk.name.clone(), x * Point3::from(mk.location)));
    }
    // 14 per vertebra, 5 on S1, the femoral heads FH_R / FH_L
    assert_eq!(m.markers.len(), 17 * 14 + 5 + 2);
    // The protocol's invariants hold on every vertebra (the base's guards).
    assert_eq!(
        report["guard_failures"],
        serde_json::json!([]),
        "guards failed"
    );
    let mut worst: f64 = 0.0;
    for b in &m.bodies {
        let Some(list) = per_body.get(&b.name) else {
            continue;
        };
        let file = b
            .geometry
            .iter()
            .find_map(|g| match g {
                osim_spine::osim::model::Geometry::Mesh { mesh_file, .. } => {
                    Some(mesh_file.clone())
                }
                _ => None,
            })
            .unwrap();
        let mesh = osim_spine::mesh::read(&od.join(&file)).unwrap();
        let q = MeshQuery::new(&mesh).unwrap();
        for (name, p) in list {
            let d = q.distance(p);
            worst = worst.max(d);
            assert!(d <= 0.0005, "{name} is {:.3} mm off {file}", d * 1e3);
        }
        if b.name != "sacrum" {
            assert_eq!(list.len(), 14, "{}", b.name);
        }
    }
    println!(
        "markers: 243, largest distance to the mesh surface {:.2e} mm",
        worst * 1e3
    );
    for v in ["view_frontal.svg", "view_sagittal.svg"] {
        let svg = std::fs::read_to_string(od.join(v)).unwrap();
        assert!(
            svg.matches("<circle").count() > 243,
            "{v} lacks the markers"
        );
    }

    let Some(py) = common::opensim_python() else {
        return;
    };
    // Acceptance 1 and 3 in OpenSim.
    let r = common::run_py(&py, "base_check.py", &[base.to_str().unwrap(), "10", "5"]);
    assert_eq!(r["ivd_6dof_joints"], 17);
    assert_eq!(r["bushings"], 17);
    let bmax = r["bushing_max_record_at_default"].as_f64().unwrap();
    assert!(bmax < 1e-9, "bushing force at default pose {bmax}");
    // OpenSim's marker positions vs the tool's kinematics of the same file.
    let kin = Kinematics::new(&m).unwrap();
    let poses = kin.body_poses(&kin.default_values()).unwrap();
    let mut kdiff: f64 = 0.0;
    for mk in &m.markers {
        let (body, x) = m.marker_frame(mk).unwrap();
        let p = poses[&body] * x * Point3::from(mk.location);
        let o = &r["markers"][&mk.name];
        for k in 0..3 {
            kdiff = kdiff.max((p[k] - o[k].as_f64().unwrap()).abs());
        }
    }
    assert!(
        kdiff < 1e-9,
        "tool and OpenSim marker positions differ by {kdiff}"
    );
    // The femoral head markers sit on the generic model's hip joint centres
    // (OpenSim on both models; the pelvis is welded at its generic pose).
    let hips = common::run_py(
        &py,
        "hip_centres.py",
        &[model.to_str().unwrap(), "hip_r", "hip_l"],
    );
    for (mk, joint) in [("FH_R", "hip_r"), ("FH_L", "hip_l")] {
        for k in 0..3 {
            let d = r["markers"][mk][k].as_f64().unwrap() - hips[joint][k].as_f64().unwrap();
            assert!(d.abs() < 1e-9, "{mk} is {d} m off the centre of {joint}");
        }
    }
    let rows = r["scoliotic"].as_array().unwrap();
    assert!(!rows.is_empty());
    let crossing = common::assert_wrap_rows(rows);
    println!(
        "scoliotic pose (LB 10 deg, AR 5 deg per level): {} muscles with PathWraps, {crossing} cross their sphere and wrap",
        rows.len()
    );
    // Equilibrium under gravity: tool vs OpenSim. The report rounds its
    // figures (1e-6 rad/m), so the tool's equilibrium is recomputed here at
    // full precision from the written model.
    let eq = osim_spine::base::check::equilibrium(&m).unwrap();
    let full = od.join("equilibrium_full_precision.json");
    std::fs::write(
        &full,
        serde_json::to_string(&serde_json::json!({"self_check": {"equilibrium": eq}})).unwrap(),
    )
    .unwrap();
    let e = common::run_py(
        &py,
        "base_equilibrium.py",
        &[base.to_str().unwrap(), full.to_str().unwrap()],
    );
    let diff = e["max_coordinate_difference"].as_f64().unwrap();
    let res = e["residual_at_tool_solution"].as_f64().unwrap();
    println!(
        "equilibrium under gravity: OpenSim residual at the tool's solution {res:.2e}, coordinates differ by {diff:.2e}; largest vertebral displacement {:.1} mm",
        report["self_check"]["equilibrium"]["max_displacement"].as_f64().unwrap() * 1e3
    );
    assert!(diff < 1e-8, "equilibria differ by {diff}");
}

fn assert_refused(args: &[&str], out: &Path, needle: &str) {
    let o = run_base(args);
    let err = String::from_utf8_lossy(&o.stderr).to_string();
    assert!(!o.status.success(), "accepted: {args:?}");
    assert!(
        err.contains(needle),
        "error does not say '{needle}':\n{err}"
    );
    assert!(!out.exists(), "output written despite the error");
}

/// Acceptance 5: bad inputs give clear errors and no output.
#[test]
fn bad_inputs_are_refused_without_output() {
    let Some((model, geom, sacrum, raw)) = cyclist_inputs() else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("OUT");
    let (m, g, s, o) = (
        model.to_str().unwrap(),
        geom.to_str().unwrap(),
        sacrum.to_str().unwrap(),
        out.to_str().unwrap(),
    );
    // Raw meshes: misplaced, each named.
    let raw_s = raw.to_str().unwrap();
    let o1 = run_base(&["--generic", m, "--geometry", raw_s, "--out", o]);
    let err = String::from_utf8_lossy(&o1.stderr);
    assert!(!o1.status.success());
    assert!(err.contains("misplaced"), "{err}");
    for f in ["thoracic1_s.vtp", "thoracic12_s.vtp"] {
        assert!(err.contains(f), "{f} not named:\n{err}");
    }
    assert!(!out.exists());
    // A generic model without the expected bodies.
    if let Some(chain) = common::shared("oracle/chain.osim") {
        assert_refused(
            &["--generic", chain.to_str().unwrap(), "--out", o],
            &out,
            "lacks the bodies",
        );
    }
    // Missing meshes.
    let empty = tmp.path().join("empty");
    std::fs::create_dir(&empty).unwrap();
    assert_refused(
        &[
            "--generic",
            m,
            "--geometry",
            empty.to_str().unwrap(),
            "--out",
            o,
        ],
        &out,
        "mesh files not found",
    );
    // A sacrum that cannot be registered: a vertebra written in
    // millimetres (1000 times too large).
    let cube = tmp.path().join("sacrum_mm.vtp");
    let l3mm = osim_spine::mesh::read(&geom.join("lumbar3.vtp"))
        .unwrap()
        .scaled(&Vector3::repeat(1000.0));
    osim_spine::mesh::write(&cube, &l3mm).unwrap();
    assert_refused(
        &[
            "--generic",
            m,
            "--geometry",
            g,
            "--sacrum",
            cube.to_str().unwrap(),
            "--out",
            o,
        ],
        &out,
        "cannot be registered",
    );
    // A non-manifold vertebra mesh: a fin on an edge of lumbar3.
    let nm = tmp.path().join("nm");
    std::fs::create_dir(&nm).unwrap();
    for e in std::fs::read_dir(&geom).unwrap() {
        let p = e.unwrap().path();
        if p.extension().map(|x| x == "vtp").unwrap_or(false) {
            std::fs::copy(&p, nm.join(p.file_name().unwrap())).unwrap();
        }
    }
    let mut l3 = osim_spine::mesh::read(&geom.join("lumbar3.vtp")).unwrap();
    let [a, b, _] = l3.triangles[0];
    l3.vertices.push(Point3::new(0.0, 0.0, 0.1));
    let n = (l3.vertices.len() - 1) as u32;
    l3.triangles.push([a, b, n]);
    osim_spine::mesh::write(&nm.join("lumbar3.vtp"), &l3).unwrap();
    assert_refused(
        &[
            "--generic",
            m,
            "--geometry",
            nm.to_str().unwrap(),
            "--sacrum",
            s,
            "--out",
            o,
        ],
        &out,
        "non-manifold",
    );
}

/// Mesh of an OBJ (Z up) re-expressed in the OpenSim convention (X
/// anterior, Y cranial, Z right) about the body mesh's centroid; anterior
/// = from the whole vertebra's centroid towards the body's (horizontal).
fn to_opensim_frame(body: &TriMesh, whole: &TriMesh) -> Isometry3<f64> {
    let cb = body.area_centroid().unwrap();
    let cw = whole.area_centroid().unwrap();
    let mut ant = cb - cw;
    ant.z = 0.0;
    let ant = ant.normalize();
    let up = Vector3::z();
    let right = ant.cross(&up);
    // Rows: new axes in old coordinates.
    let r = Rotation3::from_matrix_unchecked(nalgebra::Matrix3::from_rows(&[
        ant.transpose(),
        up.transpose(),
        right.transpose(),
    ]));
    let rq = UnitQuaternion::from_rotation_matrix(&r);
    Isometry3::from_parts(Translation3::from(-(rq * cb.coords)), rq)
}

/// Acceptance 2 on the dense vertebral bodies: the anterior-node rule and
/// the least-squares fit give a centre inside the body.
#[test]
fn sphere_fit_on_dense_lumbar_bodies() {
    let Some(dir) = common::shared("data/vertebra-meshes") else {
        return;
    };
    for l in 1..=5 {
        let body = osim_spine::mesh::read(&dir.join(format!("L{l}_body.obj"))).unwrap();
        let whole = osim_spine::mesh::read(&dir.join(format!("L{l}_whole.obj"))).unwrap();
        let x = to_opensim_frame(&body, &whole);
        let b = body.transformed(&x);
        let nodes = anterior_body_nodes(&b, &AnatomicalFrame::opensim_body()).unwrap();
        let pts: Vec<Point3<f64>> = nodes.iter().map(|&i| b.vertices[i]).collect();
        let s = fit_sphere(&pts).unwrap();
        let q = MeshQuery::new(&b).unwrap();
        println!(
            "L{l}_body.obj: {} nodes, radius {:.1} mm, RMS {:.2} mm, centre depth {:.1} mm",
            pts.len(),
            s.radius * 1e3,
            s.rms * 1e3,
            -q.signed_distance(&s.centre) * 1e3
        );
        assert!(
            q.contains(&s.centre),
            "L{l}: fitted centre outside the vertebral body"
        );
    }
}

/// `mean-shape`: the mean of rigidly moved copies of a mesh is that mesh
/// (up to a rigid motion); meshes not in correspondence are refused.
#[test]
fn mean_shape_of_moved_copies_is_the_shape() {
    let Some(geom) = common::shared("data/geometry-bodyframe") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let base = osim_spine::mesh::read(&geom.join("lumbar3.vtp")).unwrap();
    let mut paths = Vec::new();
    for (k, (ax, t)) in [(0.3, 0.01), (-0.7, -0.05), (1.1, 0.2)].iter().enumerate() {
        let x = Isometry3::new(Vector3::new(*t, 0.0, -t), Vector3::new(0.1, *ax, -0.2));
        let p = tmp.path().join(format!("m{k}.vtp"));
        osim_spine::mesh::write(&p, &base.transformed(&x)).unwrap();
        paths.push(p);
    }
    let out = tmp.path().join("mean.vtp");
    let o = Command::new(common::bin())
        .arg("mean-shape")
        .args(paths.iter().map(|p| p.to_str().unwrap()))
        .args(["--out", out.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let mean = osim_spine::mesh::read(&out).unwrap();
    assert_eq!(mean.triangles, base.triangles);
    let t = osim_spine::mesh::kabsch(&mean.vertices, &base.vertices).unwrap();
    let rms = (mean
        .vertices
        .iter()
        .zip(&base.vertices)
        .map(|(a, b)| (t.apply(a) - b).norm_squared())
        .sum::<f64>()
        / base.vertices.len() as f64)
        .sqrt();
    assert!(rms < 1e-9, "mean differs from the shape by {rms} m RMS");
    // Not in correspondence.
    let other = tmp.path().join("other.vtp");
    std::fs::copy(geom.join("lumbar4.vtp"), &other).unwrap();
    let l4 = osim_spine::mesh::read(&other).unwrap();
    if l4.triangles != base.triangles {
        let o = Command::new(common::bin())
            .args([
                "mean-shape",
                paths[0].to_str().unwrap(),
                other.to_str().unwrap(),
            ])
            .args(["--out", tmp.path().join("bad.vtp").to_str().unwrap()])
            .output()
            .unwrap();
        assert!(!o.status.success());
        assert!(!tmp.path().join("bad.vtp").exists());
    }
}
