//! Acceptance 1 of `osim-spine stiffness`: for each form (linear
//! BushingForce; non-linear FunctionBasedBushingForce; non-linear sinh and
//! coupled 6x6 as ExpressionBasedBushingForce; on all but chain17 also a
//! general expression law: rotational stiffness growing with axial
//! compression), the tool writes the model with the CLI, solves static
//! equilibria under pure moments on the top vertebra about the three ground
//! axes (sacrum/pelvis welded, gravity off in both tools), and OpenSim 4.6
//! (Python bindings), reading the written file, finds its own equilibrium
//! within 1e-8 (rad or m) of the tool's in every coordinate (Newton on
//! OpenSim's inverse-dynamics residual started from the tool's answer).
//!
//! Models, all checked by the one function [`check_model`]:
//! - the 17-joint chain `../shared/oracle/chain17.osim` (+-1, 2.5, 5, 7.5 N m);
//! - the dev specimen `../shared/diagnose-dev/dev-01/specimen.osim`, sacrum
//!   to L1 with `<LEVEL>_IVDjnt` joints (the same moments);
//! - the project's base model `base_model/base.osim` (T1-L5 + sacrum +
//!   pelvis, 17 six-DoF joints, 76 Millard muscles, wrap spheres) and the
//!   base model `osim-spine base --generic` builds from the cyclist (178
//!   Thelen muscles): 1 then 7.5 N m, and -7.5 N m, to keep CI time modest
//!   (102 DoFs: OpenSim's finite-difference Jacobian dominates the time).
//!
//! Muscles: the tool's solver applies no muscle force (see
//! `solver::from_model`); OpenSim gets the same by `appliesForce = false` on
//! every non-bushing force of the written file (not removed: the file both
//! tools read stays the one the CLI wrote; removing them was measured to be
//! no faster). What is compared is the equilibrium of the ligamentous spine.
//!
//! Large rotations: under 7.5 N m T1 turns by up to ~150 deg over the 17
//! joints (up to ~11 deg per joint); each case also asserts that the loaded
//! body turns with the moment (positive work) and further under the larger
//! moment of a sequence.

mod common;

use nalgebra::{Matrix3, Rotation3, Vector3};
use osim_spine::osim::Document;
use osim_spine::solver::{
    BushingModel, Load, LoadFrame, StaticOptions, System, SystemSpec, Workspace,
};
use std::path::Path;
use std::process::Command;

const UNITS: &str = "[units]\nrotational = \"N*m/rad\"\ntranslational = \"N/m\"\nrot_damping = \"N*m*s/rad\"\ntrans_damping = \"N*s/m\"\n";

fn linear_table() -> String {
    format!(
        "{UNITS}
[all]
form = \"linear\"
stiffness = {{ rx = 68.8, ry = 291, rz = 51.0, tx = 149000, ty = 1890000, tz = 135000 }}
damping = {{ rx = 2.3, ry = 2.3, rz = 2.3, tx = 1000, ty = 1000, tz = 1000 }}

[[level]]
name = \"L5_S1\"
ratio = {{ rx = 1.5, ry = 0.63, rz = 1.2 }}

[[level]]
name = \"L4_L5\"
stiffness = {{ rx = 40.0, rz = 80.0 }}
"
    )
}

fn nonlinear_function_table() -> String {
    format!(
        "{UNITS}
[all]
form = \"nonlinear\"
stiffness = {{ tx = 149000, tz = 135000 }}
damping = {{ rx = 2.3, ry = 2.3, rz = 2.3, tx = 1000, ty = 1000, tz = 1000 }}
[[all.curve]]
dof = \"rx\"
kind = \"cubic\"
k = 68.8
c = 900.0
[[all.curve]]
dof = \"ry\"
kind = \"bilinear\"
k_neg = 200.0
k_pos = 350.0
[[all.curve]]
dof = \"rz\"
kind = \"points\"
interp = \"spline\"
x = [-0.5, -0.25, -0.1, 0.0, 0.1, 0.25, 0.5]
y = [-40.0, -14.0, -5.0, 0.0, 5.5, 16.0, 45.0]
[[all.curve]]
dof = \"ty\"
kind = \"points\"
interp = \"linear\"
x = [-0.01, 0.0, 0.01]
y = [-25000.0, 0.0, 15000.0]

[[level]]
name = \"L5_S1\"
form = \"nonlinear\"
[[level.curve]]
dof = \"rx\"
kind = \"linear\"
k = 90.0
"
    )
}

fn nonlinear_sinh_table() -> String {
    format!(
        "{UNITS}
[all]
form = \"nonlinear\"
stiffness = {{ tx = 149000, ty = 1890000, tz = 135000 }}
damping = {{ rx = 2.3, ry = 2.3, rz = 2.3, tx = 1000, ty = 1000, tz = 1000 }}
[[all.curve]]
dof = \"rx\"
kind = \"sinh\"
k = 68.8
a = 0.05
[[all.curve]]
dof = \"ry\"
kind = \"sinh\"
k = 291.0
a = 0.1
[[all.curve]]
dof = \"rz\"
kind = \"sinh\"
k = 51.0
a = 0.04
[[all.curve]]
dof = \"tz\"
kind = \"cubic\"
k = 135000.0
c = 1.0e9
"
    )
}

/// Rotational stiffness growing with axial compression (`-delta_y`) plus a
/// coupling term: the general expression form (specimen only).
fn expression_table() -> String {
    format!(
        "{UNITS}
[all]
form = \"expression\"
damping = {{ rx = 2.3, ry = 2.3, rz = 2.3, tx = 1000, ty = 1000, tz = 1000 }}
expressions = {{ rx = \"68.8*theta_x*(1+2000*max(0,-delta_y))\", ry = \"291*theta_y\", rz = \"51*theta_z*(1+2000*max(0,-delta_y))+3*theta_x\", tx = \"149000*delta_x\", ty = \"1890000*delta_y+1e9*delta_y^3\", tz = \"135000*delta_z\" }}
"
    )
}

fn coupled_table() -> String {
    format!(
        "{UNITS}
[all]
form = \"coupled\"
damping = {{ rx = 2.3, ry = 2.3, rz = 2.3, tx = 1000, ty = 1000, tz = 1000 }}
matrix = [
  [68.8, 0.0, 8.0, 0.0, 200.0, 0.0],
  [0.0, 291.0, 0.0, -300.0, 0.0, 0.0],
  [8.0, 0.0, 51.0, 0.0, 0.0, 150.0],
  [0.0, -300.0, 0.0, 149000.0, 0.0, 0.0],
  [200.0, 0.0, 0.0, 0.0, 1890000.0, 0.0],
  [0.0, 0.0, 150.0, 0.0, 0.0, 135000.0],
]
"
    )
}

/// Copy `src` with gravity off into `dir`, apply `table` with the CLI; returns the written model.
fn write_model(src: &Path, table: &str, dir: &Path, tag: &str) -> std::path::PathBuf {
    let mut doc = Document::read(src).unwrap();
    doc.set_model_property("gravity", "0 0 0");
    let base = dir.join(format!("{tag}_base.osim"));
    doc.write(&base).unwrap();
    let tpath = dir.join(format!("{tag}.toml"));
    std::fs::write(&tpath, table).unwrap();
    let out = dir.join(format!("{tag}.osim"));
    let o = Command::new(common::bin())
        .args(["stiffness", base.to_str().unwrap(), "--table"])
        .arg(&tpath)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "{tag}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    out
}

/// The equilibria asked of one model: pure moments on `top` about each
/// ground axis, solved by the tool along each continuation sequence in
/// `sequences` (every sequence starts from the default pose, each later
/// moment from the previous equilibrium).
struct Plan<'a> {
    label: &'a str,
    src: &'a Path,
    top: &'a str,
    sequences: &'a [&'a [f64]],
    /// Also the general expression form (compression-stiffened rotation).
    with_expression: bool,
}

/// The stiffness forms as (tag, table, OpenSim class written).
fn forms(with_expression: bool) -> Vec<(&'static str, String, &'static str)> {
    let mut forms = vec![
        ("linear", linear_table(), "BushingForce"),
        (
            "nonlinear_functions",
            nonlinear_function_table(),
            "FunctionBasedBushingForce",
        ),
        (
            "nonlinear_sinh",
            nonlinear_sinh_table(),
            "ExpressionBasedBushingForce",
        ),
        ("coupled", coupled_table(), "ExpressionBasedBushingForce"),
    ];
    if with_expression {
        forms.push((
            "expression",
            expression_table(),
            "ExpressionBasedBushingForce",
        ));
    }
    forms
}

/// For every form: write the model with the CLI, solve the plan's
/// equilibria with the tool, and have OpenSim find its own equilibria from
/// the tool's on the written file; they must agree within 1e-8 (rad or m).
/// Returns the largest |q_opensim - q_tool| per form.
fn check_model(python: &Path, plan: &Plan) -> Vec<(&'static str, f64)> {
    let label = plan.label;
    let top = plan.top;
    let dir = tempfile::tempdir().unwrap();
    let per_axis: usize = plan.sequences.iter().map(|s| s.len()).sum();
    let mut summary = Vec::new();
    for (tag, table, class) in forms(plan.with_expression) {
        let out = write_model(plan.src, &table, dir.path(), tag);
        let text = std::fs::read_to_string(&out).unwrap();
        assert!(
            text.contains(&format!("<{class} ")),
            "{label} {tag}: no {class}"
        );
        let spec = SystemSpec::read_osim(&out).unwrap();
        assert_eq!(spec.gravity, Vector3::zeros());
        let want_kind = |m: &BushingModel| match tag {
            "linear" => matches!(m, BushingModel::Linear { .. }),
            "coupled" => matches!(m, BushingModel::Coupled { .. }),
            "nonlinear_functions" => matches!(m, BushingModel::PerDof { .. }),
            _ => matches!(m, BushingModel::Expression { .. }),
        };
        assert!(
            spec.bushings.iter().all(|b| want_kind(&b.model)),
            "{label} {tag}: solver law"
        );
        let t_tool = std::time::Instant::now();
        let sys = System::new(&spec).unwrap();
        let mut ws = Workspace::new(&sys);
        let opts = StaticOptions {
            residual_tol: 1e-11,
            ..StaticOptions::default()
        };
        let mut cases = Vec::new();
        let mut iterations = 0;
        let r_top = |q: &[f64], ws: &mut Workspace| -> Rotation3<f64> {
            let p = &sys.body_poses(q, ws).unwrap()[top];
            let r = p.r_ground_body_rowmajor;
            Rotation3::from_matrix_unchecked(Matrix3::from_fn(|i, j| r[i][j]))
        };
        let r0 = r_top(sys.default_q().as_slice(), &mut ws);
        // largest rotation of the top body from its unloaded pose (rad) and
        // largest rotational bushing deflection (rad) over the cases
        let (mut top_angle, mut bushing_angle) = (0.0f64, 0.0f64);
        for axis in 0..3 {
            for seq in plan.sequences {
                let mut q_prev = sys.default_q();
                let mut prev_angle: Option<f64> = None;
                for &m in seq.iter() {
                    let mut v = Vector3::zeros();
                    v[axis] = m;
                    let loads = sys
                        .prepare_loads(&[Load::Moment {
                            body: top.into(),
                            vec: v,
                            frame: LoadFrame::Ground,
                        }])
                        .unwrap();
                    let sol = sys
                        .solve_static(&loads, q_prev.as_slice(), &mut ws, &opts)
                        .unwrap_or_else(|e| panic!("{label} {tag} axis {axis} {m} Nm: {e}"));
                    iterations += sol.iterations;
                    // Large-rotation sanity, independent of any stiffness
                    // law: a stable elastic chain turns its loaded body
                    // with the moment (positive work), and further for a
                    // larger moment of the same sign.
                    let rot = r_top(sol.q.as_slice(), &mut ws) * r0.inverse();
                    let work = rot.scaled_axis().dot(&v);
                    assert!(
                        work > 0.0,
                        "{label} {tag} axis {axis} {m} Nm: {top} turns against the moment"
                    );
                    let angle = rot.angle();
                    if let Some(prev) = prev_angle {
                        assert!(
                            angle > prev,
                            "{label} {tag} axis {axis} {m} Nm: rotation {angle} not larger than at the smaller moment ({prev})"
                        );
                    }
                    prev_angle = Some(angle);
                    top_angle = top_angle.max(angle);
                    for b in sys
                        .bushing_records(sol.q.as_slice(), None, &mut ws)
                        .unwrap()
                        .values()
                    {
                        let d = b.deflection_rx_ry_rz_tx_ty_tz;
                        bushing_angle =
                            bushing_angle.max(d[0].abs().max(d[1].abs()).max(d[2].abs()));
                    }
                    q_prev = sol.q.clone();
                    let full = sys.full_coordinates(sol.q.as_slice());
                    let q: serde_json::Map<String, serde_json::Value> = sys
                        .coordinates()
                        .iter()
                        .zip(full)
                        .map(|(c, v)| (c.name.clone(), serde_json::json!(v)))
                        .collect();
                    cases.push(serde_json::json!({"axis": axis, "moment": m, "q": q}));
                }
            }
        }
        let t_tool = t_tool.elapsed().as_secs_f64();
        let cpath = dir.path().join(format!("{tag}_cases.json"));
        std::fs::write(
            &cpath,
            serde_json::to_string(&serde_json::json!({"body": top, "cases": cases})).unwrap(),
        )
        .unwrap();
        // OpenSim's own equilibria from the tool's, on the written file.
        let t_py = std::time::Instant::now();
        let (worst, biggest_q, n) = opensim_equilibria(python, &out, &cpath, label, tag);
        let t_py = t_py.elapsed().as_secs_f64();
        assert_eq!(n, 3 * per_axis);
        assert!(
            biggest_q > 0.05,
            "{label} {tag}: loads too small to test anything"
        );
        eprintln!(
            "{label} {tag}: {n} equilibria, max |q_opensim - q_tool| = {worst:.2e} (largest |q| {biggest_q:.3}, {top} turned up to {:.1} deg, bushings up to {:.1} deg); tool {t_tool:.2} s ({iterations} Newton iterations), OpenSim {t_py:.2} s",
            top_angle.to_degrees(),
            bushing_angle.to_degrees()
        );
        summary.push((tag, worst));
    }
    summary
}

/// OpenSim's Newton from the tool's equilibria of the cases in `cases` on
/// the model `model`: converged, and within 1e-8 (rad or m) of the tool's.
/// Returns the largest |q_opensim - q_tool|, the largest |q| and the case
/// count.
fn opensim_equilibria(
    python: &Path,
    model: &Path,
    cases: &Path,
    label: &str,
    tag: &str,
) -> (f64, f64, usize) {
    let res = common::run_py(
        python,
        "stiffness_equilibria.py",
        &[model.to_str().unwrap(), cases.to_str().unwrap()],
    );
    let mut worst = 0.0f64;
    let mut biggest_q = 0.0f64;
    for c in res["cases"].as_array().unwrap() {
        let dq = c["max_abs_dq"].as_f64().unwrap();
        let fin = c["final_residual"].as_f64().unwrap();
        worst = worst.max(dq);
        biggest_q = biggest_q.max(c["max_abs_q"].as_f64().unwrap());
        assert!(
            fin < 1e-8,
            "{label} {tag} axis {} {} Nm: OpenSim's Newton did not converge ({fin:e})",
            c["axis"],
            c["moment"]
        );
        assert!(
            dq < 1e-8,
            "{label} {tag} axis {} {} Nm: |q_opensim - q_tool| = {dq:e} (residual at the tool's q {:e})",
            c["axis"],
            c["moment"],
            c["residual_at_tool_q"].as_f64().unwrap_or(f64::NAN)
        );
    }
    (worst, biggest_q, res["cases"].as_array().unwrap().len())
}

/// +-1, 2.5, 5, 7.5 N m, each sign continued from the default pose.
const FULL: &[&[f64]] = &[&[1.0, 2.5, 5.0, 7.5], &[-1.0, -2.5, -5.0, -7.5]];

/// On the 102-DoF base models: 1 then 7.5 N m, and -7.5 N m straight from
/// the default pose (9 equilibria per form).
const BASE: &[&[f64]] = &[&[1.0, 7.5], &[-7.5]];

#[test]
fn chain17_equilibria_match_opensim_for_every_form() {
    let (Some(model), Some(py)) = (
        common::shared("oracle/chain17.osim"),
        common::opensim_python(),
    ) else {
        return;
    };
    check_model(
        &py,
        &Plan {
            label: "chain17",
            src: &model,
            top: "T1",
            sequences: FULL,
            with_expression: false,
        },
    );
}

#[test]
fn specimen_equilibria_match_opensim_for_every_form() {
    let (Some(model), Some(py)) = (
        common::shared("diagnose-dev/dev-01/specimen.osim"),
        common::opensim_python(),
    ) else {
        return;
    };
    check_model(
        &py,
        &Plan {
            label: "specimen dev-01",
            src: &model,
            top: "lumbar1",
            sequences: FULL,
            with_expression: true,
        },
    );
}

#[test]
fn base_model_equilibria_match_opensim_for_every_form() {
    let Some(py) = common::opensim_python() else {
        return;
    };
    let model = common::repo_root().join("base_model/base.osim");
    check_model(
        &py,
        &Plan {
            label: "base_model",
            src: &model,
            top: "thoracic1",
            sequences: BASE,
            with_expression: true,
        },
    );
}

#[test]
fn cyclist_base_model_equilibria_match_opensim_for_every_form() {
    let (Some(generic), Some(geom), Some(sacrum), Some(py)) = (
        common::shared("data/models/cyclistFullBodyMuscle.osim"),
        common::shared("data/geometry-bodyframe"),
        common::shared("data/geometry/sacrumv.vtp"),
        common::opensim_python(),
    ) else {
        return;
    };
    // the base model built from the cyclist (as tests/base_cyclist.rs does)
    let dir = tempfile::tempdir().unwrap();
    let od = dir.path().join("OUT");
    let o = Command::new(common::bin())
        .arg("base")
        .arg("--generic")
        .arg(&generic)
        .arg("--geometry")
        .arg(&geom)
        .arg("--sacrum")
        .arg(&sacrum)
        .arg("--out")
        .arg(&od)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    check_model(
        &py,
        &Plan {
            label: "cyclist base",
            src: &od.join("base.osim"),
            top: "thoracic1",
            sequences: BASE,
            with_expression: true,
        },
    );
}
