//! `osim-spine simulate MODEL [--fixed BODY] [--no-gravity] --load FILE.toml
//! [--dynamic SECONDS] --out DIR`: static equilibrium (or a forward-dynamics
//! trajectory) of a model under each `[[case]]` of a load file, written as an
//! OpenSim .sto of coordinates and a JSON with body poses and bushing records
//! (one pair of files per case). Every case is solved before anything is
//! written: a failing case leaves no output.

use crate::calibrate::experiment::{read_cases, LoadCase};
use crate::osim::Document;
use crate::solver::dynamics::Integrator;
use crate::solver::from_model::ignored_forces;
use crate::solver::output::{sto_string, BodyPose, BushingRecord};
use crate::solver::{StaticOptions, System, SystemSpec, Workspace};
use crate::util::write_atomic;
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
        .filter(|(i, _)| sys.is_welded_to_ground(*i))
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
    let bar = indicatif::ProgressBar::new(steps);
    if let Ok(st) =
        indicatif::ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} steps ({eta} left)")
    {
        bar.set_style(st);
    }
    bar.set_message(format!("case {case}"));
    bar
}

/// Run `simulate`.
pub fn run(a: Args) -> anyhow::Result<i32> {
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
    let doc = Document::read(&a.model)?;
    let model = doc.model()?;
    for w in crate::osim::physics::warnings(&model) {
        crate::errln!("warning: {}: {w}", a.model.display());
    }
    if a.dynamic.is_some() {
        refuse_impossible_inertia(&model)?;
    }
    let mut spec = SystemSpec::from_model(&model)?;
    let ignored = ignored_forces(&model);
    if a.no_gravity {
        spec.gravity = nalgebra::Vector3::zeros();
    }
    if let Some(b) = &a.fixed {
        spec = System::with_body_fixed(&spec, b)?;
    }
    let sys = System::new(&spec).with_context(|| format!("{}", a.model.display()))?;
    let fixed = a.fixed.clone().or_else(|| welded_root(&sys));
    let cases = read_cases(&a.load)?;
    let mut ws = Workspace::new(&sys);
    let q0 = sys.default_q();
    let names: Vec<String> = sys.coordinates().iter().map(|c| c.name.clone()).collect();
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
        let ctx = || format!("case '{}'", case.id);
        let loads = sys
            .prepare_loads(&case.loads(fixed.as_deref())?)
            .with_context(ctx)?;
        let (rows, q, u, info) = match a.dynamic {
            None => {
                let sol = sys
                    .solve_static(&loads, q0.as_slice(), &mut ws, &StaticOptions::default())
                    .with_context(ctx)?;
                let full = sys.full_coordinates(sol.q.as_slice());
                (
                    vec![(0.0, full)],
                    sol.q.clone(),
                    None,
                    SolverInfo {
                        mode: "static",
                        iterations: Some(sol.iterations),
                        residual_norm: Some(sol.residual_norm),
                        time_step: None,
                        duration: None,
                    },
                )
            }
            Some(t) => {
                let mut integ = Integrator::new(&sys, a.dt);
                let every = ((0.01 / a.dt).round() as usize).max(1);
                let u0 = vec![0.0; sys.n_dofs()];
                let bar = step_bar(&case.id, t, a.dt);
                let traj = integ
                    .run_observed(
                        &sys,
                        &loads,
                        &mut ws,
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
                (
                    rows,
                    last.q.clone(),
                    Some(last.u.clone()),
                    SolverInfo {
                        mode: "dynamic",
                        iterations: None,
                        residual_norm: None,
                        time_step: Some(a.dt),
                        duration: Some(t),
                    },
                )
            }
        };
        let bodies = sys.body_poses(q.as_slice(), &mut ws).with_context(ctx)?;
        let bushings = sys
            .bushing_records(q.as_slice(), u.as_ref().map(|v| v.as_slice()), &mut ws)
            .with_context(ctx)?;
        let full = sys.full_coordinates(q.as_slice());
        let coordinates: BTreeMap<String, f64> =
            names.iter().cloned().zip(full.iter().copied()).collect();
        let speeds = u.as_ref().map(|u| {
            (0..sys.n_dofs())
                .map(|i| (sys.dof_name(i).to_string(), u[i]))
                .collect()
        });
        let clamped_range_violations = sys
            .clamp_violations(q.as_slice())
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
        let result = CaseResult {
            model: a.model.display().to_string(),
            case: case.clone(),
            gravity: [g.x, g.y, g.z],
            fixed_body: fixed.clone(),
            solver: info,
            coordinates,
            speeds,
            bodies,
            bushings,
            clamped_range_violations,
            ignored_forces: ignored.clone(),
        };
        let json = serde_json::to_string_pretty(&result)?;
        let sto = sto_string(&format!("{} case {}", model.name, case.id), &names, &rows);
        outputs.push((a.out.join(format!("{stem}.sto")), sto.into_bytes()));
        outputs.push((
            a.out.join(format!("{stem}.json")),
            (json + "\n").into_bytes(),
        ));
    }
    write_all(&a.out, &outputs)?;
    crate::errln!(
        "simulate: {} case(s) written to {}",
        cases.len(),
        a.out.display()
    );
    Ok(0)
}

fn write_all(dir: &Path, files: &[(PathBuf, Vec<u8>)]) -> anyhow::Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    for (p, bytes) in files {
        write_atomic(p, bytes)?;
    }
    Ok(())
}
