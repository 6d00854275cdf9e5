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

use crate::calibrate::experiment::{LoadCase, Units};
use crate::osim::Document;
use crate::simulate::{
    body_pairs, case_record, kinematics_rows, largest_displacement, poses, read_load_file, setup,
    solve_case, CaseOut, CaseResult, Setup, SimulateOptions,
};
use crate::solver::output::sto_string;
use crate::solver::{StaticOptions, Workspace};
use anyhow::{bail, Context};
use clap::Args as ClapArgs;
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

/// A progress bar over the steps of one dynamic case (on stderr, hidden
/// when stderr is not a terminal).
fn step_bar(case: &str, t: f64, dt: f64) -> crate::util::progress::Bar {
    let steps = crate::solver::dynamics::step_count(t, dt).unwrap_or(0) as u64;
    crate::util::progress::bar(&format!("case {case}"), steps, "steps", true)
}

/// The library's options from the command line.
fn options(a: &Args) -> SimulateOptions {
    SimulateOptions {
        fixed: a.fixed.clone(),
        no_gravity: a.no_gravity,
        dynamic: a.dynamic,
        dt: a.dt,
    }
}

/// One case solved, with a progress bar over a dynamic run's steps.
fn solve_with_bar(
    st: &Setup,
    case: &LoadCase,
    opts: &SimulateOptions,
    ws: &mut Workspace,
) -> anyhow::Result<CaseOut> {
    let bar = opts.dynamic.map(|t| step_bar(&case.id, t, opts.dt));
    let out = solve_case(st, case, opts, ws, &mut |s| {
        if let Some(b) = &bar {
            b.set_position(s as u64)
        }
    })?;
    if let Some(b) = bar {
        b.finish_and_clear();
    }
    Ok(out)
}

/// The record of one case, with a warning per clamped coordinate out of range.
fn record(
    a: &Args,
    st: &Setup,
    case: &LoadCase,
    out: CaseOut,
    ws: &mut Workspace,
) -> anyhow::Result<CaseResult> {
    let result = case_record(&a.model.display().to_string(), st, case, out, ws)?;
    for v in &result.clamped_range_violations {
        crate::errln!(
            "warning: case '{}': clamped coordinate '{}' = {} is outside its range [{}, {}]",
            case.id,
            v.coordinate,
            v.value,
            v.range[0],
            v.range[1]
        );
    }
    Ok(result)
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
    let opts = options(&a);
    let st = setup(&Document::read(&a.model)?, &opts, specimen.as_ref())?;
    for w in &st.warnings {
        crate::errln!("warning: {}: {w}", a.model.display());
    }
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
        let out = solve_with_bar(&st, case, &opts, &mut ws)?;
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
        let result = record(&a, &st, case, out, &mut ws)?;
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
