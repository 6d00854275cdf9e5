//! Acceptance tests of the procedural default spine (generic model):
//! mesh validity, anatomy against the source tables, T1-S1 length against
//! the published adult value, alignment angles against the chosen means,
//! muscle path clearance and operating range, loading in OpenSim 4.6.
//!
//! Measurements here are taken from the generated meshes (endplate fans
//! found by their topology, planes fitted by SVD) and, where OpenSim is
//! available, from OpenSim's own kinematics and muscle model; they are
//! compared with the numbers in `templates/` (independent of the code).

mod common;

use nalgebra::{Isometry3, Matrix3, Point3, Vector3};
use osim_spine::anatomy::DimensionTable;
use osim_spine::landmarks::Level;
use osim_spine::mesh::{MeshQuery, TriMesh};
use osim_spine::procedural::{generate_generic, GenericModel, ProceduralOptions, Sex, Templates};
use std::collections::BTreeMap;
use std::sync::OnceLock;

fn default_model() -> &'static GenericModel {
    static M: OnceLock<GenericModel> = OnceLock::new();
    M.get_or_init(|| generate_generic(&ProceduralOptions::default()).expect("generate"))
}

/// The two cap fans of a swept shell: the vertices of the highest-degree
/// vertices' triangles. Returns (upper cap, lower cap) by the centre's `up`
/// coordinate.
fn cap_fans(mesh: &TriMesh, up: &Vector3<f64>) -> (Vec<Point3<f64>>, Vec<Point3<f64>>) {
    let mut degree = vec![0usize; mesh.vertices.len()];
    for t in &mesh.triangles {
        for &k in t {
            degree[k as usize] += 1;
        }
    }
    let maxd = *degree.iter().max().unwrap();
    let centres: Vec<usize> = (0..degree.len()).filter(|&i| degree[i] == maxd).collect();
    assert_eq!(centres.len(), 2, "expected two cap centres");
    let fan = |c: usize| -> Vec<Point3<f64>> {
        let mut idx: Vec<u32> = mesh
            .triangles
            .iter()
            .filter(|t| t.contains(&(c as u32)))
            .flat_map(|t| t.iter().copied())
            .filter(|&k| k as usize != c)
            .collect();
        idx.sort();
        idx.dedup();
        idx.iter().map(|&k| mesh.vertices[k as usize]).collect()
    };
    let (a, b) = (centres[0], centres[1]);
    if mesh.vertices[a].coords.dot(up) > mesh.vertices[b].coords.dot(up) {
        (fan(a), fan(b))
    } else {
        (fan(b), fan(a))
    }
}

/// Least-squares plane: (centroid, unit normal oriented along `hint`).
fn fit_plane(pts: &[Point3<f64>], hint: &Vector3<f64>) -> (Point3<f64>, Vector3<f64>) {
    let c = pts.iter().map(|p| p.coords).sum::<Vector3<f64>>() / pts.len() as f64;
    let mut cov = Matrix3::zeros();
    for p in pts {
        let d = p.coords - c;
        cov += d * d.transpose();
    }
    let eig = cov.symmetric_eigen();
    let (imin, _) = eig
        .eigenvalues
        .iter()
        .enumerate()
        .min_by(|a, b| a.1.total_cmp(b.1))
        .unwrap();
    let mut n: Vector3<f64> = eig.eigenvectors.column(imin).into();
    if n.dot(hint) < 0.0 {
        n = -n;
    }
    (Point3::from(c), n)
}

fn extent(pts: &[Point3<f64>], dir: &Vector3<f64>) -> f64 {
    let v: Vec<f64> = pts.iter().map(|p| p.coords.dot(dir)).collect();
    v.iter().cloned().fold(f64::MIN, f64::max) - v.iter().cloned().fold(f64::MAX, f64::min)
}

fn angle_deg(a: &Vector3<f64>, b: &Vector3<f64>) -> f64 {
    a.normalize()
        .dot(&b.normalize())
        .clamp(-1.0, 1.0)
        .acos()
        .to_degrees()
}

/// Signed angle about +Z from `a` to `b` (sagittal vectors), degrees.
fn signed_z_deg(a: &Vector3<f64>, b: &Vector3<f64>) -> f64 {
    let cross = a.cross(b).z;
    cross.atan2(a.dot(b)).to_degrees()
}

/// No edge of the mesh crosses a triangle that does not share its
/// vertices (any two intersecting triangles have such an edge).
fn assert_no_self_intersection(mesh: &TriMesh, what: &str) {
    let q = MeshQuery::new(mesh).unwrap();
    let mut edges: Vec<[u32; 2]> = mesh
        .triangles
        .iter()
        .flat_map(|t| [[t[0], t[1]], [t[1], t[2]], [t[2], t[0]]])
        .map(|[a, b]| if a < b { [a, b] } else { [b, a] })
        .collect();
    edges.sort();
    edges.dedup();
    for [i, j] in edges {
        let (a, b) = (mesh.vertices[i as usize], mesh.vertices[j as usize]);
        for h in q.segment_hits(&a, &b) {
            let t = mesh.triangles[h.triangle];
            if t.contains(&i) || t.contains(&j) {
                continue;
            }
            panic!(
                "{what}: edge {i}-{j} crosses triangle {} at t={}",
                h.triangle, h.t
            );
        }
    }
}

#[test]
fn meshes_are_closed_outward_small_and_free_of_intersections() {
    let g = default_model();
    assert_eq!(g.meshes.len(), 19, "17 vertebrae + sacrum + pelvis");
    for (name, m) in &g.meshes {
        let r = m.edge_report();
        assert!(r.is_watertight(), "{name}: not watertight");
        assert!(
            r.inconsistent_edges.is_empty(),
            "{name}: inconsistent winding"
        );
        assert!(m.signed_volume() > 0.0, "{name}: inward normals");
        assert!(
            m.triangles.len() <= 3000,
            "{name}: {} triangles",
            m.triangles.len()
        );
        assert_no_self_intersection(m, name);
    }
    // each posterior shell is outside the vertebral body and vice versa
    for v in &g.skeleton.vertebrae {
        let qb = MeshQuery::new(&v.body).unwrap();
        for (i, s) in v.posterior.iter().enumerate() {
            assert!(
                !qb.contains(&s.vertices[0]),
                "{}: shell {i} inside the body",
                v.level
            );
            let qs = MeshQuery::new(s).unwrap();
            assert!(
                !qs.contains(&v.body.vertices[0]),
                "{}: body inside shell {i}",
                v.level
            );
        }
    }
}

#[test]
fn vertebral_bodies_match_the_dimension_table_within_5_percent() {
    let g = default_model();
    let table = DimensionTable::embedded().unwrap();
    let k = g.skeleton.scale;
    println!("level  quantity  measured(mm)  table*k(mm)  table(mm)");
    for v in &g.skeleton.vertebrae {
        let row = table.level(v.level);
        let (sup, inf) = cap_fans(&v.body, &Vector3::y());
        let (_, n_sup) = fit_plane(&sup, &Vector3::y());
        let (_, n_inf) = fit_plane(&inf, &-Vector3::y());
        // in-plane anterior and right directions of each endplate
        let right = Vector3::z();
        let ant_sup = right.cross(&n_sup).normalize();
        let ant_inf = (-right).cross(&n_inf).normalize();
        let amax = |pts: &[Point3<f64>], d: &Vector3<f64>| {
            *pts.iter()
                .max_by(|a, b| a.coords.dot(d).total_cmp(&b.coords.dot(d)))
                .unwrap()
        };
        let measured = [
            ("sup_ep_width", extent(&sup, &right), row.sup_ep_width.mean),
            (
                "sup_ep_depth",
                extent(&sup, &ant_sup),
                row.sup_ep_depth.mean,
            ),
            ("inf_ep_width", extent(&inf, &right), row.inf_ep_width.mean),
            (
                "inf_ep_depth",
                extent(&inf, &ant_inf),
                row.inf_ep_depth.mean,
            ),
            (
                "ant_height",
                (amax(&sup, &Vector3::x()) - amax(&inf, &Vector3::x())).dot(&Vector3::y()),
                row.ant_height.mean,
            ),
            (
                "post_height",
                (amax(&sup, &-Vector3::x()) - amax(&inf, &-Vector3::x())).dot(&Vector3::y()),
                row.post_height.mean,
            ),
        ];
        for (q, m, t) in measured {
            println!(
                "{:<5} {q:<13} {:>7.2} {:>7.2} {:>7.2}",
                v.level.to_string(),
                1e3 * m,
                1e3 * t * k,
                1e3 * t
            );
            assert!(
                (m - t * k).abs() <= 0.05 * t * k,
                "{} {q}: {m} vs {}",
                v.level,
                t * k
            );
            assert!(
                (m - t).abs() <= 0.05 * t,
                "{} {q}: {m} vs table {t}",
                v.level
            );
        }
    }
    // sacrum: flat S1 endplate of the tabulated size
    let s1 = table.level(Level::S1);
    let sac = &g.skeleton.pelvis.sacrum;
    let (top, _) = cap_fans(sac, &Vector3::y());
    let (_, n) = fit_plane(&top, &Vector3::y());
    let w = extent(&top, &Vector3::z());
    let d = extent(&top, &Vector3::z().cross(&n).normalize());
    println!("S1 endplate {:.2} x {:.2} mm", 1e3 * w, 1e3 * d);
    assert!((w - s1.sup_ep_width.mean * k).abs() <= 0.05 * s1.sup_ep_width.mean * k);
    assert!((d - s1.sup_ep_depth.mean * k).abs() <= 0.05 * s1.sup_ep_depth.mean * k);
}

/// Superior endplate centre of T1 and of S1 in ground, from the meshes.
fn t1_s1_length(g: &GenericModel, poses: &BTreeMap<String, Isometry3<f64>>) -> f64 {
    let t1 = g.skeleton.vertebra(Level::T1).unwrap();
    let (sup, _) = cap_fans(&t1.body, &Vector3::y());
    let (c_t1, _) = fit_plane(&sup, &Vector3::y());
    let (top, _) = cap_fans(&g.skeleton.pelvis.sacrum, &Vector3::y());
    let (c_s1, _) = fit_plane(&top, &Vector3::y());
    let a = poses["thoracic1"] * c_t1;
    let b = poses["sacrum"] * c_s1;
    (a - b).norm()
}

#[test]
fn t1_s1_length_matches_the_published_adult_value() {
    // Dimeglio A, Canavese F. The growing spine: how spinal deformities
    // influence normal spine and thoracic cage growth. Eur Spine J
    // 2012;21:64-70: the T1-S1 segment measures about 45 cm in men and
    // 42 cm in women at the end of growth.
    for (sex, published) in [(Sex::Male, 0.45), (Sex::Female, 0.42)] {
        let g = generate_generic(&ProceduralOptions { stature: None, sex }).unwrap();
        let l = t1_s1_length(&g, &g.skeleton.poses);
        println!(
            "{sex}: stature {} m, T1-S1 {:.1} mm (published {:.0} mm)",
            g.skeleton.stature,
            1e3 * l,
            1e3 * published
        );
        assert!((l - published).abs() <= 0.05 * published, "{sex}: {l}");
    }
}

/// Alignment angles (deg) measured from the meshes placed by `poses`:
/// (lumbar lordosis L1-S1, thoracic kyphosis T4-T12, sacral slope).
fn alignment_angles(g: &GenericModel, poses: &BTreeMap<String, Isometry3<f64>>) -> (f64, f64, f64) {
    let sk = &g.skeleton;
    let endplate_normal = |level: Level, superior: bool| -> Vector3<f64> {
        let v = sk.vertebra(level).unwrap();
        let (sup, inf) = cap_fans(&v.body, &Vector3::y());
        let (_, n) = if superior {
            fit_plane(&sup, &Vector3::y())
        } else {
            fit_plane(&inf, &Vector3::y())
        };
        poses[&level.body_name()].rotation * n
    };
    let (top, _) = cap_fans(&sk.pelvis.sacrum, &Vector3::y());
    let (_, ns) = fit_plane(&top, &Vector3::y());
    let n_s1 = poses["sacrum"].rotation * ns;
    let n_l1 = endplate_normal(Level::L1, true);
    let n_t4 = endplate_normal(Level::T4, true);
    let n_t12 = endplate_normal(Level::T12, false);
    // lordosis: L1 normal is rotated backwards (+Z) from S1's
    let ll = signed_z_deg(&n_s1, &n_l1);
    let tk = -signed_z_deg(&n_t12, &n_t4);
    let ss = angle_deg(&n_s1, &Vector3::y());
    (ll, tk, ss)
}

#[test]
fn alignment_matches_the_chosen_population_means() {
    let g = default_model();
    let t = Templates::embedded().unwrap();
    let (ll, tk, ss) = alignment_angles(g, &g.skeleton.poses);
    println!("LL L1-S1 {ll:.2} deg, TK T4-T12 {tk:.2} deg, SS {ss:.2} deg");
    assert!(
        (ll - t.alignment.lumbar.lordosis_l1_s1_deg).abs() < 0.5,
        "LL {ll}"
    );
    assert!(
        (tk - t.alignment.thoracic.kyphosis_t4_t12_deg).abs() < 0.5,
        "TK {tk}"
    );
    assert!(
        (ss - t.alignment.pelvis.sacral_slope_deg).abs() < 0.5,
        "SS {ss}"
    );
    // pelvic tilt: hip axis to S1 endplate centre vs vertical
    let hip = g.skeleton.pelvis.pelvis_landmarks["hip_r"];
    let hip_mid = Point3::new(hip.x, hip.y, 0.0);
    let (top, _) = cap_fans(&g.skeleton.pelvis.sacrum, &Vector3::y());
    let (c, _) = fit_plane(&top, &Vector3::y());
    let s1 = g.skeleton.poses["sacrum"] * c;
    let pt = (hip_mid.x - s1.x).atan2(s1.y - hip_mid.y).to_degrees();
    println!("PT {pt:.2} deg");
    assert!(
        (pt - t.alignment.pelvis.pelvic_tilt_deg).abs() < 0.5,
        "PT {pt}"
    );
}

#[test]
fn muscle_paths_clear_the_vertebrae_and_fibres_sit_near_optimal() {
    let g = default_model();
    assert!(g.muscles.len() >= 60, "{} muscles", g.muscles.len());
    // every family on both sides
    for prefix in ["MF_", "LTpL_", "LTpT_", "IL_", "QL_", "PS_"] {
        for side in ["_r", "_l"] {
            assert!(
                g.muscles
                    .iter()
                    .any(|m| m.name.starts_with(prefix) && m.name.ends_with(side)),
                "no {prefix}*{side}"
            );
        }
    }
    let sk = &g.skeleton;
    let bodies: Vec<(String, MeshQuery)> = sk
        .vertebrae
        .iter()
        .map(|v| {
            let pose = sk.poses[&v.level.body_name()];
            (
                v.level.to_string(),
                MeshQuery::new(&v.body.transformed(&pose)).unwrap(),
            )
        })
        .collect();
    println!("muscle  L_mt(mm)  l_fibre/l_opt");
    let mut vias = 0;
    for m in &g.muscles {
        let pts: Vec<Point3<f64>> = m
            .points
            .iter()
            .map(|p| sk.poses[&p.body] * Point3::from(p.location))
            .collect();
        for w in pts.windows(2) {
            for (lv, q) in &bodies {
                let inside = q.segment_length_inside(&w[0], &w[1]);
                assert!(
                    !q.segment_intersects(&w[0], &w[1]),
                    "{} crosses {lv} ({:.1} mm inside)",
                    m.name,
                    1e3 * inside
                );
            }
        }
        let l: f64 = pts.windows(2).map(|w| (w[1] - w[0]).norm()).sum();
        vias += m.clearance_via_points;
        let ratio = (l - m.tendon_slack_length) / m.optimal_fiber_length;
        println!("{:<14} {:>7.1} {:>6.3}", m.name, 1e3 * l, ratio);
        assert!((0.5..=1.5).contains(&ratio), "{}: {ratio}", m.name);
    }
    println!("{} muscles, {vias} clearance via points", g.muscles.len());
}

#[test]
fn generation_is_deterministic_and_options_are_checked() {
    let a = default_model().files("generic");
    let b = generate_generic(&ProceduralOptions::default())
        .unwrap()
        .files("generic");
    assert_eq!(a.len(), b.len());
    for ((na, ba), (nb, bb)) in a.iter().zip(&b) {
        assert_eq!(na, nb);
        assert!(ba == bb, "{na} differs between runs");
    }
    let total: usize = a.iter().map(|(_, b)| b.len()).sum();
    println!("generic model: {} files, {} bytes", a.len(), total);
    assert!(total < 3_000_000, "{total} bytes");
    let e = generate_generic(&ProceduralOptions {
        stature: Some(175.0),
        sex: Sex::Male,
    })
    .unwrap_err()
    .to_string();
    assert!(e.contains("metres"), "{e}");
    assert!("unknown".parse::<Sex>().is_err());
    // taller -> proportionally longer spine
    let tall = generate_generic(&ProceduralOptions {
        stature: Some(1.9),
        sex: Sex::Male,
    })
    .unwrap();
    let r = t1_s1_length(&tall, &tall.skeleton.poses)
        / t1_s1_length(default_model(), &default_model().skeleton.poses);
    assert!((r - 1.9 / 1.75).abs() < 1e-6, "{r}");
}

fn mat_from_json(v: &serde_json::Value) -> Matrix3<f64> {
    let mut m = Matrix3::zeros();
    for a in 0..3 {
        for c in 0..3 {
            m[(a, c)] = v[a][c].as_f64().unwrap();
        }
    }
    m
}

#[test]
fn generic_model_loads_in_opensim_with_the_same_kinematics_and_muscles() {
    let Some(py) = common::opensim_python() else {
        return;
    };
    let g = default_model();
    let dir = tempfile::tempdir().unwrap();
    g.write(dir.path(), "generic").unwrap();
    let model = dir.path().join("generic.osim");
    let out = common::run_py(&py, "procedural_generic.py", &[model.to_str().unwrap()]);

    // bodies and joints
    let bodies = out["bodies"].as_object().unwrap();
    let mut expected: Vec<String> = Level::ALL[..17].iter().map(|l| l.body_name()).collect();
    expected.extend(["sacrum".to_string(), "pelvis".to_string()]);
    assert_eq!(bodies.len(), expected.len());
    for b in &expected {
        assert!(bodies.contains_key(b), "OpenSim model lacks {b}");
    }
    let joints = out["joints"].as_array().unwrap();
    assert_eq!(joints.len(), 19);
    let find = |n: &str| {
        joints
            .iter()
            .find(|j| j["name"] == n)
            .unwrap_or_else(|| panic!("{n}"))
    };
    assert_eq!(find("ground_pelvis")["parent"], "ground");
    assert_eq!(find("sacral")["class"], "WeldJoint");
    for w in Level::ALL.windows(2) {
        let j = find(&format!("{}_{}_IVDjnt", w[0], w[1]));
        assert_eq!(j["class"], "CustomJoint");
        assert_eq!(j["parent"], w[1].body_name().as_str());
        assert_eq!(j["child"], w[0].body_name().as_str());
        assert_eq!(j["ncoords"], 3);
    }
    let coords: Vec<&str> = out["coordinates"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c.as_str().unwrap())
        .collect();
    for c in ["L5_S1_FE", "L5_S1_LB", "L5_S1_AR", "T1_T2_FE", "T12_L1_AR"] {
        assert!(coords.contains(&c), "{c}");
    }

    // OpenSim's body placement at the default pose equals the generator's
    let mut poses = BTreeMap::new();
    for (name, b) in bodies {
        let p = b["p"].as_array().unwrap();
        let t = Vector3::new(
            p[0].as_f64().unwrap(),
            p[1].as_f64().unwrap(),
            p[2].as_f64().unwrap(),
        );
        let r = mat_from_json(&b["R"]);
        let ours = g.skeleton.poses[name];
        assert!(
            (ours.translation.vector - t).norm() < 1e-9,
            "{name} position"
        );
        assert!(
            (ours.rotation.to_rotation_matrix().matrix() - r).norm() < 1e-9,
            "{name} rotation"
        );
        let rot = nalgebra::UnitQuaternion::from_matrix(&r);
        poses.insert(name.clone(), Isometry3::from_parts(t.into(), rot));
    }
    // alignment and length measured with OpenSim's transforms
    let t = Templates::embedded().unwrap();
    let (ll, tk, ss) = alignment_angles(g, &poses);
    println!(
        "OpenSim pose: LL {ll:.2}, TK {tk:.2}, SS {ss:.2} deg, T1-S1 {:.1} mm",
        1e3 * t1_s1_length(g, &poses)
    );
    assert!((ll - t.alignment.lumbar.lordosis_l1_s1_deg).abs() < 0.5);
    assert!((tk - t.alignment.thoracic.kyphosis_t4_t12_deg).abs() < 0.5);
    assert!((ss - t.alignment.pelvis.sacral_slope_deg).abs() < 0.5);

    // muscles: OpenSim's lengths and fibre lengths at the default pose
    let ms = out["muscles"].as_array().unwrap();
    assert_eq!(ms.len(), g.muscles.len());
    assert!(ms.len() >= 60);
    let mut worst: f64 = 0.0;
    for m in ms {
        let name = m["name"].as_str().unwrap();
        assert_eq!(m["class"], "Millard2012EquilibriumMuscle");
        let ours = g.muscles.iter().find(|x| x.name == name).unwrap();
        let l = m["length"].as_f64().unwrap();
        assert!(
            (l - ours.length_default).abs() < 1e-9,
            "{name}: {l} vs {}",
            ours.length_default
        );
        let ratio =
            m["fiber_length"].as_f64().unwrap() / m["optimal_fiber_length"].as_f64().unwrap();
        worst = worst.max((ratio - 1.0).abs());
        assert!(
            (0.5..=1.5).contains(&ratio),
            "{name}: fibre/optimal {ratio}"
        );
    }
    println!(
        "{} muscles; OpenSim fibre/optimal at the default pose within 1 +- {worst:.2e}",
        ms.len()
    );
}

/// The files of a folder (relative name -> bytes), sorted.
fn folder_files(dir: &std::path::Path) -> BTreeMap<String, Vec<u8>> {
    let tracked = common::git_tracked(dir);
    let mut out = BTreeMap::new();
    for e in std::fs::read_dir(dir).unwrap() {
        let e = e.unwrap();
        let name = e.file_name().to_string_lossy().into_owned();
        let kept = tracked.as_ref().is_none_or(|t| t.contains(&name));
        if e.file_type().unwrap().is_file() && kept {
            out.insert(name, std::fs::read(e.path()).unwrap());
        }
    }
    out
}

/// Acceptance 1: `base_model/` is what `osim-spine base --procedural --out
/// base_model` writes (byte for byte), and it is a complete base model.
#[test]
fn base_model_is_regenerated_byte_identically_and_is_complete() {
    let repo = common::repo_root().join("base_model");
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("base_model");
    let o = std::process::Command::new(common::bin())
        .args(["base", "--procedural", "--out", out.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let (want, got) = (folder_files(&repo), folder_files(&out));
    assert_eq!(
        want.keys().collect::<Vec<_>>(),
        got.keys().collect::<Vec<_>>(),
        "file set differs: regenerate with `cargo run -- base --procedural --out base_model`"
    );
    for (name, bytes) in &want {
        assert!(
            bytes == &got[name],
            "base_model/{name} differs from a fresh build: regenerate with \
             `cargo run -- base --procedural --out base_model`"
        );
    }
    let total: usize = want.values().map(|b| b.len()).sum();
    println!(
        "base_model/: {} files, {:.2} MB",
        want.len(),
        total as f64 / 1e6
    );
    assert!(total < 5_000_000);

    // contents, read back with the tool's own reader
    let base = repo.join("base.osim");
    let m = osim_spine::osim::Document::read(&base)
        .unwrap()
        .model()
        .unwrap();
    let mut names: Vec<String> = m.bodies.iter().map(|b| b.name.clone()).collect();
    names.sort();
    let mut expected: Vec<String> = Level::ALL[..17].iter().map(|l| l.body_name()).collect();
    expected.extend(["sacrum".to_string(), "pelvis".to_string()]);
    expected.sort();
    assert_eq!(names, expected);
    let six_dof = m
        .joints
        .iter()
        .filter(|j| j.name.ends_with("_IVDjnt") && j.coordinates.len() == 6)
        .count();
    assert_eq!(six_dof, 17);
    assert_eq!(m.bushings().count(), 17);
    let spheres: usize = m
        .bodies
        .iter()
        .flat_map(|b| &b.wrap_objects)
        .filter(|w| w.class() == "WrapSphere")
        .count();
    assert!(spheres >= 17, "{spheres} wrap spheres");
    let mut per_body: BTreeMap<String, usize> = BTreeMap::new();
    for mk in &m.markers {
        let (body, _) = m.marker_frame(mk).unwrap();
        *per_body.entry(body).or_default() += 1;
    }
    for l in &Level::ALL[..17] {
        assert_eq!(per_body.get(&l.body_name()), Some(&14), "{l} markers");
    }
    assert!(m.muscles().count() >= 60);
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(repo.join("base_report.json")).unwrap()).unwrap();
    let sc = &report["self_check"];
    assert_eq!(
        sc["muscle_segments_through_vertebrae"]
            .as_array()
            .unwrap()
            .len(),
        0
    );
    assert_eq!(
        report["palpation_ordering_failures"]
            .as_array()
            .unwrap()
            .len(),
        0
    );
    assert!(sc["bushing_max_rotation"].as_f64().unwrap() < 1e-12);
    assert!(sc["bushing_max_translation"].as_f64().unwrap() < 1e-12);

    let Some(py) = common::opensim_python() else {
        return;
    };
    let r = common::run_py(&py, "base_check.py", &[base.to_str().unwrap(), "10", "5"]);
    assert_eq!(r["ivd_6dof_joints"], 17);
    assert_eq!(r["bushings"], 17);
    assert!(r["bushing_max_record_at_default"].as_f64().unwrap() < 1e-9);
    let g = common::run_py(&py, "procedural_generic.py", &[base.to_str().unwrap()]);
    let ms = g["muscles"].as_array().unwrap();
    assert!(ms.len() >= 60);
    let (mut lo, mut hi) = (f64::MAX, f64::MIN);
    for mu in ms {
        let ratio =
            mu["fiber_length"].as_f64().unwrap() / mu["optimal_fiber_length"].as_f64().unwrap();
        lo = lo.min(ratio);
        hi = hi.max(ratio);
        assert!((0.5..=1.5).contains(&ratio), "{}: {ratio}", mu["name"]);
    }
    println!(
        "base_model in OpenSim 4.6: {} muscles, fibre/optimal at the default pose {lo:.3}..{hi:.3}",
        ms.len()
    );
}
