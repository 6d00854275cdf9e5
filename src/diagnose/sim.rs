//! The experiment as the diagnoser simulates it: the nominal system, its
//! intervertebral levels, the load cases and the measured cells, and the
//! predicted increments of a model variant (any [`System`] built from the
//! nominal one), with warm starts so repeated evaluations are cheap.

use crate::calibrate::experiment::Experiment;
use crate::calibrate::family::{find_levels, SystemLevel};
use crate::calibrate::measure::{pair_increment, Convention};
use crate::error::{Error, Result};
use crate::solver::kinematics;
use crate::solver::workspace::KinBuf;
use crate::solver::{BodyIndex, BushingModel, Load, LoadSet, StaticOptions, System, Workspace};
use nalgebra::{DVector, Isometry3};

/// One measured value: a (row, DoF) of `kinematics.csv`.
#[derive(Debug, Clone, PartialEq)]
pub struct Cell {
    /// Row index in the experiment.
    pub row: usize,
    /// Case index.
    pub case: usize,
    /// Level index (into [`Sim::levels`]).
    pub level: usize,
    /// DoF 0..6 (rx .. tz).
    pub dof: usize,
    /// Measured value in report units (deg for rotations, mm for translations).
    pub measured: f64,
    /// Stated SD in report units (the cell's `sd_*` value, else the
    /// `[measurement]` one; divided by `sqrt(n_specimens)` for means, the
    /// standard error of the mean); `None` when the file states none.
    pub sd: Option<f64>,
}

/// Report units: degrees for rotations, millimetres for translations.
pub fn to_report_units(dof: usize, si: f64) -> f64 {
    if dof < 3 {
        si.to_degrees()
    } else {
        si * 1000.0
    }
}

/// The simulated experiment.
#[derive(Debug, Clone)]
pub struct Sim {
    /// Nominal system (sacrum or `fixed_body` welded to ground).
    pub base: System,
    /// Intervertebral levels between the fixed and the loaded bodies, in
    /// bushing order.
    pub levels: Vec<SystemLevel>,
    /// Nominal law of each level.
    pub nominal: Vec<BushingModel>,
    /// Nominal linear stiffness `(rx .. tz)` of each level.
    pub k_nominal: Vec<[f64; 6]>,
    /// Nominal bushing frames of each level.
    pub frames: Vec<(Isometry3<f64>, Isometry3<f64>)>,
    /// Loads of every case.
    pub loads: Vec<Vec<Load>>,
    /// The loads resolved on the nominal system. Follower-load guide points
    /// are fixed in the bodies where the nominal joint centres are: the
    /// rig places its cable guides on the anatomy, so a misplaced joint
    /// centre (joint_pose_error) does not carry the guides with it.
    pub prepared: Vec<LoadSet>,
    /// `(upper, lower)` body indices of each row.
    pub row_bodies: Vec<(usize, usize)>,
    /// Rows of each case.
    pub case_rows: Vec<Vec<usize>>,
    /// All measured cells, row by row, DoF order.
    pub cells: Vec<Cell>,
    /// Each case's dominant moment axis (0 X, 1 Y, 2 Z) and its sign
    /// (`None` without a moment).
    pub case_dir: Vec<Option<(usize, i8)>>,
    /// Each level's position along the spine: the number of joints between
    /// it and the fixed body (0 for the level next to it).
    pub position: Vec<f64>,
    /// For each rotational axis (X, Y, Z of ground), the spread over the
    /// levels of the angle (deg) between it and the level's own joint axis
    /// at the unloaded default pose: a lordotic specimen tilts its levels'
    /// X and Y axes differently about Z (see [`TILT_TOL_DEG`]).
    pub tilt_spread: [f64; 3],
}

/// Tilt spread (deg) above which a level pattern of the primary rotations
/// about a ground axis cannot be told from a coupling: a coupling between
/// two of a level's own axes changes the compliance about a ground axis
/// tilted by `a` from them by an amount proportional to `sin 2a`, so
/// levels tilted differently show a level pattern with no level-dependent
/// stiffness at all.
pub const TILT_TOL_DEG: f64 = 5.0;

/// Warm starts: the last equilibria (unloaded, and per case).
#[derive(Debug, Clone)]
pub struct Warm {
    q0: DVector<f64>,
    q1: Vec<DVector<f64>>,
}

impl Sim {
    /// Build from an experiment. Every row's pair must be a level (adjacent
    /// bodies joined by a linear bushing on the load path).
    pub fn new(exp: &Experiment) -> Result<Sim> {
        let ctx = format!("experiment {}", exp.dir.display());
        let base = System::new(&exp.spec)?;
        let fixed = base.body_index(&exp.fixed_body).ok_or_else(|| {
            Error::invalid(
                ctx.clone(),
                format!("fixed body '{}' is not in the model", exp.fixed_body),
            )
        })?;
        let mut loaded = Vec::new();
        for c in &exp.cases {
            let b = base.body_index(&c.body).ok_or_else(|| {
                Error::invalid(
                    format!("{ctx}: case '{}'", c.id),
                    format!("body '{}' is not in the model", c.body),
                )
            })?;
            if !loaded.contains(&b) {
                loaded.push(b);
            }
        }
        let levels = find_levels(&base, fixed, &loaded);
        if levels.is_empty() {
            return Err(Error::invalid(
                ctx,
                "no intervertebral level (a bushing between adjacent bodies) lies between the fixed body and the loaded bodies",
            ));
        }
        // every level's nominal linear law, stiffness and joint frames
        let (nominal, k_nominal, frames) = nominal_levels(&base, &levels, &ctx)?;
        // every case's loads, resolved on the nominal system
        let (loads, prepared) = case_loads(exp, &base, &ctx)?;
        let mut row_bodies = Vec::new();
        let mut case_rows = vec![Vec::new(); exp.cases.len()];
        let mut cells = Vec::new();
        for (ri, r) in exp.rows.iter().enumerate() {
            let here = || {
                format!(
                    "{}: line {}",
                    exp.dir.join("kinematics.csv").display(),
                    r.line
                )
            };
            let u = base.body_index(&r.upper).ok_or_else(|| {
                Error::invalid(here(), format!("body '{}' is not in the model", r.upper))
            })?;
            let lo = base.body_index(&r.lower).ok_or_else(|| {
                Error::invalid(here(), format!("body '{}' is not in the model", r.lower))
            })?;
            let li = levels
                .iter()
                .position(|l| l.upper == u && l.lower == lo)
                .ok_or_else(|| {
                    Error::invalid(
                        here(),
                        format!(
                            "pair {}/{} is not an intervertebral level on the load path (levels: {})",
                            r.upper,
                            r.lower,
                            levels.iter().map(|l| format!("{}/{}", l.level.upper_body, l.level.lower_body)).collect::<Vec<_>>().join(", ")
                        ),
                    )
                })?;
            row_bodies.push((u.0, lo.0));
            // cells that are means over n specimens: the stated SD is the
            // between-specimen one, the mean's standard error is SD / sqrt(n)
            let se_divisor = (exp.measurement.n_specimens.unwrap_or(1).max(1) as f64).sqrt();
            if let Some(v) = case_rows.get_mut(r.case) {
                v.push(ri);
            }
            for d in 0..6 {
                if let Some(m) = r.values[d] {
                    cells.push(Cell {
                        row: ri,
                        case: r.case,
                        level: li,
                        dof: d,
                        measured: to_report_units(d, m),
                        sd: r
                            .stated_sd(d, &exp.measurement)
                            .map(|s| to_report_units(d, s) / se_divisor),
                    });
                }
            }
        }
        if cells.is_empty() {
            return Err(Error::invalid(
                ctx,
                "kinematics.csv has no measured value: every rx .. tz cell is empty",
            ));
        }
        let position = level_positions(&base, fixed, &levels);
        let tilt_spread = axis_tilt_spread(&base, &levels);
        let case_dir = exp
            .cases
            .iter()
            .map(|c| {
                let i = super::design::CaseInfo::of(c);
                i.axis.map(|a| (a, i.sign))
            })
            .collect();
        Ok(Sim {
            base,
            levels,
            nominal,
            k_nominal,
            frames,
            loads,
            prepared,
            row_bodies,
            case_rows,
            cells,
            case_dir,
            position,
            tilt_spread,
        })
    }

    /// The rotational DoFs whose level pattern a table can attribute to a
    /// stiffness trend: measured as a primary rotation, and the levels'
    /// own axes about them not tilted differently ([`TILT_TOL_DEG`]).
    pub fn trend_dofs(&self) -> Vec<usize> {
        let pd = self.primary_dofs();
        (0..3)
            .filter(|&d| pd[d].0 && self.tilt_spread[d] <= TILT_TOL_DEG)
            .collect()
    }

    /// The rotational DoFs (0 rx, 1 ry, 2 rz) measured as the primary
    /// rotation of some case (the rotation about its load axis), and for
    /// each whether both directions of the load were measured.
    pub fn primary_dofs(&self) -> [(bool, bool); 3] {
        let mut signs = [[false; 2]; 3];
        for c in &self.cells {
            if let Some(Some((a, s))) = self.case_dir.get(c.case) {
                if *a == c.dof {
                    signs[*a][usize::from(*s > 0)] = true;
                }
            }
        }
        signs.map(|s| (s[0] || s[1], s[0] && s[1]))
    }

    /// Fresh warm starts (default pose).
    pub fn warm(&self) -> Warm {
        let q = self.base.default_q();
        Warm {
            q1: vec![q.clone(); self.loads.len()],
            q0: q,
        }
    }

    /// Predicted increments `(rx..tz)` in report units (deg, mm) of every
    /// row of the cases `cases` (other rows stay zero), for the variant
    /// `sys`. `warm` is used and updated.
    pub fn predict(&self, sys: &System, cases: &[usize], warm: &mut Warm) -> Result<Vec<[f64; 6]>> {
        let mut ws = Workspace::new(sys);
        let mut kb = KinBuf::<f64>::new(sys);
        let opts = StaticOptions::default();
        let solve = |loads: &LoadSet, start: &DVector<f64>, ws: &mut Workspace| match sys
            .solve_static(loads, start.as_slice(), ws, &opts)
        {
            Ok(s) => Ok(s.q),
            Err(_) => sys
                .solve_static(loads, sys.default_q().as_slice(), ws, &opts)
                .map(|s| s.q),
        };
        let q0 = solve(&LoadSet::empty(), &warm.q0, &mut ws)
            .map_err(|e| Error::numerical("unloaded equilibrium", e.to_string()))?;
        kb.q.copy_from_slice(q0.as_slice());
        kinematics::forward(sys, &mut kb);
        let poses0 = kb.x_gb.clone();
        warm.q0 = q0;
        let mut out = vec![[0.0; 6]; self.row_bodies.len()];
        for &ci in cases {
            let (Some(ls), Some(rows), Some(start)) = (
                self.prepared.get(ci),
                self.case_rows.get(ci),
                warm.q1.get(ci),
            ) else {
                continue;
            };
            let q1 = solve(ls, start, &mut ws).map_err(|e| {
                Error::numerical(format!("case {ci}"), format!("no equilibrium: {e}"))
            })?;
            kb.q.copy_from_slice(q1.as_slice());
            kinematics::forward(sys, &mut kb);
            for &ri in rows {
                let (u, l) = self.row_bodies[ri];
                let inc = pair_increment(
                    Convention::Composed,
                    &poses0[u],
                    &poses0[l],
                    &kb.x_gb[u],
                    &kb.x_gb[l],
                );
                out[ri] = std::array::from_fn(|d| to_report_units(d, inc[d]));
            }
            warm.q1[ci] = q1;
        }
        Ok(out)
    }
}

/// Number of joints on the tree path between bodies `a` and `b`.
fn tree_distance(sys: &System, a: BodyIndex, b: BodyIndex) -> usize {
    let mut up_a = Vec::new();
    let mut cur = Some(a);
    while let Some(c) = cur {
        up_a.push(c);
        cur = sys.parent_of(c);
    }
    let mut cur = Some(b);
    let mut db = 0;
    while let Some(c) = cur {
        if let Some(da) = up_a.iter().position(|x| *x == c) {
            return da + db;
        }
        db += 1;
        cur = sys.parent_of(c);
    }
    up_a.len() + db
}

/// The spread over the levels of the angle (deg) between each ground axis
/// and the level's own joint axis at the default pose (the first bushing
/// frame carried by its body).
fn axis_tilt_spread(sys: &System, levels: &[SystemLevel]) -> [f64; 3] {
    let mut kb = KinBuf::<f64>::new(sys);
    let q = sys.default_q();
    kb.q.copy_from_slice(q.as_slice());
    kinematics::forward(sys, &mut kb);
    let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
    for l in levels {
        let (Some((x1, _)), Some((Some(b1), _))) =
            (sys.bushing_frames(l.bushing), sys.bushing_bodies(l.bushing))
        else {
            continue;
        };
        let Some(pose) = kb.x_gb.get(b1.0) else {
            continue;
        };
        let r = pose.r * x1.rotation.to_rotation_matrix().into_inner();
        for d in 0..3 {
            let t = r[(d, d)].abs().min(1.0).acos().to_degrees();
            lo[d] = lo[d].min(t);
            hi[d] = hi[d].max(t);
        }
    }
    std::array::from_fn(|d| if hi[d] >= lo[d] { hi[d] - lo[d] } else { 0.0 })
}

/// Each level's position along the spine from the fixed body (the joints
/// between its nearer body and the fixed one).
fn level_positions(sys: &System, fixed: BodyIndex, levels: &[SystemLevel]) -> Vec<f64> {
    levels
        .iter()
        .map(|l| {
            let d = tree_distance(sys, fixed, l.upper).min(tree_distance(sys, fixed, l.lower));
            d as f64
        })
        .collect()
}

/// The loads of every case of `exp`, and the same resolved on `base`.
fn case_loads(
    exp: &Experiment,
    base: &System,
    ctx: &str,
) -> Result<(Vec<Vec<Load>>, Vec<LoadSet>)> {
    let loads = exp
        .cases
        .iter()
        .map(|c| c.loads(Some(&exp.fixed_body)))
        .collect::<Result<Vec<_>>>()?;
    let prepared = exp
        .cases
        .iter()
        .zip(&loads)
        .map(|(c, l)| {
            base.prepare_loads(l)
                .map_err(|e| Error::invalid(format!("{ctx}: case '{}'", c.id), e.to_string()))
        })
        .collect::<Result<Vec<_>>>()?;
    Ok((loads, prepared))
}

/// Every level's nominal law (linear, uncoupled, positive, on its joint's
/// frames: the baseline form), its six stiffnesses and its two frames.
#[allow(clippy::type_complexity)]
fn nominal_levels(
    base: &System,
    levels: &[SystemLevel],
    ctx: &str,
) -> Result<(
    Vec<BushingModel>,
    Vec<[f64; 6]>,
    Vec<(Isometry3<f64>, Isometry3<f64>)>,
)> {
    let mut nominal = Vec::new();
    let mut k_nominal = Vec::new();
    let mut frames = Vec::new();
    for l in levels {
        let m = base
            .bushing_model(l.bushing)
            .cloned()
            .ok_or_else(|| Error::invalid(ctx.to_string(), "bushing index out of range"))?;
        let k = match &m {
            BushingModel::Linear {
                rot_stiffness: r,
                trans_stiffness: t,
                ..
            } => [r.x, r.y, r.z, t.x, t.y, t.z],
            _ => return Err(Error::invalid(
                format!("{ctx}: level {}", l.level.name),
                "the nominal model must have linear, uncoupled BushingForces (the baseline form)",
            )),
        };
        if !k.iter().all(|v| v.is_finite() && *v > 0.0) {
            return Err(Error::invalid(
                format!("{ctx}: level {}", l.level.name),
                format!("nominal stiffness must be positive, got {k:?}"),
            ));
        }
        if !base.bushing_on_joint_frames(l.bushing) {
            return Err(Error::invalid(
                format!("{ctx}: level {}", l.level.name),
                "the bushing must sit on the two offset frames of its 6-DoF joint",
            ));
        }
        let fr = base
            .bushing_frames(l.bushing)
            .ok_or_else(|| Error::invalid(ctx.to_string(), "bushing index out of range"))?;
        nominal.push(m);
        k_nominal.push(k);
        frames.push(fr);
    }
    Ok((nominal, k_nominal, frames))
}
