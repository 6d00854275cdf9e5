//! Shared helpers for integration tests: locating `../shared/` and the
//! OpenSim Python bindings, with a printed reason when a test must skip.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::Command;

/// The repository root (where Cargo.toml is).
pub fn repo_root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// True under CI (`CI=true`), where a missing prerequisite is a failure.
pub fn under_ci() -> bool {
    std::env::var("CI").map(|v| v == "true").unwrap_or(false)
}

/// Skip with a printed reason, or fail under CI.
pub fn skip(reason: &str) {
    if under_ci() {
        panic!("CI=true but {reason}");
    }
    eprintln!("SKIP: {reason}");
}

/// `../shared/` beside the repository, or `None` (and a printed reason).
/// CI always has it (a missing one fails there); a user's clone may not.
pub fn shared_dir() -> Option<PathBuf> {
    let p = repo_root().join("..").join("shared");
    if p.join("data").is_dir() {
        Some(p)
    } else {
        skip(&format!(
            "../shared/ not found beside the repository ({})",
            p.display()
        ));
        None
    }
}

/// A path inside `../shared/`, or `None` with a printed reason (a failure
/// under CI).
pub fn shared(rel: &str) -> Option<PathBuf> {
    let p = shared_dir()?.join(rel);
    if p.exists() {
        Some(p)
    } else {
        skip(&format!("{} not found", p.display()));
        None
    }
}

/// A Python interpreter that can `import opensim`: `$OSIM_SPINE_PYTHON`,
/// then `.venv/bin/python` in the repository. `None` with a printed reason.
/// Under CI (`CI=true`) a missing OpenSim is a failure, not a skip.
pub fn opensim_python() -> Option<PathBuf> {
    python_with("opensim")
}

/// A Python interpreter that can `import nibabel` (the NIfTI reference
/// reader), found and skipped as [`opensim_python`].
pub fn nibabel_python() -> Option<PathBuf> {
    python_with("nibabel")
}

/// `$OSIM_SPINE_PYTHON`, then `.venv/bin/python`, the first that can
/// import `module`.
fn python_with(module: &str) -> Option<PathBuf> {
    let mut candidates = Vec::new();
    if let Ok(p) = std::env::var("OSIM_SPINE_PYTHON") {
        candidates.push(PathBuf::from(p));
    }
    candidates.push(repo_root().join(".venv/bin/python"));
    for c in candidates {
        if c.exists() {
            let ok = Command::new(&c)
                .args(["-c", &format!("import {module}")])
                .output()
                .map(|o| o.status.success())
                .unwrap_or(false);
            if ok {
                return Some(c);
            }
        }
    }
    if std::env::var("CI").map(|v| v == "true").unwrap_or(false) {
        panic!("CI=true but no Python with {module} found (set OSIM_SPINE_PYTHON or run .ci/run)");
    }
    eprintln!(
        "SKIP: no Python with `{module}` (set OSIM_SPINE_PYTHON or create .venv: see README)"
    );
    None
}

/// Run a script from `tests/py/` with the OpenSim Python and the given
/// arguments; returns its stdout parsed as JSON. Panics with the script's
/// stderr when it fails (a test failure, not a skip). NumPy's BLAS runs
/// single-threaded: the scripts solve small systems, and a threaded BLAS
/// on a loaded 2-core machine made each 102 x 102 solve take up to 0.5 s.
pub fn run_py(python: &Path, script: &str, args: &[&str]) -> serde_json::Value {
    let script_path = repo_root().join("tests/py").join(script);
    let out = Command::new(python)
        .arg(&script_path)
        .args(args)
        .env("OPENBLAS_NUM_THREADS", "1")
        .output()
        .expect("failed to start python");
    if !out.status.success() {
        panic!(
            "{} failed:\n{}",
            script_path.display(),
            String::from_utf8_lossy(&out.stderr)
        );
    }
    serde_json::from_slice(&out.stdout).unwrap_or_else(|e| {
        panic!(
            "{} printed no JSON ({e}):\n{}",
            script_path.display(),
            String::from_utf8_lossy(&out.stdout)
        )
    })
}

/// Path of the built `osim-spine` binary (for CLI tests).
pub fn bin() -> PathBuf {
    PathBuf::from(env!("CARGO_BIN_EXE_osim-spine"))
}

/// Runs `osim-spine` with `args` and asserts that it succeeded (its stderr
/// in the failure message).
pub fn run_ok<S: AsRef<std::ffi::OsStr>>(args: &[S]) -> std::process::Output {
    let o = Command::new(bin()).args(args).output().unwrap();
    assert!(
        o.status.success(),
        "osim-spine {:?}: {}",
        args.iter().map(|a| a.as_ref()).collect::<Vec<_>>(),
        String::from_utf8_lossy(&o.stderr)
    );
    o
}

/// The wrap checks of the `base` issue on OpenSim's rows for a posed model
/// (`tests/py` scripts' `scoliotic` rows): no wrapped path shorter than the
/// straight line, no path point inside a wrap sphere, every muscle whose
/// straight path crosses its sphere wraps over it. Returns how many crossed.
pub fn assert_wrap_rows(rows: &[serde_json::Value]) -> usize {
    let mut crossing = 0;
    for row in rows {
        let name = row["muscle"].as_str().unwrap();
        let (len, straight) = (
            row["length"].as_f64().unwrap(),
            row["straight"].as_f64().unwrap(),
        );
        assert!(
            len >= straight - 1e-12,
            "{name}: path {len} shorter than straight {straight}"
        );
        let cl = row["min_clearance"].as_f64().unwrap();
        assert!(
            cl > 0.0,
            "{name}: a path point is {:.2} mm inside a wrap sphere",
            -cl * 1e3
        );
        if row["crosses_wrapped_sphere"].as_bool().unwrap() {
            crossing += 1;
            assert!(
                row["wrap_points"].as_u64().unwrap() > 0,
                "{name}: crosses its sphere but does not wrap"
            );
        }
    }
    crossing
}

/// OpenSim 4.6's wrapped muscle paths of `model` at its default pose
/// (`tests/py/wrapped_paths.py`) tested against the model's vertebra
/// meshes: the crossings (muscle, vertebra, depth in mm) of OpenSim's own
/// path (own points, wrap tangent points and arcs; the via points
/// `generate` adds to clear a vertebra are not exempt from that vertebra's
/// test, unlike attachments), and the largest
/// difference between the tool's wrapped path length
/// ([`osim_spine::base::wrapped::wrapped_path`]) and OpenSim's (m).
pub fn opensim_path_crossings(
    python: &Path,
    model: &Path,
) -> (Vec<osim_spine::base::wrapped::Crossing>, f64) {
    use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion};
    use osim_spine::base::wrapped::{self, PathVertex};
    use osim_spine::base::DirMeshSource;
    let r = run_py(python, "wrapped_paths.py", &[model.to_str().unwrap()]);
    let p3 = |v: &serde_json::Value| {
        Point3::new(
            v[0].as_f64().unwrap(),
            v[1].as_f64().unwrap(),
            v[2].as_f64().unwrap(),
        )
    };
    let mut poses: std::collections::BTreeMap<String, Isometry3<f64>> = r["bodies"]
        .as_object()
        .unwrap()
        .iter()
        .map(|(k, v)| {
            let m = Matrix3::from_fn(|i, j| v["R"][i][j].as_f64().unwrap());
            let q = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(m));
            (
                k.clone(),
                Isometry3::from_parts(Translation3::from(p3(&v["p"]).coords), q),
            )
        })
        .collect();
    poses.insert("ground".into(), Isometry3::identity());
    let doc = osim_spine::osim::Document::read(model).unwrap();
    let m = doc.model().unwrap();
    let src = DirMeshSource {
        model_path: model.to_path_buf(),
        extra: vec![],
    };
    let owned = wrapped::vertebra_meshes(&m, &src).unwrap();
    assert_eq!(owned.len(), 17, "vertebra meshes found");
    let verts: Vec<(String, &osim_spine::mesh::MeshQuery)> =
        owned.iter().map(|(n, q)| (n.clone(), q)).collect();
    // The tool's own wrapped paths at the default pose, for the length check.
    let kin = osim_spine::base::kin::Kinematics::new(&m).unwrap();
    let q = kin.default_values();
    let own_poses = kin.body_poses(&q).unwrap();
    let spheres = wrapped::spheres_at(&m, &own_poses);
    let mut crossings = Vec::new();
    let mut worst = 0.0f64;
    for mu in m.muscles() {
        let row = &r["muscles"][&mu.name];
        let poly: Vec<PathVertex> = row["polyline"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| PathVertex {
                ground: p3(&v["ground"]),
                // Via points added by `generate` to clear a vertebra are
                // tested against that vertebra too (not exempt as
                // attachments are).
                body: v["body"]
                    .as_str()
                    .filter(|_| !v["name"].as_str().unwrap_or("").contains("-clear-"))
                    .map(String::from),
            })
            .collect();
        crossings.extend(wrapped::through_vertebrae(&mu.name, &poly, &verts, &poses));
        let mine = wrapped::wrapped_path(&m, mu, &own_poses, &q, &spheres).unwrap();
        worst = worst.max((mine.length - row["length"].as_f64().unwrap()).abs());
    }
    (crossings, worst)
}

/// A generated model in OpenSim 4.6 (`tests/py/base_check.py`): it loads,
/// its 17 bushings carry no force at the default pose, and the base issue's
/// wrap checks hold in a scoliotic test pose (LB 10 deg, AR 5 deg).
/// Returns (muscles with PathWraps, crossing and wrapping).
pub fn check_generated_in_opensim(python: &Path, model: &Path) -> (usize, usize) {
    let r = run_py(
        python,
        "base_check.py",
        &[model.to_str().unwrap(), "10", "5"],
    );
    assert_eq!(r["bushings"], 17);
    let bmax = r["bushing_max_record_at_default"].as_f64().unwrap();
    assert!(
        bmax < 1e-6,
        "bushing force/torque at the default pose {bmax}"
    );
    let rows = r["scoliotic"].as_array().unwrap();
    let crossing = assert_wrap_rows(rows);
    println!(
        "  OpenSim: bushing records at default <= {bmax:.1e}; {} muscles with PathWraps, {crossing} crossing and wrapping",
        rows.len()
    );
    (rows.len(), crossing)
}

/// The names of the files of `dir` that git tracks (a stray file such as
/// OpenSim's `opensim.log` is not one), or `None` when `dir` is not in a
/// git checkout.
pub fn git_tracked(dir: &Path) -> Option<std::collections::BTreeSet<String>> {
    let o = Command::new("git")
        .arg("-C")
        .arg(dir)
        .args(["ls-files", "--", "."])
        .output()
        .ok()?;
    o.status.success().then(|| {
        String::from_utf8_lossy(&o.stdout)
            .lines()
            .map(str::to_string)
            .collect()
    })
}
