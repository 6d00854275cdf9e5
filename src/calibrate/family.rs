//! Parametric model families: a parameter vector (positive values, fitted
//! on a log scale within bounds) mapped onto a solver [`System`] — modified
//! force laws and/or joint frames — with the derivative of the static
//! residual with respect to the parameters.
//!
//! [`ModelFamily`] is the reusable abstraction (calibration uses it for the
//! stiffness parameterisations; `diagnose` extends it with candidate
//! effects). [`StiffnessFamily`] implements the parameterisations of
//! `--params` (names as the stiffness table's forms, `docs/stiffness-table.md`):
//!
//! | `--params` | parameters | law written |
//! |---|---|---|
//! | `uniform` | one `k_d` per DoF for all levels (thesis uniform model) | BushingForce |
//! | `ratio:TABLE` | a base `k_d` per DoF times fixed level ratios (thesis Table 4.3) | BushingForce |
//! | `per-level` | independent `k_d` per level and DoF | BushingForce |
//! | `nonlinear:sinh`, `nonlinear:cubic` | uniform `k_d` plus a stiffening `s_d` per rotational DoF ([`super::forms`]) | ExpressionBasedBushingForce (sinh) / FunctionBasedBushingForce (cubic) |
//! | `nonlinear:sinh:per-level`, `nonlinear:cubic:per-level` | per-level `k_d`, one `s_d` per rotational DoF | idem |
//! | `coupled` | uniform `k_d` plus rotational correlations `rho_xy`, `rho_xz` and partial `rho_yz|x` (SPD by construction) | ExpressionBasedBushingForce (linear expressions) |
//!
//! Stiffness values are fitted on a log scale ([`Scale::Log`]), the
//! stiffening `s` as `ln(1 + s)` ([`Scale::Log1p`]: `1 + s` is a stiffness
//! ratio, the linear limit `s = 0` its lower bound), the correlations as
//! they are ([`Scale::Linear`], neutral value 0 inside the bounds).

use super::forms::{self, CurveForm};
use crate::anatomy::BushingLevel;
use crate::calibrate::experiment::DOF_NAMES;
use crate::error::{Error, Result};
use crate::solver::scalar::Scalar;
use crate::solver::{BodyIndex, BushingIndex, BushingModel, Curve, System, Workspace};
use nalgebra::DMatrix;
use num_dual::Dual64;
use serde::Serialize;
use std::collections::BTreeMap;

/// One parameter of a family.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ParamInfo {
    /// Unique name, e.g. `rx` (uniform), `rx_base` (ratio), `L4_L5.rz` (per level).
    pub name: String,
    /// Unit of the value, e.g. `N*m/rad`.
    pub unit: String,
    /// Lower bound (> 0).
    pub lower: f64,
    /// Upper bound.
    pub upper: f64,
    /// Value of the nominal model (may lie outside the bounds).
    pub nominal: f64,
    /// The scale the parameter is fitted on.
    pub scale: Scale,
    /// What the value means, when the name does not say it (e.g. the
    /// reference rotation of a stiffening parameter).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub note: Option<String>,
}

/// The scale a parameter is fitted (and its confidence interval computed) on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Scale {
    /// Positive, fitted as `ln p` (stiffness values): multiplicative intervals.
    Log,
    /// Any sign, fitted as `p` itself (dimensionless coupling parameters
    /// whose neutral value 0 lies inside the bounds): additive intervals.
    Linear,
    /// `p >= 0`, fitted as `ln(1 + p)` (stiffening parameters: `1 + p` is a
    /// stiffness ratio, and the linear limit `p = 0` is the lower bound):
    /// multiplicative intervals on `1 + p`.
    Log1p,
}

impl ParamInfo {
    /// A log-scale stiffness parameter.
    pub fn log(name: String, unit: &str, lower: f64, upper: f64, nominal: f64) -> ParamInfo {
        ParamInfo {
            name,
            unit: unit.into(),
            lower,
            upper,
            nominal,
            scale: Scale::Log,
            note: None,
        }
    }
    /// The fitting coordinate of value `p`.
    pub fn to_fit(&self, p: f64) -> f64 {
        match self.scale {
            Scale::Log => p.ln(),
            Scale::Linear => p,
            Scale::Log1p => p.ln_1p(),
        }
    }
    /// The value of fitting coordinate `x`.
    pub fn from_fit(&self, x: f64) -> f64 {
        match self.scale {
            Scale::Log => x.exp(),
            Scale::Linear => x,
            Scale::Log1p => x.exp_m1(),
        }
    }
    /// `d p / d x` at value `p`.
    pub fn dvalue_dfit(&self, p: f64) -> f64 {
        match self.scale {
            Scale::Log => p,
            Scale::Linear => 1.0,
            Scale::Log1p => 1.0 + p,
        }
    }
    /// Bounds on the fitting scale.
    pub fn fit_bounds(&self) -> (f64, f64) {
        (self.to_fit(self.lower), self.to_fit(self.upper))
    }
}

/// Values of fitting coordinates `x` of `params`.
pub fn values_of(params: &[ParamInfo], x: &[f64]) -> Vec<f64> {
    params.iter().zip(x).map(|(i, v)| i.from_fit(*v)).collect()
}

/// Fitting coordinates of values `p` of `params`.
pub fn fit_coords_of(params: &[ParamInfo], p: &[f64]) -> Vec<f64> {
    params.iter().zip(p).map(|(i, v)| i.to_fit(*v)).collect()
}

/// A family of models indexed by a positive parameter vector.
pub trait ModelFamily: Send + Sync {
    /// A short description (e.g. `uniform`, `per-level`).
    fn label(&self) -> String;
    /// The parameters, in vector order.
    fn params(&self) -> &[ParamInfo];
    /// The system of parameter values `p` (natural units): a variant of
    /// `sys` (a system of this family, any parameters) with the family's
    /// force laws replaced. Must be cheap (called at every residual
    /// evaluation) and must not depend on the parameters `sys` had before
    /// (the same `p` gives the same system).
    fn system(&self, p: &[f64], sys: &System) -> Result<System>;
    /// `d tau / d p` at `q` (`n_dofs x n_params`), `sys` being the system of
    /// `p`. The default is central finite differences through
    /// [`ModelFamily::system`] (exact families override it).
    fn dtau_dp(
        &self,
        p: &[f64],
        sys: &System,
        q: &[f64],
        loads: &crate::solver::LoadSet,
        ws: &mut Workspace,
        out: &mut DMatrix<f64>,
    ) -> Result<()> {
        let mut pp = p.to_vec();
        let info = self.params();
        for j in 0..p.len() {
            let h = match info.get(j).map(|i| i.scale) {
                Some(Scale::Linear) | Some(Scale::Log1p) => 1e-6 * p[j].abs().max(1.0),
                _ => 1e-6 * p[j].abs().max(1e-12),
            };
            pp[j] = p[j] + h;
            let plus = self
                .system(&pp, sys)?
                .static_residual(q, loads, ws)?
                .to_vec();
            pp[j] = p[j] - h;
            let minus_sys = self.system(&pp, sys)?;
            let minus = minus_sys.static_residual(q, loads, ws)?;
            for (i, (a, b)) in plus.iter().zip(minus).enumerate() {
                out[(i, j)] = (a - b) / (2.0 * h);
            }
            pp[j] = p[j];
        }
        Ok(())
    }
}

/// Literature bounds of thesis Table 3.3 (rotations N*m/rad about X, Y, Z;
/// translations N/m along X, Y, Z), deflection order rx..tz.
const LITERATURE_BOUNDS: [(f64, f64); 6] = [
    (9.0, 249.0),             // right-left (lateral) bending
    (43.0, 1250.0),           // axial rotation
    (12.0, 750.0),            // flexion-extension
    (31_600.0, 857_000.0),    // anterior-posterior translation
    (108_000.0, 3_330_000.0), // inferior-superior translation
    (53_000.0, 584_000.0),    // right-left translation
];

/// Upper bound of a stiffening parameter (tangent stiffness x10001 at the
/// reference rotation: a sinh neutral zone of a tenth of the reference rotation).
const MAX_STIFFENING: f64 = 1e4;

/// Bound of the coupling (partial) correlations.
const MAX_CORRELATION: f64 = 0.95;

/// Unit of stiffness DoF `d`.
fn stiffness_unit(d: usize) -> &'static str {
    if d < 3 {
        "N*m/rad"
    } else {
        "N/m"
    }
}

/// An intervertebral level of a system: the model's [`BushingLevel`] (a
/// bushing between a parent-child pair of bodies) and where it sits in the
/// system.
#[derive(Debug, Clone, PartialEq)]
pub struct SystemLevel {
    /// The level: its name, bushing and bodies by name.
    pub level: BushingLevel,
    /// Bushing index in the system.
    pub bushing: BushingIndex,
    /// Cranial body.
    pub upper: BodyIndex,
    /// Caudal body.
    pub lower: BodyIndex,
}

/// In the calibration report: the level's name, its bushing and bodies by
/// index, then the bodies by name.
impl Serialize for SystemLevel {
    fn serialize<S: serde::Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        use serde::ser::SerializeStruct;
        let mut st = s.serialize_struct("SystemLevel", 6)?;
        st.serialize_field("name", &self.level.name)?;
        st.serialize_field("bushing", &self.bushing)?;
        st.serialize_field("upper", &self.upper)?;
        st.serialize_field("lower", &self.lower)?;
        st.serialize_field("upper_name", &self.level.upper_body)?;
        st.serialize_field("lower_name", &self.level.lower_body)?;
        st.end()
    }
}

/// Normalised level key for matching tables: upper case, no `_`/`-`/space
/// (`T12_L1`, `t12l1` and `T12-L1` all match).
fn level_key(name: &str) -> String {
    name.chars()
        .filter(|c| !matches!(c, '_' | '-' | ' '))
        .flat_map(|c| c.to_uppercase())
        .collect()
}

/// The levels of `sys` on the paths between `fixed` and each of `loaded`
/// (system body indices), cranial to caudal order of the bushing list.
/// A level is a bushing whose two bodies are a parent-child pair of the tree.
pub fn find_levels(sys: &System, fixed: BodyIndex, loaded: &[BodyIndex]) -> Vec<SystemLevel> {
    let mut on_path = vec![false; sys.n_bodies()];
    for &b in loaded {
        // bodies from b up to (excluding) the common ancestor with fixed
        let mut up_fixed = Vec::new();
        let mut cur = Some(fixed);
        while let Some(c) = cur {
            up_fixed.push(c);
            cur = sys.parent_of(c);
        }
        let mut cur = Some(b);
        while let Some(c) = cur {
            if up_fixed.contains(&c) {
                for &f in &up_fixed {
                    if f == c {
                        break;
                    }
                    on_path[f.0] = true;
                }
                on_path[c.0] = true;
                break;
            }
            on_path[c.0] = true;
            cur = sys.parent_of(c);
        }
    }
    let names: Vec<&str> = sys.body_names().collect();
    let mut out = Vec::new();
    for (i, bname) in sys.bushing_names().enumerate() {
        let Some((Some(b1), Some(b2))) = sys.bushing_bodies(BushingIndex(i)) else {
            continue;
        };
        let (upper, lower) = if sys.parent_of(b2) == Some(b1) {
            (b2, b1)
        } else if sys.parent_of(b1) == Some(b2) {
            (b1, b2)
        } else {
            continue;
        };
        if !(on_path[upper.0] && on_path[lower.0]) {
            continue;
        }
        let body = |b: BodyIndex| names.get(b.0).copied().unwrap_or("");
        out.push(SystemLevel {
            level: BushingLevel::new(bname, body(upper), body(lower)),
            bushing: BushingIndex(i),
            upper,
            lower,
        });
    }
    out
}

/// How stiffness values are tied to parameters.
#[derive(Debug, Clone, PartialEq)]
pub enum Parameterisation {
    /// One value per DoF for all levels.
    Uniform,
    /// A base value per DoF times a fixed ratio per level and DoF (keys are
    /// [`level_key`]s; values any positive scale, only ratios matter).
    Ratio(BTreeMap<String, [Option<f64>; 6]>),
    /// Independent values per level and DoF.
    PerLevel,
    /// Non-linear rotational curves: the linear part `k_d` uniform (or per
    /// level with `per_level`) and one stiffening `s_d` per rotational DoF.
    Nonlinear {
        /// The stiffening law of the rotational curves.
        curve: CurveForm,
        /// `k_d` per level instead of uniform.
        per_level: bool,
    },
    /// Coupled rotational stiffness: uniform diagonal `k_d` and three
    /// correlation parameters.
    Coupled,
}

impl Parameterisation {
    /// The `--params` spelling (`ratio` without its table).
    pub fn label(&self) -> String {
        match self {
            Parameterisation::Uniform => "uniform".into(),
            Parameterisation::Ratio(_) => "ratio".into(),
            Parameterisation::PerLevel => "per-level".into(),
            Parameterisation::Nonlinear { curve, per_level } => format!(
                "nonlinear:{}{}",
                curve.name(),
                if *per_level { ":per-level" } else { "" }
            ),
            Parameterisation::Coupled => "coupled".into(),
        }
    }
}

/// What the parameters beyond the linear part are.
#[derive(Debug, Clone, PartialEq)]
enum FormParams {
    /// None: linear bushings.
    Linear,
    /// Parameter index of the stiffening of each rotational DoF (`None`:
    /// DoF not calibrated, stays linear).
    Nonlinear {
        curve: CurveForm,
        shape: [Option<usize>; 3],
    },
    /// Parameter indices of `rho_xy`, `rho_xz`, `rho_yz|x`.
    Coupled { corr: [usize; 3] },
}

/// Layout of a level law's [`BushingModel::stiffness_params`].
#[derive(Debug, Clone, Copy, PartialEq)]
enum Layout {
    Linear,
    /// Per DoF: 0 linear curve, 1 cubic, 2 sinh.
    PerDof([u8; 6]),
    Coupled,
}

/// Linear-bushing stiffness parameterisations over a set of levels.
#[derive(Debug, Clone)]
pub struct StiffnessFamily {
    label: String,
    params: Vec<ParamInfo>,
    /// Nominal diagonal stiffness of every bushing of the system (NaN for non-linear laws).
    nominal: Vec<[f64; 6]>,
    /// First column of each bushing in `System::dtau_dstiffness`, and the total.
    col_offset: Vec<usize>,
    n_cols: usize,
    /// Per parameter: (bushing, dof, factor) with `k = factor * p`.
    map: Vec<Vec<(usize, usize, f64)>>,
    /// Per bushing: (parameter, dof, factor) of the linear part.
    by_bushing: Vec<Vec<(usize, usize, f64)>>,
    /// Nominal damping of every bushing.
    damping: Vec<[f64; 6]>,
    /// Number of linear-part parameters (they come first).
    n_linear: usize,
    form: FormParams,
    /// Reference rotation (rad) of the stiffening parameters per rotational DoF.
    theta_ref: [f64; 3],
    /// The levels the family acts on.
    pub levels: Vec<SystemLevel>,
    /// The stiffness DoFs that are parameters.
    pub dofs: Vec<usize>,
}

fn geomean(v: &[f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    (v.iter().map(|x| x.ln()).sum::<f64>() / v.len() as f64).exp()
}

/// The linear-part parameters of `kind` over `levels` and `dofs` (the
/// non-linear and coupled forms take uniform or per-level linear parts),
/// nominal values from the bushings' `nominal` stiffness.
fn linear_params(
    kind: &Parameterisation,
    levels: &[SystemLevel],
    dofs: &[usize],
    nominal: &[[f64; 6]],
) -> Result<ParamMap> {
    let mut params = Vec::new();
    let mut map = Vec::new();
    let linear_kind = match kind {
        Parameterisation::Nonlinear {
            per_level: true, ..
        } => &Parameterisation::PerLevel,
        Parameterisation::Nonlinear { .. } | Parameterisation::Coupled => {
            &Parameterisation::Uniform
        }
        k => k,
    };
    match linear_kind {
        Parameterisation::Uniform => {
            for &d in dofs {
                let vals: Vec<f64> = levels.iter().map(|l| nominal[l.bushing.0][d]).collect();
                params.push(ParamInfo::log(
                    DOF_NAMES[d].to_string(),
                    stiffness_unit(d),
                    LITERATURE_BOUNDS[d].0,
                    LITERATURE_BOUNDS[d].1,
                    geomean(&vals),
                ));
                map.push(levels.iter().map(|l| (l.bushing.0, d, 1.0)).collect());
            }
        }
        Parameterisation::Ratio(table) => {
            for &d in dofs {
                let raw = table_ratios(table, levels, d)?;
                let g = geomean(&raw);
                let factors: Vec<f64> = raw.iter().map(|v| v / g).collect();
                let base: Vec<f64> = levels
                    .iter()
                    .zip(&factors)
                    .map(|(l, f)| nominal[l.bushing.0][d] / f)
                    .collect();
                params.push(ParamInfo::log(
                    format!("{}_base", DOF_NAMES[d]),
                    stiffness_unit(d),
                    LITERATURE_BOUNDS[d].0,
                    LITERATURE_BOUNDS[d].1,
                    geomean(&base),
                ));
                map.push(
                    levels
                        .iter()
                        .zip(&factors)
                        .map(|(l, f)| (l.bushing.0, d, *f))
                        .collect(),
                );
            }
        }
        Parameterisation::PerLevel
        | Parameterisation::Nonlinear { .. }
        | Parameterisation::Coupled => {
            for l in levels {
                for &d in dofs {
                    params.push(ParamInfo::log(
                        format!("{}.{}", l.level.name, DOF_NAMES[d]),
                        stiffness_unit(d),
                        LITERATURE_BOUNDS[d].0,
                        LITERATURE_BOUNDS[d].1,
                        nominal[l.bushing.0][d],
                    ));
                    map.push(vec![(l.bushing.0, d, 1.0)]);
                }
            }
        }
    }
    Ok((params, map))
}

/// The ratio of DoF `d` of each level in a ratio table (present, positive).
fn table_ratios(
    table: &BTreeMap<String, [Option<f64>; 6]>,
    levels: &[SystemLevel],
    d: usize,
) -> Result<Vec<f64>> {
    let mut raw = Vec::new();
    for l in levels {
        let Some(row) = table.get(&level_key(&l.level.name)) else {
            return Err(Error::invalid(
                "ratio table",
                format!(
                    "no row for level '{}' (table levels: {})",
                    l.level.name,
                    table.keys().cloned().collect::<Vec<_>>().join(", ")
                ),
            ));
        };
        let Some(v) = row[d] else {
            return Err(Error::invalid(
                "ratio table",
                format!("level '{}' has no {} value", l.level.name, DOF_NAMES[d]),
            ));
        };
        if !(v > 0.0 && v.is_finite()) {
            return Err(Error::invalid(
                "ratio table",
                format!(
                    "level '{}' {}: ratio must be positive, got {v}",
                    l.level.name, DOF_NAMES[d]
                ),
            ));
        }
        raw.push(v);
    }
    Ok(raw)
}

/// The form of `kind`, its shape parameters appended to `params`: one
/// stiffening per calibrated rotational DoF (non-linear), three rotational
/// correlations (coupled).
fn form_params(
    kind: &Parameterisation,
    dofs: &[usize],
    params: &mut Vec<ParamInfo>,
) -> Result<FormParams> {
    Ok(match kind {
        Parameterisation::Nonlinear { curve, .. } => {
            let mut shape = [None; 3];
            for &d in dofs.iter().filter(|&&d| d < 3) {
                shape[d] = Some(params.len());
                params.push(ParamInfo {
                    name: format!("{}_stiffening", DOF_NAMES[d]),
                    unit: "ratio: K(5 deg)/K(0) - 1".into(),
                    lower: 0.0,
                    upper: MAX_STIFFENING,
                    nominal: 0.0,
                    scale: Scale::Log1p,
                    note: None,
                });
            }
            if shape.iter().all(|s| s.is_none()) {
                return Err(Error::invalid(
                    "calibration",
                    "--params nonlinear needs at least one rotational DoF to calibrate",
                ));
            }
            FormParams::Nonlinear {
                curve: *curve,
                shape,
            }
        }
        Parameterisation::Coupled => {
            let n0 = params.len();
            for (name, note) in [
                ("rho_rx_ry", "correlation of rx and ry: K_xy = rho sqrt(k_x k_y)"),
                ("rho_rx_rz", "correlation of rx and rz: K_xz = rho sqrt(k_x k_z)"),
                (
                    "rho_ry_rz|rx",
                    "partial correlation of ry and rz given rx: rho_yz = rho_yz|x sqrt((1 - rho_xy^2)(1 - rho_xz^2)) + rho_xy rho_xz",
                ),
            ] {
                params.push(ParamInfo {
                    name: name.into(),
                    unit: "ratio (stiffness correlation)".into(),
                    lower: -MAX_CORRELATION,
                    upper: MAX_CORRELATION,
                    nominal: 0.0,
                    scale: Scale::Linear,
                    note: Some(note.into()),
                });
            }
            FormParams::Coupled {
                corr: [n0, n0 + 1, n0 + 2],
            }
        }
        _ => FormParams::Linear,
    })
}

/// The laws of a system's bushings as a stiffness family starts from them.
struct NominalLaws {
    /// Nominal diagonal stiffness of every bushing (NaN for non-linear laws).
    nominal: Vec<[f64; 6]>,
    /// Nominal damping of every bushing.
    damping: Vec<[f64; 6]>,
    /// Whether each bushing's law is linear.
    linear: Vec<bool>,
    /// First column of each bushing in `System::dtau_dstiffness`.
    col_offset: Vec<usize>,
    /// Total column count.
    n_cols: usize,
}

impl NominalLaws {
    fn of(sys: &System) -> Self {
        let mut laws = NominalLaws {
            nominal: Vec::new(),
            damping: Vec::new(),
            linear: Vec::new(),
            col_offset: Vec::new(),
            n_cols: 0,
        };
        for i in 0..sys.bushing_names().count() {
            let Some(m) = sys.bushing_model(BushingIndex(i)) else {
                continue;
            };
            let p = m.stiffness_params();
            laws.damping.push(m.damping());
            laws.col_offset.push(laws.n_cols);
            laws.n_cols += p.len();
            let is_linear = matches!(m, crate::solver::BushingModel::Linear { .. });
            laws.linear.push(is_linear);
            laws.nominal.push(if is_linear {
                std::array::from_fn(|d| p.get(d).copied().unwrap_or(0.0))
            } else {
                [f64::NAN; 6]
            });
        }
        laws
    }

    /// Every level's bushing is linear, with a positive nominal stiffness
    /// in each DoF of `dofs`.
    fn check_levels(&self, levels: &[SystemLevel], dofs: &[usize]) -> Result<()> {
        for l in levels {
            if !self.linear.get(l.bushing.0).copied().unwrap_or(false) {
                return Err(Error::invalid(
                    format!("level {}", l.level.name),
                    "its bushing is not a linear BushingForce: calibration starts from a linear nominal model (the non-linear and coupled forms are chosen with --params; write linear values first with `osim-spine stiffness --table`)",
                ));
            }
        }
        for l in levels {
            let k = self.nominal.get(l.bushing.0).copied().unwrap_or([0.0; 6]);
            for &d in dofs {
                if k[d].is_nan() || k[d] <= 0.0 {
                    return Err(Error::invalid(
                        format!("level {}", l.level.name),
                        format!(
                            "nominal {} stiffness is {} {}: a calibrated stiffness must start from a positive value",
                            DOF_NAMES[d], k[d], stiffness_unit(d)
                        ),
                    ));
                }
            }
        }
        Ok(())
    }
}

/// Parameters of a family and, per parameter, the (bushing, dof, factor)
/// it sets with `k = factor * p`.
type ParamMap = (Vec<ParamInfo>, Vec<Vec<(usize, usize, f64)>>);

impl StiffnessFamily {
    /// Build over `levels` of `sys` for the stiffness DoFs `dofs` (0..6).
    /// Bounds are the literature ranges ([`LITERATURE_BOUNDS`]).
    pub fn new(
        sys: &System,
        levels: Vec<SystemLevel>,
        dofs: &[usize],
        kind: &Parameterisation,
    ) -> Result<StiffnessFamily> {
        if levels.is_empty() {
            return Err(Error::invalid(
                "calibration",
                "no intervertebral level (a BushingForce between an adjacent pair of bodies) lies between the fixed body and the loaded bodies",
            ));
        }
        // The nominal laws: every level linear, positive in the calibrated DoFs.
        let nom = NominalLaws::of(sys);
        nom.check_levels(&levels, dofs)?;
        // The linear-part parameters (uniform, ratio or per level) come first.
        let (mut params, map) = linear_params(kind, &levels, dofs, &nom.nominal)?;
        let n_linear = params.len();
        // Then the shape parameters of the non-linear or coupled form.
        let form = form_params(kind, dofs, &mut params)?;
        // Per bushing: the parameters that set its linear part.
        let mut by_bushing = vec![Vec::new(); nom.nominal.len()];
        for (j, entries) in map.iter().enumerate() {
            for &(b, d, f) in entries {
                if let Some(v) = by_bushing.get_mut(b) {
                    v.push((j, d, f));
                }
            }
        }
        let theta_ref = [5f64.to_radians(); 3];
        let mut fam = StiffnessFamily {
            label: kind.label(),
            params,
            nominal: nom.nominal,
            col_offset: nom.col_offset,
            n_cols: nom.n_cols,
            map,
            by_bushing,
            damping: nom.damping,
            n_linear,
            form,
            theta_ref,
            levels,
            dofs: dofs.to_vec(),
        };
        fam.set_reference_rotations(theta_ref);
        Ok(fam)
    }

    /// Set the reference rotations (rad, per rotational DoF) at which the
    /// stiffening parameters are defined (calibration uses the largest
    /// measured rotation of each DoF; default 5 deg). Values below
    /// [`forms::MIN_REFERENCE_ROTATION`] are raised to it.
    pub fn set_reference_rotations(&mut self, theta: [f64; 3]) {
        self.theta_ref = theta.map(|t| {
            if t.is_finite() {
                t.abs().max(forms::MIN_REFERENCE_ROTATION)
            } else {
                forms::MIN_REFERENCE_ROTATION
            }
        });
        if let FormParams::Nonlinear { curve, shape } = &self.form {
            for (d, j) in shape.iter().enumerate() {
                if let Some(p) = j.and_then(|j| self.params.get_mut(j)) {
                    p.note = Some(format!(
                        "{} curve: tangent stiffness at {:.4} deg over the slope at 0, minus 1 (0 = linear)",
                        curve.name(),
                        self.theta_ref[d].to_degrees()
                    ));
                }
            }
        }
    }

    /// The reference rotations (rad) of the stiffening parameters.
    pub fn reference_rotations(&self) -> [f64; 3] {
        self.theta_ref
    }

    /// Linear part of bushing `b`'s stiffness for parameters `p` (any scalar).
    fn diagonal<T: Scalar>(&self, b: usize, p: &[T]) -> [T; 6] {
        let mut k = self
            .nominal
            .get(b)
            .copied()
            .unwrap_or([f64::NAN; 6])
            .map(T::c);
        for &(j, d, f) in self.by_bushing.get(b).map(|v| v.as_slice()).unwrap_or(&[]) {
            k[d] = p.get(j).copied().unwrap_or(T::c(f64::NAN)) * T::c(f);
        }
        k
    }

    /// The law parameters of bushing `b` in [`BushingModel::stiffness_params`]
    /// order, and their layout.
    fn law_values<T: Scalar>(&self, b: usize, p: &[T]) -> (Vec<T>, Layout) {
        let k = self.diagonal(b, p);
        match &self.form {
            FormParams::Linear => (k.to_vec(), Layout::Linear),
            FormParams::Nonlinear { curve, shape } => {
                let mut vals = Vec::with_capacity(9);
                let mut kinds = [0u8; 6];
                for d in 0..6 {
                    match shape.get(d).copied().flatten() {
                        Some(j) => {
                            let s = p.get(j).copied().unwrap_or(T::c(f64::NAN));
                            let (cp, sinh) =
                                forms::shaped_curve(*curve, k[d], s, self.theta_ref[d]);
                            vals.extend(cp);
                            kinds[d] = if sinh { 2 } else { 1 };
                        }
                        None => vals.push(k[d]),
                    }
                }
                (vals, Layout::PerDof(kinds))
            }
            FormParams::Coupled { corr } => {
                let pc = corr.map(|j| p.get(j).copied().unwrap_or(T::c(f64::NAN)));
                let rho = forms::correlations_from_partial(pc);
                (forms::coupled_entries(&k, rho).to_vec(), Layout::Coupled)
            }
        }
    }

    fn model_of(&self, b: usize, vals: &[f64], layout: Layout) -> BushingModel {
        let damping = self.damping.get(b).copied().unwrap_or([0.0; 6]);
        let v = |i: usize| vals.get(i).copied().unwrap_or(f64::NAN);
        match layout {
            Layout::Linear => BushingModel::Linear {
                rot_stiffness: nalgebra::Vector3::new(v(0), v(1), v(2)),
                trans_stiffness: nalgebra::Vector3::new(v(3), v(4), v(5)),
                rot_damping: nalgebra::Vector3::new(damping[0], damping[1], damping[2]),
                trans_damping: nalgebra::Vector3::new(damping[3], damping[4], damping[5]),
            },
            Layout::PerDof(kinds) => {
                let mut i = 0;
                let curves: [Curve; 6] = std::array::from_fn(|d| match kinds[d] {
                    0 => {
                        i += 1;
                        Curve::Linear { k: v(i - 1) }
                    }
                    kind => {
                        i += 2;
                        forms::curve_of([v(i - 2), v(i - 1)], kind == 2)
                    }
                });
                BushingModel::PerDof {
                    curves: Box::new(curves),
                    damping,
                }
            }
            Layout::Coupled => forms::coupled_model(vals, damping),
        }
    }

    /// The law of every level for parameters `p`: `(bushing index, law)`,
    /// in the order of [`Self::levels`] (damping nominal).
    pub fn level_models(&self, p: &[f64]) -> Vec<(BushingIndex, BushingModel)> {
        self.levels
            .iter()
            .map(|l| {
                let (vals, layout) = self.law_values(l.bushing.0, p);
                (l.bushing, self.model_of(l.bushing.0, &vals, layout))
            })
            .collect()
    }

    /// True for the plain linear parameterisations (uniform, ratio, per-level).
    pub fn is_linear(&self) -> bool {
        self.form == FormParams::Linear
    }

    /// Number of linear-stiffness parameters (the first ones).
    pub fn n_linear(&self) -> usize {
        self.n_linear
    }

    /// Diagonal stiffness of every bushing for parameters `p`.
    pub fn bushing_stiffness(&self, p: &[f64]) -> Vec<[f64; 6]> {
        let mut k = self.nominal.clone();
        for (j, entries) in self.map.iter().enumerate() {
            let v = p.get(j).copied().unwrap_or(f64::NAN);
            for &(b, d, f) in entries {
                if let Some(kb) = k.get_mut(b) {
                    kb[d] = f * v;
                }
            }
        }
        k
    }

    /// The family's label (`uniform`, `ratio`, `per-level`).
    pub fn label_str(&self) -> &str {
        &self.label
    }

    /// The parameters (same as [`ModelFamily::params`]).
    pub fn params_info(&self) -> &[ParamInfo] {
        &self.params
    }

    /// Nominal parameter values.
    pub fn params_nominal(&self) -> Vec<f64> {
        self.params.iter().map(|p| p.nominal).collect()
    }
}

impl StiffnessFamily {
    fn dtau_dp_forms(
        &self,
        p: &[f64],
        sys: &System,
        q: &[f64],
        ws: &mut Workspace,
        out: &mut DMatrix<f64>,
    ) -> Result<()> {
        // columns of the current laws in `System::dtau_dstiffness`
        let mut offset = Vec::new();
        let mut col = 0;
        for i in 0..sys.bushing_names().count() {
            offset.push(col);
            col += sys
                .bushing_model(BushingIndex(i))
                .map(|m| m.stiffness_params().len())
                .unwrap_or(0);
        }
        let mut dk = DMatrix::zeros(sys.n_dofs(), col);
        sys.dtau_dstiffness(q, ws, &mut dk)?;
        out.fill(0.0);
        let mut pd: Vec<Dual64> = p.iter().map(|v| Dual64::from(*v)).collect();
        for l in &self.levels {
            let b = l.bushing.0;
            let mut js: Vec<usize> = self
                .by_bushing
                .get(b)
                .map(|v| v.iter().map(|e| e.0).collect())
                .unwrap_or_default();
            js.extend(self.n_linear..p.len());
            js.sort_unstable();
            js.dedup();
            let off = offset.get(b).copied().unwrap_or(0);
            for j in js {
                pd[j] = Dual64::new(p[j], 1.0);
                let (vals, _) = self.law_values(b, &pd);
                pd[j] = Dual64::from(p[j]);
                for (i, v) in vals.iter().enumerate() {
                    if v.eps == 0.0 {
                        continue;
                    }
                    let c = off + i;
                    if c >= dk.ncols() {
                        return Err(Error::numerical(
                            "calibration",
                            "the system's bushing law does not match the family's (apply the parameters first)",
                        ));
                    }
                    for r in 0..sys.n_dofs() {
                        out[(r, j)] += v.eps * dk[(r, c)];
                    }
                }
            }
        }
        Ok(())
    }
}

impl ModelFamily for StiffnessFamily {
    fn label(&self) -> String {
        self.label.clone()
    }
    fn params(&self) -> &[ParamInfo] {
        &self.params
    }
    fn system(&self, p: &[f64], sys: &System) -> Result<System> {
        if p.len() != self.params.len() {
            return Err(Error::invalid(
                "calibration",
                format!("expected {} parameters, got {}", self.params.len(), p.len()),
            ));
        }
        if !self.is_linear() {
            return sys.with_bushing_models(self.level_models(p));
        }
        let k = self.bushing_stiffness(p);
        let mut touched: Vec<usize> = self.map.iter().flatten().map(|e| e.0).collect();
        touched.sort_unstable();
        touched.dedup();
        let models = touched
            .into_iter()
            .filter_map(|b| k.get(b).map(|kb| (b, *kb)))
            .map(|(b, kb)| {
                Ok((
                    BushingIndex(b),
                    sys.linear_with_stiffness(BushingIndex(b), kb)?,
                ))
            })
            .collect::<Result<Vec<_>>>()?;
        sys.with_bushing_models(models)
    }
    /// Exact: the residual is linear in every stiffness (through the
    /// deflection), so `d tau / d p_j = sum factor * d tau / d k`; for the
    /// non-linear and coupled forms the chain rule through the law
    /// parameters, `d tau / d p_j = sum_i d tau / d theta_i d theta_i / d p_j`
    /// with `d theta / d p` by dual numbers through the law builders.
    fn dtau_dp(
        &self,
        p: &[f64],
        sys: &System,
        q: &[f64],
        _loads: &crate::solver::LoadSet,
        ws: &mut Workspace,
        out: &mut DMatrix<f64>,
    ) -> Result<()> {
        if !self.is_linear() {
            return self.dtau_dp_forms(p, sys, q, ws, out);
        }
        let mut dk = DMatrix::zeros(sys.n_dofs(), self.n_cols);
        sys.dtau_dstiffness(q, ws, &mut dk)?;
        out.fill(0.0);
        for (j, entries) in self.map.iter().enumerate() {
            for &(b, d, f) in entries {
                let col = self.col_offset.get(b).copied().unwrap_or(0) + d;
                for i in 0..sys.n_dofs() {
                    out[(i, j)] += f * dk[(i, col)];
                }
            }
        }
        Ok(())
    }
}

/// A level-ratio table: [`level_key`] -> values per DoF (rx..tz).
pub type RatioTable = BTreeMap<String, [Option<f64>; 6]>;

#[derive(Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct RatioLevelToml {
    name: String,
    rx: Option<f64>,
    ry: Option<f64>,
    rz: Option<f64>,
    tx: Option<f64>,
    ty: Option<f64>,
    tz: Option<f64>,
}

#[derive(Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct RatioToml {
    #[serde(default)]
    #[allow(dead_code)]
    source: Option<String>,
    #[serde(default)]
    #[allow(dead_code)]
    unit: Option<String>,
    level: Vec<RatioLevelToml>,
}

/// Read a level-ratio table: TOML (`[[level]]` tables with `name` and any of
/// `rx .. tz`) or CSV with a header `level,rx,ry,rz[,tx,ty,tz]`. Values must
/// be positive; levels must be unique.
pub fn read_ratio_table(path: &std::path::Path) -> Result<RatioTable> {
    let text =
        crate::util::read_text_capped(path, crate::util::input::MAX_TABLE_BYTES, "ratio tables")?;
    let mut out = RatioTable::new();
    let mut put = |name: &str, vals: [Option<f64>; 6], at: String| -> Result<()> {
        for (d, v) in vals.iter().enumerate() {
            if let Some(v) = v {
                if !(v.is_finite() && *v > 0.0) {
                    return Err(Error::parse(
                        path,
                        at.clone(),
                        format!(
                            "{} of level '{name}' must be a positive number, got {v}",
                            DOF_NAMES[d]
                        ),
                    ));
                }
            }
        }
        if out.insert(level_key(name), vals).is_some() {
            return Err(Error::parse(
                path,
                at,
                format!("level '{name}' appears twice"),
            ));
        }
        Ok(())
    };
    let is_toml = path
        .extension()
        .map(|e| e.eq_ignore_ascii_case("toml"))
        .unwrap_or(false);
    if is_toml {
        let t: RatioToml = toml::from_str(&text).map_err(|e| {
            let location = match e.span() {
                Some(s) => format!(
                    "line {}",
                    text[..s.start.min(text.len())].lines().count().max(1)
                ),
                None => "file".to_string(),
            };
            Error::parse(path, location, e.message().to_string())
        })?;
        for (i, l) in t.level.iter().enumerate() {
            put(
                &l.name,
                [l.rx, l.ry, l.rz, l.tx, l.ty, l.tz],
                format!("[[level]] #{}", i + 1),
            )?;
        }
    } else {
        let mut rows = crate::util::table::CsvReader::new(&text, path).records();
        let Some(headers) = rows.next().transpose()? else {
            return Err(Error::parse(
                path,
                "line 1",
                "missing column 'level' (expected level,rx,ry,rz): no header row",
            ));
        };
        let col = |n: &str| headers.cells().position(|h| h == n);
        let Some(lc) = col("level") else {
            return Err(headers.error(path, "missing column 'level' (expected level,rx,ry,rz)"));
        };
        let cols: Vec<Option<usize>> = DOF_NAMES.iter().map(|d| col(d)).collect();
        if cols.iter().all(|c| c.is_none()) {
            return Err(headers.error(path, "no DoF column (rx, ry, rz, tx, ty, tz)"));
        }
        for rec in rows {
            let rec = rec?;
            let at = rec.at();
            rec.check_width(&headers, path)?;
            let name = rec.cell(lc).to_string();
            let mut vals = [None; 6];
            for (d, c) in cols.iter().enumerate() {
                let Some(c) = c else { continue };
                let s = rec.cell(*c);
                if s.is_empty() {
                    continue;
                }
                vals[d] = Some(s.parse::<f64>().map_err(|_| {
                    Error::parse(
                        path,
                        at.clone(),
                        format!("column {}: '{s}' is not a number", DOF_NAMES[d]),
                    )
                })?);
            }
            put(&name, vals, at)?;
        }
    }
    if out.is_empty() {
        return Err(Error::parse(path, "file", "no level in the ratio table"));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Regression: the fast-path bushing reads rx, rz wrapped into
    /// (-pi, pi]; d tau / d k must use the same angles, or a Newton solution
    /// 2 pi away (same pose) gives a wrong Jacobian.
    #[test]
    fn dtau_dp_is_the_same_for_coordinates_two_pi_apart() {
        let p = std::path::Path::new("../shared/diagnose-dev/dev-07");
        if !p.exists() {
            assert!(
                std::env::var("CI").as_deref() != Ok("true"),
                "CI=true but ../shared/diagnose-dev not found"
            );
            eprintln!("SKIP: ../shared/diagnose-dev not found");
            return;
        }
        let exp = crate::calibrate::experiment::Experiment::read(p).unwrap();
        let sys = System::new(&exp.spec).unwrap();
        let fixed = sys.body_index("sacrum").unwrap();
        let top = sys.body_index("thoracic12").unwrap();
        let levels = find_levels(&sys, fixed, &[top]);
        let fam =
            StiffnessFamily::new(&sys, levels, &[0, 1, 2], &Parameterisation::PerLevel).unwrap();
        let pv = fam.params_nominal();
        let sys = fam.system(&pv, &sys).unwrap();
        let mut ws = Workspace::new(&sys);
        let mut q: Vec<f64> = (0..sys.n_dofs())
            .map(|i| 0.01 * (i as f64 % 5.0 - 2.0))
            .collect();
        let loads = crate::solver::LoadSet::empty();
        let mut a = DMatrix::zeros(sys.n_dofs(), pv.len());
        fam.dtau_dp(&pv, &sys, &q, &loads, &mut ws, &mut a).unwrap();
        let rz = sys.dof_of("L3_L4_rz").unwrap();
        q[rz.0] += 2.0 * std::f64::consts::PI;
        let mut b = DMatrix::zeros(sys.n_dofs(), pv.len());
        fam.dtau_dp(&pv, &sys, &q, &loads, &mut ws, &mut b).unwrap();
        assert!((&a - &b).amax() < 1e-12, "{}", (&a - &b).amax());
    }

    #[test]
    fn reads_the_shipped_zhang_template_and_csv() {
        let t =
            read_ratio_table(std::path::Path::new("templates/level_ratios_zhang.toml")).unwrap();
        assert_eq!(t.len(), 6);
        assert_eq!(t["T12L1"][0], Some(36.4));
        assert_eq!(t["L5S1"][2], Some(51.0));
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("r.csv");
        std::fs::write(&p, "level,rx,ry,rz\nL4_L5,1,2,3\nL5-S1,2,,4\n").unwrap();
        let t = read_ratio_table(&p).unwrap();
        assert_eq!(t["L5S1"], [Some(2.0), None, Some(4.0), None, None, None]);
        std::fs::write(&p, "level,rx\nL4_L5,-1\n").unwrap();
        let e = read_ratio_table(&p).unwrap_err().to_string();
        assert!(e.contains("line 2") && e.contains("positive"), "{e}");
        std::fs::write(&p, "level,rx\nL4_L5,1\nl4l5,2\n").unwrap();
        assert!(read_ratio_table(&p)
            .unwrap_err()
            .to_string()
            .contains("twice"));
        // BOM, comments, CRLF, quoted cells; a bad cell names its file line
        std::fs::write(
            &p,
            "\u{feff}# ratios\r\nlevel,rx,ry\r\n\r\n\"L4_L5\",\"1\",2\r\nL5_S1,\"1,5\",2\r\n",
        )
        .unwrap();
        let e = read_ratio_table(&p).unwrap_err().to_string();
        assert!(
            e.contains("line 5: column rx: '1,5' is not a number"),
            "{e}"
        );
        std::fs::write(
            &p,
            "\u{feff}# ratios\r\nlevel,rx,ry\r\n\r\n\"L4_L5\",\"1\",2\r\n",
        )
        .unwrap();
        let t = read_ratio_table(&p).unwrap();
        assert_eq!(t["L4L5"][..2], [Some(1.0), Some(2.0)]);
    }
}
