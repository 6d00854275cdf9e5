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
//! | `nonlinear_stiffness` / `sinh` | per DoF `lambda_d = exp(s_d)`: `M = k sinh(lambda th) / lambda` | FunctionBased/ExpressionBased |
//! | `nonlinear_stiffness` / `cubic` | per DoF `c_d = k_d exp(s_d)`: `M = k th + c th^3` | FunctionBasedBushingForce (PolynomialFunction) |
//! | `asymmetric_stiffness` / `bilinear` | per DoF `k+ = k- exp(a_d)` | FunctionBasedBushingForce (PiecewiseLinearFunction) |
//! | `asymmetric_stiffness` / `per_level` | per level and DoF one-sided stiffening `exp(|a_ld|)` of the positive (`a > 0`) or negative (`a < 0`) side (levels of the mask; others symmetric) | idem |
//! | `coupled_stiffness` / `uniform` | 3 correlations `rho_ij`, `K_ij = rho_ij sqrt(k_i k_j)` | ExpressionBasedBushingForce (linear) |
//! | `coupled_stiffness` / `per_level` | 3 correlations per level | idem |
//! | `joint_pose_error` / `rotation` | per level a rotation vector (rad) of both joint frames | linear, joint frames moved |
//! | `joint_pose_error` / `pose` | per level rotation vector and offset (mm) of both joint frames | idem |
//! | `preload_stiffening` | `beta = exp(b)` (1/m): rotational `M = k th (1 + beta max(0, -delta_y))` | ExpressionBasedBushingForce |

use super::sim::Sim;
use crate::error::{Error, Result};
use crate::solver::{BushingModel, Curve, Expr, System};
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use serde::Serialize;

/// The vocabulary of `diagnosis.json` (`verdict.effect`), without `unidentifiable`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Effect {
    None,
    LevelDependentStiffness,
    NonlinearStiffness,
    AsymmetricStiffness,
    CoupledStiffness,
    JointPoseError,
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
    Baseline,
    LevelScalar,
    LevelPerDof,
    NonlinearSinh,
    NonlinearCubic,
    AsymmetricBilinear,
    /// Bilinear asymmetry with its own ratios at each level of the mask
    /// (an asymmetry at some levels only).
    AsymmetricPerLevel,
    CoupledUniform,
    CoupledPerLevel,
    /// Coupling at the levels of the family's mask only (a local effect).
    CoupledLocal,
    JointRotation,
    JointPose,
    /// Joint pose error at the levels of the mask only.
    JointLocal,
    Preload,
}

impl Kind {
    /// The effect this family adds.
    pub fn effect(&self) -> Effect {
        match self {
            Kind::Baseline => Effect::None,
            Kind::LevelScalar | Kind::LevelPerDof => Effect::LevelDependentStiffness,
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
}

const DOF3: [&str; 3] = ["rx", "ry", "rz"];

/// A family instantiated on an experiment: parameter names, start, box.
#[derive(Debug, Clone)]
pub struct Family {
    pub kind: Kind,
    /// Levels that carry per-level parameters (all for the per-level
    /// kinds; one or a few for the local kinds).
    pub mask: Vec<bool>,
    /// Joint offsets (mm) are parameters (pose kinds).
    pub offsets: bool,
    pub names: Vec<String>,
    pub x0: Vec<f64>,
    pub lo: Vec<f64>,
    pub hi: Vec<f64>,
}

/// What a parameter vector means, level by level.
#[derive(Debug, Clone)]
pub struct Variant {
    /// Force law of each level.
    pub laws: Vec<BushingModel>,
    /// Rigid change `T` of each level's joint frames (both frames become
    /// `X * T`), identity when unchanged.
    pub frames: Vec<Option<Isometry3<f64>>>,
    /// The preload expressions, when the family writes expressions.
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
            mask: mask.clone(),
            offsets,
            names: Vec::new(),
            x0: Vec::new(),
            lo: Vec::new(),
            hi: Vec::new(),
        };
        let push = |f: &mut Family, name: String, x0: f64, lo: f64, hi: f64| {
            f.names.push(name);
            f.x0.push(x0.clamp(lo, hi));
            f.lo.push(lo);
            f.hi.push(hi);
        };
        let gbox = 4.0; // factor e^4 ~ 55 either way
        if kind != Kind::LevelPerDof {
            for (d, g) in start_global.iter().enumerate() {
                push(&mut f, format!("log_k_{}", DOF3[d]), *g, -gbox, gbox);
            }
        }
        let scale = rotation_scale(sim);
        match kind {
            Kind::Baseline => {}
            Kind::LevelScalar => {
                for l in sim.levels.iter().skip(1) {
                    push(&mut f, format!("{}.log_m", l.name), 0.0, -3.0, 3.0);
                }
            }
            Kind::LevelPerDof => {
                for l in &sim.levels {
                    for (d, g) in start_global.iter().enumerate() {
                        push(
                            &mut f,
                            format!("{}.log_k_{}", l.name, DOF3[d]),
                            *g,
                            -gbox,
                            gbox,
                        );
                    }
                }
            }
            Kind::NonlinearSinh => {
                // lambda = 1/a; start where the curve stiffens by ~20% at the largest rotation
                for d in 0..3 {
                    let l0 = (1.0 / scale[d]).ln();
                    push(
                        &mut f,
                        format!("log_lambda_{}", DOF3[d]),
                        l0,
                        l0 - 6.0,
                        l0 + 3.0,
                    );
                }
            }
            Kind::NonlinearCubic => {
                // c = k exp(s) / scale^2: start at ~10% extra stiffness at the largest rotation
                for d in 0..3 {
                    push(
                        &mut f,
                        format!("log_c_{}", DOF3[d]),
                        (0.1f64).ln(),
                        -12.0,
                        5.0,
                    );
                }
            }
            Kind::AsymmetricBilinear => {
                for d in 0..3 {
                    push(
                        &mut f,
                        format!("log_kpos_over_kneg_{}", DOF3[d]),
                        0.0,
                        -3.0,
                        3.0,
                    );
                }
            }
            Kind::AsymmetricPerLevel => {
                for l in sim.levels.iter().zip(&mask).filter(|p| *p.1).map(|p| p.0) {
                    for d in DOF3 {
                        push(
                            &mut f,
                            format!("{}.log_kpos_over_kneg_{d}", l.name),
                            0.0,
                            -3.0,
                            3.0,
                        );
                    }
                }
            }
            Kind::CoupledUniform => {
                for n in ["xy", "xz", "yz"] {
                    push(&mut f, format!("rho_{n}"), 0.0, -0.8, 0.8);
                }
            }
            Kind::CoupledPerLevel | Kind::CoupledLocal => {
                for l in sim.levels.iter().zip(&mask).filter(|p| *p.1).map(|p| p.0) {
                    for n in ["xy", "xz", "yz"] {
                        push(&mut f, format!("{}.rho_{n}", l.name), 0.0, -0.8, 0.8);
                    }
                }
            }
            Kind::JointRotation | Kind::JointPose | Kind::JointLocal => {
                for l in sim.levels.iter().zip(&mask).filter(|p| *p.1).map(|p| p.0) {
                    for a in ["x", "y", "z"] {
                        push(&mut f, format!("{}.rot_{a}_rad", l.name), 0.0, -0.4, 0.4);
                    }
                    if offsets {
                        for a in ["x", "y", "z"] {
                            push(
                                &mut f,
                                format!("{}.offset_{a}_mm", l.name),
                                0.0,
                                -10.0,
                                10.0,
                            );
                        }
                    }
                }
            }
            Kind::Preload => {
                // beta * (largest axial compression) starts at 0.2
                let k_ty = sim
                    .k_nominal
                    .iter()
                    .map(|k| k[4])
                    .fold(f64::INFINITY, f64::min);
                let fmax = max_follower(sim);
                let dy = (fmax / k_ty).max(1e-7);
                push(
                    &mut f,
                    "log_beta_per_m".into(),
                    (0.2 / dy).ln(),
                    (1e-3 / dy).ln(),
                    (20.0 / dy).ln(),
                );
            }
        }
        f
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
        let level = |name: &str| sim.levels.iter().position(|l| l.name == name);
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
            } else if key == "log_m" {
                out.insert(format!("{pre}k_ratio_to_{}", sim.levels[0].name), v.exp());
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

    /// Level `li`'s linear stiffness under parameters `x`: the nominal
    /// `kn` with the rotational terms scaled by exp of the shared (or, per
    /// DoF and level, own) log-factors, and the level factor of
    /// `LevelScalar`.
    fn level_stiffness(&self, kn: [f64; 6], li: usize, x: &[f64]) -> [f64; 6] {
        let get = |i: usize| x.get(i).copied().unwrap_or(0.0);
        let mut k = kn;
        for d in 0..3 {
            let i = if self.kind == Kind::LevelPerDof {
                3 * li + d
            } else {
                d
            };
            k[d] = kn[d] * get(i).exp();
        }
        if self.kind == Kind::LevelScalar && li > 0 {
            let m = get(3 + li - 1).exp();
            for kd in k.iter_mut().take(3) {
                *kd *= m;
            }
        }
        k
    }

    /// The laws and frames of parameters `x`.
    pub fn variant(&self, sim: &Sim, x: &[f64]) -> Result<Variant> {
        let nl = sim.levels.len();
        let get = |i: usize| x.get(i).copied().unwrap_or(0.0);
        let scale = rotation_scale(sim);
        let mut laws = Vec::with_capacity(nl);
        let mut frames = vec![None; nl];
        let mut expressions = vec![None; nl];
        let block = self.block_index(nl);
        for li in 0..nl {
            let damping = sim.nominal[li].damping();
            let k = self.level_stiffness(sim.k_nominal[li], li, x);
            let linear = |k: [f64; 6]| BushingModel::Linear {
                rot_stiffness: Vector3::new(k[0], k[1], k[2]),
                trans_stiffness: Vector3::new(k[3], k[4], k[5]),
                rot_damping: Vector3::new(damping[0], damping[1], damping[2]),
                trans_damping: Vector3::new(damping[3], damping[4], damping[5]),
            };
            let trans_curves = |k: [f64; 6]| -> [Curve; 3] {
                [
                    Curve::Linear { k: k[3] },
                    Curve::Linear { k: k[4] },
                    Curve::Linear { k: k[5] },
                ]
            };
            let law = match self.kind {
                Kind::Baseline | Kind::LevelScalar | Kind::LevelPerDof => linear(k),
                Kind::NonlinearSinh
                | Kind::NonlinearCubic
                | Kind::AsymmetricBilinear
                | Kind::AsymmetricPerLevel => {
                    let rot: [Curve; 3] = std::array::from_fn(|d| {
                        if self.kind == Kind::AsymmetricPerLevel {
                            // one-sided stiffening: a > 0 stiffens the positive
                            // side, a < 0 the negative side, by exp(|a|)
                            let a = block[li].map(|b| get(3 + 3 * b + d)).unwrap_or(0.0);
                            let f = a.abs().exp();
                            return if a >= 0.0 {
                                Curve::Bilinear {
                                    k_neg: k[d],
                                    k_pos: k[d] * f,
                                }
                            } else {
                                Curve::Bilinear {
                                    k_neg: k[d] * f,
                                    k_pos: k[d],
                                }
                            };
                        }
                        let s = get(3 + d);
                        match self.kind {
                            Kind::NonlinearSinh => Curve::Sinh {
                                k: k[d],
                                a: (-s).exp(),
                            },
                            Kind::NonlinearCubic => Curve::Cubic {
                                k: k[d],
                                c: k[d] * s.exp() / (scale[d] * scale[d]),
                            },
                            _ => Curve::Bilinear {
                                k_neg: k[d],
                                k_pos: k[d] * s.exp(),
                            },
                        }
                    });
                    let [t0, t1, t2] = trans_curves(k);
                    let [r0, r1, r2] = rot;
                    BushingModel::PerDof {
                        curves: Box::new([r0, r1, r2, t0, t1, t2]),
                        damping,
                    }
                }
                Kind::CoupledUniform | Kind::CoupledPerLevel | Kind::CoupledLocal => {
                    let off = match (self.kind, block[li]) {
                        (Kind::CoupledUniform, _) => Some(3),
                        (_, Some(b)) => Some(3 + 3 * b),
                        _ => None,
                    };
                    // K_ij = rho_ij sqrt(k_i k_j) (shared with calibration's coupled form)
                    let rho = std::array::from_fn(|n| off.map(|o| get(o + n)).unwrap_or(0.0));
                    BushingModel::Coupled {
                        stiffness: crate::calibrate::forms::coupled_matrix(&k, rho),
                        damping,
                    }
                }
                Kind::JointRotation | Kind::JointPose | Kind::JointLocal => {
                    let per = if self.offsets { 6 } else { 3 };
                    if let Some(b) = block[li] {
                        let o = 3 + per * b;
                        let w = Vector3::new(get(o), get(o + 1), get(o + 2));
                        let t = if self.offsets {
                            Vector3::new(get(o + 3), get(o + 4), get(o + 5)) * 1e-3
                        } else {
                            Vector3::zeros()
                        };
                        frames[li] = Some(Isometry3::from_parts(
                            Translation3::from(t),
                            UnitQuaternion::from_scaled_axis(w),
                        ));
                    }
                    linear(k)
                }
                Kind::Preload => {
                    let beta = get(3).exp();
                    let ex = preload_expressions(&k, beta);
                    let parsed: Vec<Expr> = ex
                        .iter()
                        .map(|s| {
                            Expr::parse(s).map_err(|e| {
                                Error::invalid("preload expression", format!("{s}: {e}"))
                            })
                        })
                        .collect::<Result<_>>()?;
                    let exprs: [Expr; 6] = parsed
                        .try_into()
                        .map_err(|_| Error::invalid("preload expression", "six expressions"))?;
                    expressions[li] = Some(ex);
                    BushingModel::Expression {
                        exprs: Box::new(exprs),
                        damping,
                    }
                }
            };
            laws.push(law);
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

/// The six Lepton expressions of the preload-stiffening law.
pub fn preload_expressions(k: &[f64; 6], beta: f64) -> [String; 6] {
    let f = crate::util::fmt_f64;
    let g = format!("(1+{}*max(0,-delta_y))", f(beta));
    [
        format!("{}*theta_x*{g}", f(k[0])),
        format!("{}*theta_y*{g}", f(k[1])),
        format!("{}*theta_z*{g}", f(k[2])),
        format!("{}*delta_x", f(k[3])),
        format!("{}*delta_y", f(k[4])),
        format!("{}*delta_z", f(k[5])),
    ]
}
