//! `osim-spine simulate MODEL [--fixed BODY] [--no-gravity] --load FILE.toml
//! [--dynamic SECONDS] --out DIR`: static equilibrium (or a forward-dynamics
//! trajectory) of a model under each `[[case]]` of a load file, written as an
//! OpenSim .sto of coordinates and a JSON with body poses and bushing records
//! (one pair of files per case). A load file in the experiment format
//! (`[specimen]`, `[units]`) sets gravity and the fixed body (`--fixed`
//! and `--no-gravity` override), and its `[units]` are those of the
//! `kinematics.csv` written beside (format of `experiment.md`: increments
//! from the unloaded equilibrium, one row per case and joint). One console
//! line per case: converged, largest displacement, stability. Every case is
//! solved before anything is written: a failing case leaves no output.

use crate::calibrate::experiment::{
    parse_cases, parse_experiment_toml, LoadCase, Units, MAX_FILE_BYTES,
};
use crate::calibrate::measure::{pair_increment, Convention};
use crate::osim::Document;
use crate::solver::dynamics::Integrator;
use crate::solver::from_model::ignored_forces;
use crate::solver::output::{sto_string, BodyPose, BushingRecord};
use crate::solver::{BodyIndex, DofIndex, StaticOptions, System, SystemSpec, Workspace};
use anyhow::{bail, Context};
use clap::Args as ClapArgs;
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Arguments of `simulate`.
#[derive(Debug, ClapArgs)]
pub struct Args {
    /// The .osim model.
    pub model: PathBuf,
    /// Body held fixed in its default pose (all coordinates between ground
    /// and it locked). A body already welded to ground needs none.
    #[arg(long, value_name = "BODY")]
    pub fixed: Option<String>,
    /// Switch gravity off.
    #[arg(long)]
    pub no_gravity: bool,
    /// Load file with `[[case]]` tables (experiment format).
    #[arg(long, value_name = "FILE.toml")]
    pub load: PathBuf,
    /// Integrate forward dynamics for this many seconds from the default
    /// pose at rest instead of solving for static equilibrium.
    #[arg(long, value_name = "SECONDS")]
    pub dynamic: Option<f64>,
    /// Time step of the implicit integrator (s).
    #[arg(long, default_value_t = 1e-3, value_name = "SECONDS")]
    pub dt: f64,
    /// Output folder.
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Allow the output to go where an input is (it may be replaced).
    #[arg(long)]
    pub force: bool,
}

#[derive(Debug, Serialize)]
struct SolverInfo {
    mode: &'static str,
    iterations: Option<usize>,
    residual_norm: Option<f64>,
    time_step: Option<f64>,
    duration: Option<f64>,
}

#[derive(Debug, Serialize)]
struct ClampViolation {
    coordinate: String,
    value: f64,
    range: [f64; 2],
}

#[derive(Debug, Serialize)]
struct CaseResult {
    model: String,
    case: LoadCase,
    gravity: [f64; 3],
    fixed_body: Option<String>,
    solver: SolverInfo,
    coordinates: BTreeMap<String, f64>,
    speeds: Option<BTreeMap<String, f64>>,
    bodies: BTreeMap<String, BodyPose>,
    bushings: BTreeMap<String, BushingRecord>,
    clamped_range_violations: Vec<ClampViolation>,
    ignored_forces: Vec<String>,
}

/// File stem for a case id: letters, digits, `.`, `_`, `-`; others become `_`.
fn file_stem(id: &str) -> String {
    id.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || matches!(c, '.' | '_' | '-') {
                c
            } else {
                '_'
            }
        })
        .collect()
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

/// `--dynamic` needs an inertia some mass distribution has: refuse bodies
/// whose principal moments break the triangle inequality.
fn refuse_impossible_inertia(model: &crate::osim::model::Model) -> anyhow::Result<()> {
    for b in &model.bodies {
        if crate::osim::physics::breaks_triangle(&b.inertia) {
            bail!(
                "{}: <Body name=\"{}\"> (line {}): inertia {:?} breaks the triangle inequality of principal moments (I1 + I2 >= I3); forward dynamics refused",
                model.file.display(),
                b.name,
                b.line,
                b.inertia
            );
        }
    }
    Ok(())
}

/// A progress bar over the steps of one dynamic case (on stderr, hidden
/// when stderr is not a terminal).
fn step_bar(case: &str, t: f64, dt: f64) -> indicatif::ProgressBar {
    let steps = crate::solver::dynamics::step_count(t, dt).unwrap_or(0) as u64;
    let bar = crate::util::progress::bar(&format!("case {case}"), steps, "steps", true);
    bar
}

/// The `[specimen]` table of a load file in the experiment format.
struct Specimen {
    fixed_body: String,
    gravity: bool,
    units: Units,
}

/// Read the load file: its cases and, in the experiment format
/// (`[specimen]` and `[units]` tables), the specimen description.
fn read_load_file(path: &Path) -> anyhow::Result<(Vec<LoadCase>, Option<Specimen>)> {
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

/// The solver system of the model with the fixed body and gravity of the
/// command line, else of the `[specimen]` table.
struct Setup {
    model: crate::osim::model::Model,
    sys: System,
    fixed: Option<String>,
    ignored: Vec<String>,
    names: Vec<String>,
}

fn setup(a: &Args, specimen: Option<&Specimen>) -> anyhow::Result<Setup> {
    let doc = Document::read(&a.model)?;
    let model = doc.model()?;
    for w in crate::osim::lint::warnings(&model) {
        crate::errln!("warning: {}: {w}", a.model.display());
    }
    if a.dynamic.is_some() {
        refuse_impossible_inertia(&model)?;
    }
    let mut spec = SystemSpec::from_model(&model)?;
    let ignored = ignored_forces(&model);
    // Gravity off by --no-gravity or `[specimen] gravity = false`.
    if a.no_gravity || specimen.map(|s| !s.gravity).unwrap_or(false) {
        spec.gravity = nalgebra::Vector3::zeros();
    }
    // Fixed body: --fixed, else `[specimen] fixed_body`.
    let fixed_arg = a
        .fixed
        .clone()
        .or_else(|| specimen.map(|s| s.fixed_body.clone()));
    if let Some(b) = &fixed_arg {
        spec = System::with_body_fixed(&spec, b)?;
    }
    let sys = System::new(&spec).with_context(|| format!("{}", a.model.display()))?;
    let fixed = fixed_arg.or_else(|| welded_root(&sys));
    let names = sys.coordinates().iter().map(|c| c.name.clone()).collect();
    Ok(Setup {
        model,
        sys,
        fixed,
        ignored,
        names,
    })
}

/// What one case gave.
struct CaseOut {
    rows: Vec<(f64, Vec<f64>)>,
    q: nalgebra::DVector<f64>,
    u: Option<nalgebra::DVector<f64>>,
    info: SolverInfo,
    stable: Option<bool>,
}

/// Static equilibrium or forward dynamics of one case.
fn solve_case(
    a: &Args,
    st: &Setup,
    case: &LoadCase,
    ws: &mut Workspace,
) -> anyhow::Result<CaseOut> {
    let sys = &st.sys;
    let ctx = || format!("case '{}'", case.id);
    let loads = sys
        .prepare_loads(&case.loads(st.fixed.as_deref())?)
        .with_context(ctx)?;
    let q0 = sys.default_q();
    let Some(t) = a.dynamic else {
        let sol = sys
            .solve_static(&loads, q0.as_slice(), ws, &StaticOptions::default())
            .with_context(|| format!("case '{}': static equilibrium did not converge", case.id))?;
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
    let mut integ = Integrator::new(sys, a.dt);
    let every = ((0.01 / a.dt).round() as usize).max(1);
    let u0 = vec![0.0; sys.n_dofs()];
    let bar = step_bar(&case.id, t, a.dt);
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
                    bar.set_position(s as u64)
                }
            },
        )
        .with_context(ctx)?;
    bar.finish_and_clear();
    let Some(last) = traj.last() else {
        bail!("{}: empty trajectory", ctx())
    };
    let rows = traj
        .iter()
        .map(|s| (s.time, sys.full_coordinates(s.q.as_slice())))
        .collect();
    let info = SolverInfo {
        mode: "dynamic",
        iterations: None,
        residual_norm: None,
        time_step: Some(a.dt),
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

/// The case's JSON record.
fn case_record(
    a: &Args,
    st: &Setup,
    case: &LoadCase,
    out: CaseOut,
    ws: &mut Workspace,
) -> anyhow::Result<CaseResult> {
    let sys = &st.sys;
    let ctx = || format!("case '{}'", case.id);
    let q = out.q.as_slice();
    let bodies = sys.body_poses(q, ws).with_context(ctx)?;
    let bushings = sys
        .bushing_records(q, out.u.as_ref().map(|v| v.as_slice()), ws)
        .with_context(ctx)?;
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
    for v in &clamped_range_violations {
        crate::errln!(
            "warning: case '{}': clamped coordinate '{}' = {} is outside its range [{}, {}]",
            case.id,
            v.coordinate,
            v.value,
            v.range[0],
            v.range[1]
        );
    }
    let g = sys.gravity();
    Ok(CaseResult {
        model: a.model.display().to_string(),
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
fn poses(sys: &System, q: &[f64]) -> anyhow::Result<BTreeMap<String, nalgebra::Isometry3<f64>>> {
    Ok(sys.body_transforms(q)?.into_iter().collect())
}

/// Largest body-origin displacement between two sets of poses (m, body).
fn largest_displacement(
    from: &BTreeMap<String, nalgebra::Isometry3<f64>>,
    to: &BTreeMap<String, nalgebra::Isometry3<f64>>,
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
fn body_pairs(st: &Setup) -> anyhow::Result<Vec<(String, String)>> {
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
fn kinematics_rows(
    id: &str,
    pairs: &[(String, String)],
    p0: &BTreeMap<String, nalgebra::Isometry3<f64>>,
    p1: &BTreeMap<String, nalgebra::Isometry3<f64>>,
    units: &Units,
) -> String {
    let pose = |x: &nalgebra::Isometry3<f64>| crate::solver::Pose {
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

/// One console line per case: converged, largest displacement, stable.
fn case_line(case: &LoadCase, out: &CaseOut, disp: (f64, String), from: &str) -> String {
    let conv = match (out.info.iterations, out.info.residual_norm) {
        (Some(i), Some(r)) => format!("converged in {i} iteration(s) (residual {r:.1e})"),
        _ => format!("integrated for {} s", out.info.duration.unwrap_or(0.0)),
    };
    let stable = match out.stable {
        Some(true) => "stable",
        Some(false) => "UNSTABLE",
        None if out.info.mode == "dynamic" => "stability not assessed (dynamics)",
        None => "stability not assessed (non-conservative load: moment or follower)",
    };
    format!(
        "case {}: {conv}; largest displacement {:.2} mm ({}) from {from}; {stable}",
        case.id,
        disp.0 * 1e3,
        disp.1
    )
}

/// Run `simulate`.
pub fn run(a: Args) -> anyhow::Result<i32> {
    // Never write into a folder that holds an input.
    let protected = crate::util::guard::Protected::default().inputs([&a.model, &a.load]);
    crate::util::guard::check_output_dir(&a.out, &protected, a.force)?;
    check_durations(&a)?;
    let (cases, specimen) = read_load_file(&a.load)?;
    let st = setup(&a, specimen.as_ref())?;
    let g = st.sys.gravity();
    crate::outln!(
        "simulate: gravity {}, fixed body {}{}",
        if g.norm() > 0.0 { "on" } else { "off" },
        st.fixed.as_deref().unwrap_or("none"),
        if specimen.is_some() {
            " (load file [specimen] table)"
        } else {
            ""
        }
    );
    let mut ws = Workspace::new(&st.sys);
    // The unloaded equilibrium: reference of displacements and kinematics.
    let p_default = poses(&st.sys, st.sys.default_q().as_slice())?;
    let p_ref = match st.sys.solve_static(
        &st.sys.prepare_loads(&[])?,
        st.sys.default_q().as_slice(),
        &mut ws,
        &StaticOptions::default(),
    ) {
        Ok(sol) => Some(poses(&st.sys, sol.q.as_slice())?),
        Err(e) => {
            crate::errln!("warning: no unloaded equilibrium ({e}): displacements from the default pose, no kinematics.csv");
            None
        }
    };
    let units = specimen.as_ref().map(|s| s.units).unwrap_or(Units {
        angle: "deg",
        length: "mm",
    });
    let pairs = body_pairs(&st)?;
    let mut kin = String::from("case,upper,lower,rx,ry,rz,tx,ty,tz\n");
    let mut outputs: Vec<(PathBuf, Vec<u8>)> = Vec::new();
    let mut stems = std::collections::BTreeSet::new();
    for case in &cases {
        let stem = file_stem(&case.id);
        if !stems.insert(stem.clone()) {
            bail!(
                "{}: case ids '{}' and another map to the same file name '{stem}'",
                a.load.display(),
                case.id
            );
        }
        let out = solve_case(&a, &st, case, &mut ws)?;
        let p1 = poses(&st.sys, out.q.as_slice())?;
        let (from, from_name) = match &p_ref {
            Some(p) => (p, "the unloaded equilibrium"),
            None => (&p_default, "the default pose"),
        };
        crate::outln!(
            "{}",
            case_line(case, &out, largest_displacement(from, &p1), from_name)
        );
        if let Some(p0) = &p_ref {
            kin.push_str(&kinematics_rows(&case.id, &pairs, p0, &p1, &units));
        }
        let rows = out.rows.clone();
        let result = case_record(&a, &st, case, out, &mut ws)?;
        let json = serde_json::to_string_pretty(&result)?;
        let sto = sto_string(
            &format!("{} case {}", st.model.name, case.id),
            &st.names,
            &rows,
        );
        outputs.push((a.out.join(format!("{stem}.sto")), sto.into_bytes()));
        outputs.push((
            a.out.join(format!("{stem}.json")),
            (json + "\n").into_bytes(),
        ));
    }
    if p_ref.is_some() {
        outputs.push((a.out.join("kinematics.csv"), kin.into_bytes()));
    }
    write_all(&a.out, &outputs)?;
    crate::outln!(
        "simulate: {} case(s) written to {}",
        cases.len(),
        a.out.display()
    );
    Ok(0)
}

/// `--dynamic` and `--dt` must be positive, the step not longer than the run.
fn check_durations(a: &Args) -> anyhow::Result<()> {
    if let Some(t) = a.dynamic {
        if !(t.is_finite() && t > 0.0) {
            bail!("--dynamic: the duration must be a positive number of seconds, got {t}");
        }
        if !(a.dt.is_finite() && a.dt > 0.0 && a.dt <= t) {
            bail!(
                "--dt: the time step must be positive and not longer than the duration, got {}",
                a.dt
            );
        }
        crate::solver::dynamics::step_count(t, a.dt).context("--dynamic")?;
    }
    Ok(())
}

/// The outputs into `dir`, all or nothing (the folder itself is created
/// even when a run writes no file).
fn write_all(dir: &Path, files: &[(PathBuf, Vec<u8>)]) -> anyhow::Result<()> {
    if files.is_empty() {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    crate::util::write_all_or_nothing(files)?;
    Ok(())
}
