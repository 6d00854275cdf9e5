//! Candidate model families: the baseline (the nominal model's form with
//! its values free) and one real extension per effect of the format's
//! vocabulary. A family maps an unconstrained parameter vector `x` (within
//! a box) onto a solver [`System`] (force laws and joint frames) and onto
//! the laws and frames written into the improved `.osim`.
//!
//! Every family starts with the three global rotational stiffness
//! factors `k_d = k_nominal,d * exp(x_d)` (d = LB/X, AR/Y, FE/Z, the same at
//! every level); translational stiffness stays nominal. Then:
//!
//! | family | extra parameters | law |
//! |---|---|---|
//! | `baseline` | none | linear diagonal (BushingForce) |
//! | `level_dependent_stiffness` / `scalar` | per-level factor `exp(m_l)` on all three DoFs (L-1; the first level is the reference) | linear |
//! | `level_dependent_stiffness` / `per_dof` | per-level, per-DoF factors (3L, replacing the 3 global ones) | linear |
//! | `level_dependent_stiffness` / `trend` | per measured DoF a log-linear trend along the spine, `k_ld = k_d exp(b_d (z_l - z_mean))` with `z_l` the level's position from the fixed body (one parameter per DoF; a table of one magnitude can predict a level it has not seen from it) | linear |
//! | `nonlinear_stiffness` / `sinh` | per DoF `lambda_d = exp(s_d)`: `M = k sinh(lambda th) / lambda` | FunctionBased/ExpressionBased |
//! | `nonlinear_stiffness` / `cubic` | per DoF `c_d = k_d exp(s_d)`: `M = k th + c th^3` | FunctionBasedBushingForce (PolynomialFunction) |
//! | `asymmetric_stiffness` / `bilinear` | per DoF loaded in both directions `k+ = k- exp(a_d)`, shared by the levels | FunctionBasedBushingForce (PiecewiseLinearFunction) |
//! | `asymmetric_stiffness` / `per_level` | per level and DoF one-sided stiffening `exp(|a_ld|)` of the positive (`a > 0`) or negative (`a < 0`) side (levels of the mask; others symmetric) | idem |
//! | `coupled_stiffness` / `uniform` | 3 correlations `rho_ij`, `K_ij = rho_ij sqrt(k_i k_j)` | ExpressionBasedBushingForce (linear) |
//! | `coupled_stiffness` / `per_level` | 3 correlations per level | idem |
//! | `joint_pose_error` / `rotation` | per level a rotation vector (rad) of both joint frames | linear, joint frames moved |
//! | `joint_pose_error` / `pose` | per level rotation vector and offset (mm) of both joint frames | idem |
//! | `preload_stiffening` | `beta = exp(b)` (1/m): rotational `M = k th (1 + beta max(0, -delta_y))` | ExpressionBasedBushingForce |

use super::law::{LawParts, OneSided};
use super::sim::Sim;
use crate::error::Result;
use crate::solver::{BushingModel, Curve, System};
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use serde::Serialize;

/// The vocabulary of `diagnosis.json` (`verdict.effect`), without `unidentifiable`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Effect {
    /// No unmodelled effect: the baseline explains the data.
    None,
    /// Stiffness differs between levels.
    LevelDependentStiffness,
    /// Stiffness changes with the deflection.
    NonlinearStiffness,
    /// Stiffness differs between the two directions of a DoF.
    AsymmetricStiffness,
    /// Off-diagonal stiffness couples the rotational DoFs.
    CoupledStiffness,
    /// The joint frames are misplaced.
    JointPoseError,
    /// Compression stiffens the rotations.
    PreloadStiffening,
}

impl Effect {
    /// The name used in `diagnosis.json`.
    pub fn name(&self) -> &'static str {
        match self {
            Effect::None => "none",
            Effect::LevelDependentStiffness => "level_dependent_stiffness",
            Effect::NonlinearStiffness => "nonlinear_stiffness",
            Effect::AsymmetricStiffness => "asymmetric_stiffness",
            Effect::CoupledStiffness => "coupled_stiffness",
            Effect::JointPoseError => "joint_pose_error",
            Effect::PreloadStiffening => "preload_stiffening",
        }
    }
    /// Order in which effects build a mixed law: level factors first
    /// (the others scale with the local stiffness), curves before the
    /// one-sided terms added to them.
    pub fn order(&self) -> u8 {
        match self {
            Effect::None => 0,
            Effect::LevelDependentStiffness => 1,
            Effect::NonlinearStiffness => 2,
            Effect::AsymmetricStiffness => 3,
            Effect::CoupledStiffness => 4,
            Effect::JointPoseError => 5,
            Effect::PreloadStiffening => 6,
        }
    }
    /// Every effect but `none`.
    pub const CANDIDATES: [Effect; 6] = [
        Effect::LevelDependentStiffness,
        Effect::NonlinearStiffness,
        Effect::AsymmetricStiffness,
        Effect::CoupledStiffness,
        Effect::JointPoseError,
        Effect::PreloadStiffening,
    ];
}

/// A parametric family (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Kind {
    /// The nominal law with its three global rotational factors free.
    Baseline,
    /// One stiffness factor per level on all three rotational DoFs.
    LevelScalar,
    /// One stiffness factor per level and rotational DoF.
    LevelPerDof,
    /// A log-linear stiffness trend along the spine per DoF.
    LevelTrend,
    /// Per DoF `M = k sinh(lambda th) / lambda`.
    NonlinearSinh,
    /// Per DoF `M = k th + c th^3`.
    NonlinearCubic,
    /// Per DoF a stiffness ratio between the two directions, shared by the levels.
    AsymmetricBilinear,
    /// Bilinear asymmetry with its own ratios at each level of the mask
    /// (an asymmetry at some levels only).
    AsymmetricPerLevel,
    /// Three rotational correlations shared by the levels.
    CoupledUniform,
    /// Three rotational correlations per level.
    CoupledPerLevel,
    /// Coupling at the levels of the family's mask only (a local effect).
    CoupledLocal,
    /// Per level a rotation of both joint frames.
    JointRotation,
    /// Per level a rotation and an offset of both joint frames.
    JointPose,
    /// Joint pose error at the levels of the mask only.
    JointLocal,
    /// Rotational stiffness growing with the disc's compression.
    Preload,
}

impl Kind {
    /// The effect this family adds.
    pub fn effect(&self) -> Effect {
        match self {
            Kind::Baseline => Effect::None,
            Kind::LevelScalar | Kind::LevelPerDof | Kind::LevelTrend => {
                Effect::LevelDependentStiffness
            }
            Kind::NonlinearSinh | Kind::NonlinearCubic => Effect::NonlinearStiffness,
            Kind::AsymmetricBilinear | Kind::AsymmetricPerLevel => Effect::AsymmetricStiffness,
            Kind::CoupledUniform | Kind::CoupledPerLevel | Kind::CoupledLocal => {
                Effect::CoupledStiffness
            }
            Kind::JointRotation | Kind::JointPose | Kind::JointLocal => Effect::JointPoseError,
            Kind::Preload => Effect::PreloadStiffening,
        }
    }
    /// Short label of the variant.
    pub fn label(&self) -> &'static str {
        match self {
            Kind::Baseline => "baseline",
            Kind::LevelScalar => "level_scalar",
            Kind::LevelPerDof => "level_per_dof",
            Kind::LevelTrend => "level_trend",
            Kind::NonlinearSinh => "nonlinear_sinh",
            Kind::NonlinearCubic => "nonlinear_cubic",
            Kind::AsymmetricBilinear => "asymmetric_bilinear",
            Kind::AsymmetricPerLevel => "asymmetric_per_level",
            Kind::CoupledUniform => "coupled_uniform",
            Kind::CoupledPerLevel => "coupled_per_level",
            Kind::CoupledLocal => "coupled_local",
            Kind::JointLocal => "joint_local",
            Kind::JointRotation => "joint_rotation",
            Kind::JointPose => "joint_pose",
            Kind::Preload => "preload",
        }
    }
    /// Order in which effects build a mixed law (see [`Effect::order`]).
    pub fn order(&self) -> u8 {
        self.effect().order()
    }
}

const DOF3: [&str; 3] = ["rx", "ry", "rz"];

/// A family instantiated on an experiment: parameter names, start, box.
#[derive(Debug, Clone)]
pub struct Family {
    /// Which family.
    pub kind: Kind,
    /// Levels that carry per-level parameters (all for the per-level
    /// kinds; one or a few for the local kinds).
    pub mask: Vec<bool>,
    /// Joint offsets (mm) are parameters (pose kinds).
    pub offsets: bool,
    /// Parameter names, in `x` order.
    pub names: Vec<String>,
    /// Starting parameter vector.
    pub x0: Vec<f64>,
    /// Lower bounds of the parameters.
    pub lo: Vec<f64>,
    /// Upper bounds of the parameters.
    pub hi: Vec<f64>,
    /// A second effect's family (mixed effects): its own parameters follow
    /// this family's in `x`, its global block is this one's.
    pub add: Option<Box<Family>>,
    /// The rotational DoF (0 rx, 1 ry, 2 rz) of each own per-DoF parameter
    /// (trend and shared-asymmetry kinds: only the DoFs the data can show).
    pub dofs: Vec<usize>,
}

/// Box of the global log-factors: e^4 ~ 55 either way.
const GBOX: f64 = 4.0;

/// What a parameter vector means, level by level.
#[derive(Debug, Clone)]
pub struct Variant {
    /// Force law of each level.
    pub laws: Vec<BushingModel>,
    /// Rigid change `T` of each level's joint frames (both frames become
    /// `X * T`), identity when unchanged.
    pub frames: Vec<Option<Isometry3<f64>>>,
    /// The expressions of the levels whose law is an expression law.
    pub expressions: Vec<Option<[String; 6]>>,
}

/// Scale of the stiffening parameters: the largest measured rotation (rad)
/// of each rotational DoF over the cells, a floor of 0.1 deg.
pub fn rotation_scale(sim: &Sim) -> [f64; 3] {
    crate::calibrate::forms::reference_rotations(
        sim.cells.iter().map(|c| (c.dof, c.measured.to_radians())),
    )
}

impl Family {
    /// Instantiate `kind` on `sim`; `start_global` are the baseline's fitted
    /// global factors (log), used as the start of the global block.
    /// `offsets` says whether joint-centre offsets are part of the pose family.
    pub fn new(kind: Kind, sim: &Sim, start_global: [f64; 3]) -> Family {
        let all = vec![true; sim.levels.len()];
        Family::masked(kind, sim, start_global, all, kind == Kind::JointPose)
    }

    /// Instantiate with per-level parameters at the `mask` levels only, and
    /// joint offsets when `offsets` (pose kinds).
    pub fn masked(
        kind: Kind,
        sim: &Sim,
        start_global: [f64; 3],
        mask: Vec<bool>,
        offsets: bool,
    ) -> Family {
        let mut f = Family {
            kind,
            mask,
            offsets,
            names: Vec::new(),
            x0: Vec::new(),
            lo: Vec::new(),
            hi: Vec::new(),
            add: None,
            dofs: Vec::new(),
        };
        // the global block (per level and DoF for LevelPerDof)
        if kind != Kind::LevelPerDof {
            for (d, g) in start_global.iter().enumerate() {
                f.push(format!("log_k_{}", DOF3[d]), *g, -GBOX, GBOX);
            }
        }
        f.push_kind_params(sim, start_global);
        f
    }

    /// Append a parameter (start clamped into its box).
    fn push(&mut self, name: String, x0: f64, lo: f64, hi: f64) {
        self.names.push(name);
        self.x0.push(x0.clamp(lo, hi));
        self.lo.push(lo);
        self.hi.push(hi);
    }

    /// Names of the levels of the mask.
    fn masked_levels<'a>(&'a self, sim: &'a Sim) -> impl Iterator<Item = &'a str> + 'a {
        sim.levels
            .iter()
            .zip(&self.mask)
            .filter(|p| *p.1)
            .map(|p| p.0.level.name.as_str())
    }

    /// The kind's own parameters (after the global block).
    fn push_kind_params(&mut self, sim: &Sim, start_global: [f64; 3]) {
        let scale = rotation_scale(sim);
        let levels: Vec<String> = self.masked_levels(sim).map(String::from).collect();
        match self.kind {
            Kind::Baseline => {}
            Kind::LevelScalar => {
                for l in sim.levels.iter().skip(1) {
                    self.push(format!("{}.log_m", l.level.name), 0.0, -3.0, 3.0);
                }
            }
            Kind::LevelPerDof => {
                for l in &sim.levels {
                    for (d, g) in start_global.iter().enumerate() {
                        let name = format!("{}.log_k_{}", l.level.name, DOF3[d]);
                        self.push(name, *g, -GBOX, GBOX);
                    }
                }
            }
            Kind::NonlinearSinh => {
                // lambda = 1/a; start where the curve stiffens by ~20% at the largest rotation
                for d in 0..3 {
                    let l0 = (1.0 / scale[d]).ln();
                    self.push(format!("log_lambda_{}", DOF3[d]), l0, l0 - 6.0, l0 + 3.0);
                }
            }
            Kind::NonlinearCubic => {
                // c = k exp(s) / scale^2: start at ~10% extra stiffness at the largest rotation
                for d in DOF3 {
                    self.push(format!("log_c_{d}"), (0.1f64).ln(), -12.0, 5.0);
                }
            }
            Kind::LevelTrend => {
                // the DoFs measured as a primary rotation whose level
                // pattern no coupling through tilted levels can imitate
                self.dofs = sim.trend_dofs();
                for d in self.dofs.clone() {
                    let name = format!("trend_log_k_{}_per_level", DOF3[d]);
                    self.push(name, 0.0, -1.5, 1.5);
                }
            }
            Kind::AsymmetricBilinear => {
                // the DoFs loaded in both directions (all three when no
                // case has a primary rotation)
                let pd = sim.primary_dofs();
                self.dofs = (0..3).filter(|&d| pd[d].1).collect();
                if self.dofs.is_empty() {
                    self.dofs = vec![0, 1, 2];
                }
                for d in self.dofs.clone() {
                    self.push(format!("log_kpos_over_kneg_{}", DOF3[d]), 0.0, -3.0, 3.0);
                }
            }
            Kind::AsymmetricPerLevel => {
                for l in &levels {
                    for d in DOF3 {
                        self.push(format!("{l}.log_kpos_over_kneg_{d}"), 0.0, -3.0, 3.0);
                    }
                }
            }
            Kind::CoupledUniform => {
                for n in ["xy", "xz", "yz"] {
                    self.push(format!("rho_{n}"), 0.0, -0.8, 0.8);
                }
            }
            Kind::CoupledPerLevel | Kind::CoupledLocal => {
                for l in &levels {
                    for n in ["xy", "xz", "yz"] {
                        self.push(format!("{l}.rho_{n}"), 0.0, -0.8, 0.8);
                    }
                }
            }
            Kind::JointRotation | Kind::JointPose | Kind::JointLocal => {
                for l in &levels {
                    for a in ["x", "y", "z"] {
                        self.push(format!("{l}.rot_{a}_rad"), 0.0, -0.4, 0.4);
                    }
                    if self.offsets {
                        for a in ["x", "y", "z"] {
                            self.push(format!("{l}.offset_{a}_mm"), 0.0, -10.0, 10.0);
                        }
                    }
                }
            }
            Kind::Preload => self.push_preload(sim),
        }
    }

    /// The preload gain: `beta * (largest axial compression)` starts at 0.2.
    fn push_preload(&mut self, sim: &Sim) {
        let k_ty = sim
            .k_nominal
            .iter()
            .map(|k| k[4])
            .fold(f64::INFINITY, f64::min);
        let fmax = max_follower(sim);
        let dy = (fmax / k_ty).max(1e-7);
        self.push(
            "log_beta_per_m".into(),
            (0.2 / dy).ln(),
            (1e-3 / dy).ln(),
            (20.0 / dy).ln(),
        );
    }

    /// Two effects at once: `a` and `b` (fitted alone at `xa`, `xb`, of
    /// different effects) in one family started from both fits. The global
    /// block is `a`'s or `b`'s (the level-dependent one's when there is one,
    /// since its law is built first); the other family adds its own
    /// parameters after it.
    pub fn pair(a: &Family, xa: &[f64], b: &Family, xb: &[f64]) -> Family {
        let ((base, xbase), (add, xadd)) = if b.kind.order() < a.kind.order() {
            ((b, xb), (a, xa))
        } else {
            ((a, xa), (b, xb))
        };
        let mut f = base.clone();
        f.add = None;
        f.x0 = xbase.to_vec();
        let mut second = add.clone();
        second.add = None;
        second.x0 = xadd.to_vec();
        for i in second.n_global()..second.n() {
            let x0 = xadd.get(i).copied().unwrap_or(second.x0[i]);
            f.push(second.names[i].clone(), x0, second.lo[i], second.hi[i]);
        }
        f.add = Some(Box::new(second));
        f
    }

    /// The effects the family adds (two for a pair).
    pub fn effects(&self) -> Vec<Effect> {
        let mut v = vec![self.kind.effect()];
        v.extend(self.add.as_ref().map(|a| a.kind.effect()));
        v
    }

    /// Label of the variant (`a+b` for a pair; the DoFs of a per-DoF
    /// kind that acts on some of the three only, e.g. `level_trend[rz]`).
    pub fn label(&self) -> String {
        let one = |f: &Family| {
            let per_dof = matches!(f.kind, Kind::LevelTrend | Kind::AsymmetricBilinear);
            if per_dof && f.dofs.len() < 3 {
                let d: Vec<&str> = f.dofs.iter().map(|&d| DOF3[d]).collect();
                format!("{}[{}]", f.kind.label(), d.join(","))
            } else {
                f.kind.label().to_string()
            }
        };
        match &self.add {
            Some(a) => format!("{}+{}", one(self), one(a)),
            None => one(self),
        }
    }

    /// The variants of a per-DoF kind (trend, shared asymmetry) on every
    /// non-empty subset of the DoFs its full family has: the data may show
    /// the effect about some axes only (a trend in flexion, none in axial
    /// rotation), and a parameter for an axis without it only adds noise
    /// to the prediction of a level the fit has not seen.
    pub fn dof_subsets(kind: Kind, sim: &Sim, start_global: [f64; 3]) -> Vec<Family> {
        let full = Family::new(kind, sim, start_global);
        let n = full.dofs.len();
        if !matches!(kind, Kind::LevelTrend | Kind::AsymmetricBilinear) {
            return vec![full];
        }
        // no DoF to act on: the baseline again
        if n == 0 {
            return Vec::new();
        }
        if n == 1 {
            return vec![full];
        }
        (1..(1usize << n))
            .map(|m| {
                let keep: Vec<usize> = (0..n).filter(|i| m & (1 << i) != 0).collect();
                let mut f = full.clone();
                f.dofs = keep.iter().map(|&i| full.dofs[i]).collect();
                f.names = full.names[..3].to_vec();
                f.names
                    .extend(keep.iter().map(|&i| full.names[3 + i].clone()));
                let pick = |v: &[f64]| -> Vec<f64> {
                    v[..3]
                        .iter()
                        .copied()
                        .chain(keep.iter().map(|&i| v[3 + i]))
                        .collect()
                };
                f.x0 = pick(&full.x0);
                f.lo = pick(&full.lo);
                f.hi = pick(&full.hi);
                f
            })
            .collect()
    }

    /// Size of the global block (0 for LevelPerDof, whose per-level block
    /// replaces it).
    fn n_global(&self) -> usize {
        if self.kind == Kind::LevelPerDof {
            0
        } else {
            3
        }
    }

    /// The fitted parameters `x` in physical units, keyed by name with the
    /// unit in it: rotational stiffness in N*m/rad and as a ratio to the
    /// nominal, stiffness ratios, sinh rate (1/rad), cubic coefficient
    /// (N*m/rad^3), correlations, joint rotations (deg) and offsets (mm),
    /// preload gain (1/mm of axial compression). Stiffness of global
    /// factors is given at the first level (the nominal is the same at
    /// every level of the format's specimens).
    pub fn physical_params(&self, sim: &Sim, x: &[f64]) -> std::collections::BTreeMap<String, f64> {
        let mut out = std::collections::BTreeMap::new();
        let scale = rotation_scale(sim);
        let level = |name: &str| sim.levels.iter().position(|l| l.level.name == name);
        let kn = |li: usize, d: usize| sim.k_nominal.get(li).map(|k| k[d]).unwrap_or(f64::NAN);
        // the global factor of DoF d (1 for per-level-per-DoF families)
        let global = |d: usize| {
            if self.kind == Kind::LevelPerDof {
                1.0
            } else {
                x.get(d).map(|v| v.exp()).unwrap_or(1.0)
            }
        };
        for (name, v) in self.names.iter().zip(x) {
            let (lvl, key) = match name.split_once('.') {
                Some((l, k)) => (Some(l), k),
                None => (None, name.as_str()),
            };
            let li = lvl.and_then(level);
            let pre = lvl.map(|l| format!("{l}.")).unwrap_or_default();
            let dof = DOF3.iter().position(|d| key.ends_with(d)).unwrap_or(0);
            if let Some(d) = key
                .strip_prefix("log_k_")
                .and_then(|d| DOF3.iter().position(|x| *x == d))
            {
                let l = li.unwrap_or(0);
                out.insert(format!("{pre}k_{}_ratio_to_nominal", DOF3[d]), v.exp());
                out.insert(format!("{pre}k_{}_N*m/rad", DOF3[d]), kn(l, d) * v.exp());
            } else if let Some(d) = key
                .strip_prefix("trend_log_k_")
                .and_then(|k| k.strip_suffix("_per_level"))
            {
                out.insert(format!("k_{d}_ratio_per_level"), v.exp());
                if let Some((near, far)) = trend_span(sim) {
                    let span = sim.position[far] - sim.position[near];
                    let key = format!(
                        "k_{d}_ratio_{}_to_{}",
                        sim.levels[far].level.name, sim.levels[near].level.name
                    );
                    out.insert(key, (v * span).exp());
                }
            } else if key == "log_m" {
                out.insert(
                    format!("{pre}k_ratio_to_{}", sim.levels[0].level.name),
                    v.exp(),
                );
            } else if key.starts_with("log_lambda_") {
                out.insert(format!("lambda_{}_1/rad", DOF3[dof]), v.exp());
            } else if key.starts_with("log_c_") {
                let c = kn(0, dof) * global(dof) * v.exp() / (scale[dof] * scale[dof]);
                out.insert(format!("c_{}_N*m/rad^3", DOF3[dof]), c);
            } else if key.starts_with("log_kpos_over_kneg_") {
                out.insert(format!("{pre}kpos_over_kneg_{}", DOF3[dof]), v.exp());
            } else if key.starts_with("rho_") {
                out.insert(format!("{pre}{key}_ratio"), *v);
            } else if let Some(a) = key
                .strip_prefix("rot_")
                .and_then(|k| k.strip_suffix("_rad"))
            {
                out.insert(format!("{pre}rot_{a}_deg"), v.to_degrees());
            } else if key == "log_beta_per_m" {
                out.insert("beta_1/mm_of_compression".into(), v.exp() * 1e-3);
            } else {
                out.insert(name.clone(), *v);
            }
        }
        out
    }

    /// Number of parameters.
    pub fn n(&self) -> usize {
        self.x0.len()
    }

    /// Block index of each masked level (its parameters' position among
    /// the masked levels), `None` for the others.
    fn block_index(&self, nl: usize) -> Vec<Option<usize>> {
        let mut block = vec![None; nl];
        let mut nb = 0;
        for (li, m) in self.mask.iter().enumerate().take(nl) {
            if *m {
                block[li] = Some(nb);
                nb += 1;
            }
        }
        block
    }

    /// Every level's linear parts from the global block of `x` (per level
    /// and DoF for LevelPerDof): the nominal rotational stiffness scaled by
    /// exp of the log-factors, translations nominal. The reference
    /// stiffness is the global one (for LevelPerDof the geometric mean of
    /// the levels').
    fn initial_parts(&self, sim: &Sim, x: &[f64]) -> Vec<LawParts> {
        let get = |i: usize| x.get(i).copied().unwrap_or(0.0);
        let mut parts: Vec<LawParts> = (0..sim.levels.len())
            .map(|li| {
                let kn = sim.k_nominal[li];
                let mut k = kn;
                for d in 0..3 {
                    let i = if self.kind == Kind::LevelPerDof {
                        3 * li + d
                    } else {
                        d
                    };
                    k[d] = kn[d] * get(i).exp();
                }
                LawParts::new(k, sim.nominal[li].damping())
            })
            .collect();
        if self.kind == Kind::LevelPerDof && !parts.is_empty() {
            let n = parts.len() as f64;
            for d in 0..3 {
                let g = (parts.iter().map(|p| p.k[d].ln()).sum::<f64>() / n).exp();
                parts.iter_mut().for_each(|p| p.k_ref[d] = g);
            }
        }
        parts
    }

    /// Add this family's effect, of own parameters `own` (after the global
    /// block), to every level's parts and joint frames.
    fn apply(
        &self,
        sim: &Sim,
        own: &[f64],
        parts: &mut [LawParts],
        frames: &mut [Option<Isometry3<f64>>],
    ) {
        let get = |i: usize| own.get(i).copied().unwrap_or(0.0);
        let scale = rotation_scale(sim);
        let block = self.block_index(parts.len());
        for (li, p) in parts.iter_mut().enumerate() {
            match self.kind {
                Kind::Baseline | Kind::LevelPerDof => {}
                Kind::LevelScalar if li > 0 => {
                    let m = get(li - 1).exp();
                    for kd in p.k.iter_mut().take(3) {
                        *kd *= m;
                    }
                }
                Kind::LevelScalar => {}
                Kind::LevelTrend => {
                    let z = sim.position.get(li).copied().unwrap_or(0.0) - mean_position(sim);
                    for (j, &d) in self.dofs.iter().enumerate() {
                        p.k[d] *= (get(j) * z).exp();
                    }
                }
                // the deflection scale follows the level's own compliance
                // (factor 1 without a level effect)
                Kind::NonlinearSinh => {
                    for d in 0..3 {
                        let r = p.k_ref[d] / p.k[d];
                        let (k, a) = (p.k[d], (-get(d)).exp() * r);
                        p.rot[d] = Some(Curve::Sinh { k, a });
                    }
                }
                Kind::NonlinearCubic => {
                    for d in 0..3 {
                        let (k, r) = (p.k[d], p.k[d] / p.k_ref[d]);
                        let c = k * get(d).exp() / (scale[d] * scale[d]) * (r * r);
                        p.rot[d] = Some(Curve::Cubic { k, c });
                    }
                }
                Kind::AsymmetricBilinear => {
                    for (j, &d) in self.dofs.iter().enumerate() {
                        one_sided(p, d, true, get(j).exp());
                    }
                }
                Kind::AsymmetricPerLevel => {
                    // one-sided stiffening: a > 0 stiffens the positive
                    // side, a < 0 the negative side, by exp(|a|)
                    for d in 0..3 {
                        let a = block[li].map(|b| get(3 * b + d)).unwrap_or(0.0);
                        one_sided(p, d, a >= 0.0, a.abs().exp());
                    }
                }
                Kind::CoupledUniform | Kind::CoupledPerLevel | Kind::CoupledLocal => {
                    let off = match (self.kind, block[li]) {
                        (Kind::CoupledUniform, _) => Some(0),
                        (_, Some(b)) => Some(3 * b),
                        _ => None,
                    };
                    // K_ij = rho_ij sqrt(k_i k_j) (shared with calibration's coupled form)
                    p.rho = Some(std::array::from_fn(|n| {
                        off.map(|o| get(o + n)).unwrap_or(0.0)
                    }));
                }
                Kind::JointRotation | Kind::JointPose | Kind::JointLocal => {
                    if let Some(b) = block[li] {
                        frames[li] = Some(self.frame_change(&get, b));
                    }
                }
                Kind::Preload => p.beta = Some(get(0).exp()),
            }
        }
    }

    /// The rigid change of the joint frames of block `b` (pose kinds): a
    /// rotation vector (rad) and, with offsets, a translation (mm).
    fn frame_change(&self, get: &dyn Fn(usize) -> f64, b: usize) -> Isometry3<f64> {
        let per = if self.offsets { 6 } else { 3 };
        let o = per * b;
        let w = Vector3::new(get(o), get(o + 1), get(o + 2));
        let t = if self.offsets {
            Vector3::new(get(o + 3), get(o + 4), get(o + 5)) * 1e-3
        } else {
            Vector3::zeros()
        };
        Isometry3::from_parts(Translation3::from(t), UnitQuaternion::from_scaled_axis(w))
    }

    /// The laws and frames of parameters `x`: the linear parts of the
    /// global block, this family's effect, then the added family's.
    pub fn variant(&self, sim: &Sim, x: &[f64]) -> Result<Variant> {
        let nl = sim.levels.len();
        let mut parts = self.initial_parts(sim, x);
        let mut frames = vec![None; nl];
        let add_len = self.add.as_ref().map(|a| a.n() - a.n_global()).unwrap_or(0);
        let split = self.n().saturating_sub(add_len);
        let own = x.get(self.n_global()..split.min(x.len())).unwrap_or(&[]);
        self.apply(sim, own, &mut parts, &mut frames);
        if let Some(a) = &self.add {
            let own = x.get(split.min(x.len())..).unwrap_or(&[]);
            a.apply(sim, own, &mut parts, &mut frames);
        }
        let mut laws = Vec::with_capacity(nl);
        let mut expressions = Vec::with_capacity(nl);
        for p in &parts {
            let (law, ex) = p.model()?;
            laws.push(law);
            expressions.push(ex);
        }
        Ok(Variant {
            laws,
            frames,
            expressions,
        })
    }

    /// The solver system of parameters `x`.
    pub fn system(&self, sim: &Sim, x: &[f64]) -> Result<System> {
        let v = self.variant(sim, x)?;
        apply_variant(sim, &v)
    }
}

/// The mean position of the levels along the spine (the trend's centre).
pub fn mean_position(sim: &Sim) -> f64 {
    let n = sim.position.len().max(1) as f64;
    sim.position.iter().sum::<f64>() / n
}

/// The levels nearest to and farthest from the fixed body (the ends of a
/// trend), `None` with fewer than two distinct positions.
pub fn trend_span(sim: &Sim) -> Option<(usize, usize)> {
    let by = |a: &usize, b: &usize| sim.position[*a].total_cmp(&sim.position[*b]);
    let near = (0..sim.position.len()).min_by(by)?;
    let far = (0..sim.position.len()).max_by(by)?;
    (sim.position[far] > sim.position[near]).then_some((near, far))
}

/// A one-sided stiffening of rotational DoF `d` by `factor` on the
/// positive (or negative) side: a bilinear curve on a linear DoF, an
/// added one-sided term on a curved one (mixed effects).
fn one_sided(p: &mut LawParts, d: usize, positive: bool, factor: f64) {
    let k = p.k[d];
    match p.rot[d] {
        None => {
            let (k_neg, k_pos) = if positive {
                (k, k * factor)
            } else {
                (k * factor, k)
            };
            p.rot[d] = Some(Curve::Bilinear { k_neg, k_pos });
        }
        Some(_) => {
            p.one_sided[d] = Some(OneSided {
                positive,
                threshold: 0.0,
                factor,
            })
        }
    }
}

/// Put a variant into a copy of the nominal system.
pub fn apply_variant(sim: &Sim, v: &Variant) -> Result<System> {
    let laws = sim
        .levels
        .iter()
        .zip(&v.laws)
        .map(|(l, law)| (l.bushing, law.clone()));
    let mut sys = sim.base.with_bushing_models(laws)?;
    for (li, l) in sim.levels.iter().enumerate() {
        if let Some(Some(t)) = v.frames.get(li) {
            let (x1, x2) = sim.frames[li];
            sys = sys.with_bushing_joint_frames(l.bushing, &(x1 * t), &(x2 * t))?;
        }
    }
    Ok(sys)
}

/// Largest follower load (N) of the experiment's cases (0 when none).
pub fn max_follower(sim: &Sim) -> f64 {
    sim.loads
        .iter()
        .flatten()
        .filter_map(|l| match l {
            crate::solver::Load::Follower { magnitude, .. } => Some(*magnitude),
            _ => None,
        })
        .fold(0.0, f64::max)
}
