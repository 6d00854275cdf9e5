//! Load cases solved on a model (`osim-spine simulate`): static equilibrium
//! or a forward-dynamics trajectory under each `[[case]]` of a load file,
//! with what each case gave (coordinates, body poses, bushing records) and
//! the experiment-format kinematics of every joint between two bodies.
//!
//! Pinocchio's split: [`setup`] builds the immutable solver system once,
//! [`solve_case`] runs one case in a caller's [`Workspace`], and
//! [`case_record`] / [`kinematics_rows`] turn the result into what is
//! written. Nothing here prints or writes a file.

use crate::calibrate::experiment::{
    parse_cases, parse_experiment_toml, LoadCase, Units, MAX_FILE_BYTES,
};
use crate::calibrate::measure::{pair_increment, Convention};
use crate::error::{Error, Result};
use crate::osim::model::Model;
use crate::osim::Document;
use crate::solver::dynamics::Integrator;
use crate::solver::from_model::ignored_forces;
use crate::solver::output::{BodyPose, BushingRecord};
use crate::solver::{BodyIndex, DofIndex, StaticOptions, System, SystemSpec, Workspace};
use nalgebra::{DVector, Isometry3};
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::Path;

/// How the cases are solved: the command line's choices, which override a
/// load file's `[specimen]` table.
#[derive(Debug, Clone, Default)]
pub struct SimulateOptions {
    /// Body held fixed in its default pose (else the `[specimen]` one).
    pub fixed: Option<String>,
    /// Gravity off (else as the `[specimen]` table says; on without one).
    pub no_gravity: bool,
    /// Integrate forward dynamics for this many seconds instead of solving
    /// for static equilibrium.
    pub dynamic: Option<f64>,
    /// Time step of the implicit integrator (s).
    pub dt: f64,
}

/// How one case was solved.
#[derive(Debug, Serialize)]
pub struct SolverInfo {
    /// `static` or `dynamic`.
    pub mode: &'static str,
    /// Newton iterations (static).
    pub iterations: Option<usize>,
    /// Final residual norm (static).
    pub residual_norm: Option<f64>,
    /// Integrator step (dynamic, s).
    pub time_step: Option<f64>,
    /// Integrated duration (dynamic, s).
    pub duration: Option<f64>,
}

/// A clamped coordinate outside its range at the solution.
#[derive(Debug, Serialize)]
pub struct ClampViolation {
    /// The coordinate's name.
    pub coordinate: String,
    /// Its value (model units: rad or m).
    pub value: f64,
    /// Its range.
    pub range: [f64; 2],
}

/// The JSON record of one case.
#[derive(Debug, Serialize)]
pub struct CaseResult {
    /// The model file as the user named it.
    pub model: String,
    /// The case as read.
    pub case: LoadCase,
    /// Gravity used (m/s^2, ground frame).
    pub gravity: [f64; 3],
    /// The body held fixed, if any.
    pub fixed_body: Option<String>,
    /// How the case was solved.
    pub solver: SolverInfo,
    /// Every coordinate at the solution (rad or m).
    pub coordinates: BTreeMap<String, f64>,
    /// Speeds of the free coordinates at the end (dynamic only).
    pub speeds: Option<BTreeMap<String, f64>>,
    /// Body poses in ground.
    pub bodies: BTreeMap<String, BodyPose>,
    /// Bushing deflections and forces.
    pub bushings: BTreeMap<String, BushingRecord>,
    /// Clamped coordinates found outside their ranges.
    pub clamped_range_violations: Vec<ClampViolation>,
    /// Forces of the model the solver does not apply.
    pub ignored_forces: Vec<String>,
}

/// The `[specimen]` table of a load file in the experiment format.
#[derive(Debug, Clone)]
pub struct Specimen {
    /// The body the experiment holds.
    pub fixed_body: String,
    /// Whether gravity acts.
    pub gravity: bool,
    /// Units of the measured kinematics.
    pub units: Units,
}

/// Read a load file: its cases and, in the experiment format (`[specimen]`
/// and `[units]` tables), the specimen description.
pub fn read_load_file(path: &Path) -> Result<(Vec<LoadCase>, Option<Specimen>)> {
    let text = crate::util::read_text_capped(path, MAX_FILE_BYTES, "load files")?;
    let has_specimen = text
        .parse::<toml::Table>()
        .map(|t| t.contains_key("specimen"))
        .unwrap_or(false);
    if !has_specimen {
        return Ok((parse_cases(&text, path)?, None));
    }
    let e = parse_experiment_toml(&text, path)?;
    let sp = Specimen {
        fixed_body: e.fixed_body,
        gravity: e.gravity,
        units: e.units,
    };
    Ok((e.cases, Some(sp)))
}

/// The solver system of a model with its fixed body and gravity: the
/// model, never changed, for every case.
pub struct Setup {
    /// The model read.
    pub model: Model,
    /// Its solver system.
    pub sys: System,
    /// The body held fixed (asked for, or the one welded to ground).
    pub fixed: Option<String>,
    /// Forces the solver does not apply.
    pub ignored: Vec<String>,
    /// Every coordinate's name, in the system's full order.
    pub names: Vec<String>,
    /// The model's lint warnings.
    pub warnings: Vec<String>,
}

/// The solver system of `doc` with the fixed body and gravity of `opts`,
/// else of the `[specimen]` table.
pub fn setup(doc: &Document, opts: &SimulateOptions, specimen: Option<&Specimen>) -> Result<Setup> {
    let model = doc.model()?;
    let warnings = crate::osim::lint::warnings(&model);
    // Forward dynamics needs inertias some mass distribution has.
    if opts.dynamic.is_some() {
        refuse_impossible_inertia(&model)?;
    }
    let mut spec = SystemSpec::from_model(&model)?;
    let ignored = ignored_forces(&model);
    // Gravity off by the options or `[specimen] gravity = false`.
    if opts.no_gravity || specimen.map(|s| !s.gravity).unwrap_or(false) {
        spec.gravity = nalgebra::Vector3::zeros();
    }
    // Fixed body: the options', else `[specimen] fixed_body`.
    let fixed_arg = opts
        .fixed
        .clone()
        .or_else(|| specimen.map(|s| s.fixed_body.clone()));
    if let Some(b) = &fixed_arg {
        spec = System::with_body_fixed(&spec, b)?;
    }
    let sys = System::new(&spec).map_err(|e| within(e, &model.file.display().to_string()))?;
    let fixed = fixed_arg.or_else(|| welded_root(&sys));
    let names = sys.coordinates().iter().map(|c| c.name.clone()).collect();
    Ok(Setup {
        model,
        sys,
        fixed,
        ignored,
        names,
        warnings: warnings.into_iter().map(|w| w.to_string()).collect(),
    })
}

/// `context: ` put before an error's own context, as a console reads it.
fn within(e: Error, context: &str) -> Error {
    match e {
        Error::Invalid {
            context: c,
            message,
        } => Error::invalid(format!("{context}: {c}"), message),
        Error::Numerical {
            context: c,
            message,
        } => Error::numerical(format!("{context}: {c}"), message),
        Error::Solver { context: c, error } => Error::solver(format!("{context}: {c}"), error),
        other => Error::invalid(context, other.to_string()),
    }
}

/// The body welded to ground (root joint without free coordinates), if unique.
fn welded_root(sys: &System) -> Option<String> {
    let roots: Vec<&str> = sys
        .body_names()
        .enumerate()
        .filter(|(i, _)| sys.is_welded_to_ground(BodyIndex(*i)))
        .map(|(_, n)| n)
        .collect();
    match roots.as_slice() {
        [one] => Some(one.to_string()),
        _ => None,
    }
}

/// Refuse bodies whose principal moments break the triangle inequality
/// (no mass distribution has them).
fn refuse_impossible_inertia(model: &Model) -> Result<()> {
    for b in &model.bodies {
        if crate::osim::physics::breaks_triangle(&b.inertia) {
            return Err(Error::invalid(
                format!(
                    "{}: <Body name=\"{}\"> (line {})",
                    model.file.display(),
                    b.name,
                    b.line
                ),
                format!(
                    "inertia {:?} breaks the triangle inequality of principal moments (I1 + I2 >= I3); forward dynamics refused",
                    b.inertia
                ),
            ));
        }
    }
    Ok(())
}

/// What one case gave.
pub struct CaseOut {
    /// Rows of the trajectory (time, every coordinate); one row for statics.
    pub rows: Vec<(f64, Vec<f64>)>,
    /// Free coordinates at the end.
    pub q: DVector<f64>,
    /// Free speeds at the end (dynamic only).
    pub u: Option<DVector<f64>>,
    /// How it was solved.
    pub info: SolverInfo,
    /// Stability of the static equilibrium, where assessed.
    pub stable: Option<bool>,
}

/// Static equilibrium or forward dynamics of one case; `progress` is told
/// the step reached every 1000 steps of a dynamic run.
pub fn solve_case(
    st: &Setup,
    case: &LoadCase,
    opts: &SimulateOptions,
    ws: &mut Workspace,
    progress: &mut dyn FnMut(usize),
) -> Result<CaseOut> {
    let sys = &st.sys;
    let ctx = format!("case '{}'", case.id);
    let loads = sys
        .prepare_loads(&case.loads(st.fixed.as_deref())?)
        .map_err(|e| within(e, &ctx))?;
    let q0 = sys.default_q();
    let Some(t) = opts.dynamic else {
        let sol = sys
            .solve_static(&loads, q0.as_slice(), ws, &StaticOptions::default())
            .map_err(|e| within(e, &format!("{ctx}: static equilibrium did not converge")))?;
        let full = sys.full_coordinates(sol.q.as_slice());
        let info = SolverInfo {
            mode: "static",
            iterations: Some(sol.iterations),
            residual_norm: Some(sol.residual_norm),
            time_step: None,
            duration: None,
        };
        return Ok(CaseOut {
            rows: vec![(0.0, full)],
            q: sol.q,
            u: None,
            info,
            stable: sol.stable,
        });
    };
    let mut integ = Integrator::new(sys, opts.dt);
    let every = ((0.01 / opts.dt).round() as usize).max(1);
    let u0 = vec![0.0; sys.n_dofs()];
    let traj = integ
        .run_observed(
            sys,
            &loads,
            ws,
            (q0.as_slice(), &u0),
            t,
            every,
            &mut |s, _| {
                if s % 1000 == 0 {
                    progress(s)
                }
            },
        )
        .map_err(|e| within(e, &ctx))?;
    let Some(last) = traj.last() else {
        return Err(Error::numerical(ctx, "empty trajectory"));
    };
    let rows = traj
        .iter()
        .map(|s| (s.time, sys.full_coordinates(s.q.as_slice())))
        .collect();
    let info = SolverInfo {
        mode: "dynamic",
        iterations: None,
        residual_norm: None,
        time_step: Some(opts.dt),
        duration: Some(t),
    };
    Ok(CaseOut {
        rows,
        q: last.q.clone(),
        u: Some(last.u.clone()),
        info,
        stable: None,
    })
}

/// The case's JSON record; `model` names the model file as the user did.
pub fn case_record(
    model: &str,
    st: &Setup,
    case: &LoadCase,
    out: CaseOut,
    ws: &mut Workspace,
) -> Result<CaseResult> {
    let sys = &st.sys;
    let ctx = format!("case '{}'", case.id);
    let q = out.q.as_slice();
    let bodies = sys.body_poses(q, ws).map_err(|e| within(e, &ctx))?;
    let bushings = sys
        .bushing_records(q, out.u.as_ref().map(|v| v.as_slice()), ws)
        .map_err(|e| within(e, &ctx))?;
    let full = sys.full_coordinates(q);
    let coordinates = st.names.iter().cloned().zip(full.iter().copied()).collect();
    let speeds = out.u.as_ref().map(|u| {
        (0..sys.n_dofs())
            .map(|i| (sys.dof_name(DofIndex(i)).to_string(), u[i]))
            .collect()
    });
    let clamped_range_violations = sys
        .clamp_violations(q)
        .into_iter()
        .map(|(coordinate, value, range)| ClampViolation {
            coordinate,
            value,
            range,
        })
        .collect::<Vec<_>>();
    let g = sys.gravity();
    Ok(CaseResult {
        model: model.to_string(),
        case: case.clone(),
        gravity: [g.x, g.y, g.z],
        fixed_body: st.fixed.clone(),
        solver: out.info,
        coordinates,
        speeds,
        bodies,
        bushings,
        clamped_range_violations,
        ignored_forces: st.ignored.clone(),
    })
}

/// Body poses in ground (name order of the system) at free dofs `q`.
pub fn poses(sys: &System, q: &[f64]) -> Result<BTreeMap<String, Isometry3<f64>>> {
    Ok(sys.body_transforms(q)?.into_iter().collect())
}

/// Largest body-origin displacement between two sets of poses (m, body).
pub fn largest_displacement(
    from: &BTreeMap<String, Isometry3<f64>>,
    to: &BTreeMap<String, Isometry3<f64>>,
) -> (f64, String) {
    let mut best = (0.0, String::new());
    for (n, x) in to {
        if let Some(x0) = from.get(n) {
            let d = (x.translation.vector - x0.translation.vector).norm();
            if d > best.0 {
                best = (d, n.clone());
            }
        }
    }
    best
}

/// Adjacent (upper, lower) body pairs: every joint between two bodies.
pub fn body_pairs(st: &Setup) -> Result<Vec<(String, String)>> {
    let known: std::collections::BTreeSet<&str> = st.sys.body_names().collect();
    Ok(st
        .model
        .joint_frames()?
        .into_iter()
        .filter(|j| known.contains(j.child_body.as_str()) && known.contains(j.parent_body.as_str()))
        .map(|j| (j.child_body, j.parent_body))
        .collect())
}

/// `kinematics.csv` rows of one case (format of `experiment.md`): the
/// change each pair's relative pose underwent from the unloaded
/// equilibrium `p0` to the loaded one `p1`, in `units`.
pub fn kinematics_rows(
    id: &str,
    pairs: &[(String, String)],
    p0: &BTreeMap<String, Isometry3<f64>>,
    p1: &BTreeMap<String, Isometry3<f64>>,
    units: &Units,
) -> String {
    let pose = |x: &Isometry3<f64>| crate::solver::Pose {
        r: x.rotation.to_rotation_matrix().into_inner(),
        p: x.translation.vector,
    };
    let mut out = String::new();
    for (u, l) in pairs {
        let (Some(u0), Some(l0), Some(u1), Some(l1)) = (p0.get(u), p0.get(l), p1.get(u), p1.get(l))
        else {
            continue;
        };
        let inc = pair_increment(
            Convention::Composed,
            &pose(u0),
            &pose(l0),
            &pose(u1),
            &pose(l1),
        );
        let cells: Vec<String> = (0..6)
            .map(|d| format!("{}", inc[d] * units.from_si(d)))
            .collect();
        out.push_str(&format!("{id},{u},{l},{}\n", cells.join(",")));
    }
    out
}
