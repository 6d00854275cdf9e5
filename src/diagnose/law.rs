//! One level's force law assembled from what the effects contribute: the
//! linear stiffness (global and level factors), a rotational curve per DoF
//! (neutral zone / stiffening, bilinear asymmetry), a one-sided extra
//! stiffness beyond a threshold (facet contact), rotational couplings and
//! a preload gain. One contribution gives the native law the single-effect
//! families always had (BushingForce, FunctionBased curves, coupled matrix,
//! preload expressions); several give one ExpressionBasedBushingForce, so
//! that two effects (mixed-effect candidates, two-effect truths) combine
//! into one law that the solver evaluates and OpenSim reads.

use crate::error::{Error, Result};
use crate::solver::{BushingModel, Curve, Expr};
use nalgebra::Vector3;

/// An extra one-sided stiffness of a rotational DoF: beyond `threshold`
/// (rad) on the positive (or negative) side the tangent stiffness is
/// `factor` times the linear one (a threshold facet contact; a bilinear
/// law when the threshold is 0).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OneSided {
    /// Acts on the positive side (else the negative one).
    pub positive: bool,
    /// Deflection beyond which it acts (rad).
    pub threshold: f64,
    /// Tangent stiffness beyond the threshold over the linear one.
    pub factor: f64,
}

/// The contributions to one level's law.
#[derive(Debug, Clone)]
pub struct LawParts {
    /// Linear stiffness `(rx .. tz)`: N m/rad, N/m.
    pub k: [f64; 6],
    /// The stiffness the level-independent effects refer to: `k` before
    /// level factors (a neutral zone or stiffening scales with each level's
    /// own compliance, so that it reaches the same ratio at the same moment).
    pub k_ref: [f64; 6],
    /// Damping `(rx .. tz)`: N m/(rad/s), N/(m/s).
    pub damping: [f64; 6],
    /// Rotational curve of each DoF (`None`: linear with `k`).
    pub rot: [Option<Curve>; 3],
    /// One-sided extra stiffness of each rotational DoF.
    pub one_sided: [Option<OneSided>; 3],
    /// Rotational correlations `rho_xy, rho_xz, rho_yz` (coupled stiffness).
    pub rho: Option<[f64; 3]>,
    /// Preload gain (1/m of axial compression) on the rotational moments.
    pub beta: Option<f64>,
}

/// A number as an expression operand (negative values in parentheses).
fn num(x: f64) -> String {
    let s = crate::util::fmt_f64(x);
    if x < 0.0 {
        format!("({s})")
    } else {
        s
    }
}

const THETA: [&str; 3] = ["theta_x", "theta_y", "theta_z"];
const DELTA: [&str; 3] = ["delta_x", "delta_y", "delta_z"];

impl LawParts {
    /// Linear, uncoupled parts.
    pub fn new(k: [f64; 6], damping: [f64; 6]) -> LawParts {
        LawParts {
            k,
            k_ref: k,
            damping,
            rot: [None, None, None],
            one_sided: [None; 3],
            rho: None,
            beta: None,
        }
    }

    /// The linear BushingForce of `k`.
    fn linear(&self) -> BushingModel {
        let (k, c) = (self.k, self.damping);
        BushingModel::Linear {
            rot_stiffness: Vector3::new(k[0], k[1], k[2]),
            trans_stiffness: Vector3::new(k[3], k[4], k[5]),
            rot_damping: Vector3::new(c[0], c[1], c[2]),
            trans_damping: Vector3::new(c[3], c[4], c[5]),
        }
    }

    /// Rotational curve of DoF `d` (linear with `k` when unset).
    fn curve(&self, d: usize) -> Curve {
        self.rot[d]
            .clone()
            .unwrap_or(Curve::Linear { k: self.k[d] })
    }

    /// The law and, for an expression law, its six expressions.
    pub fn model(&self) -> Result<(BushingModel, Option<[String; 6]>)> {
        let shaped = self.rot.iter().any(Option::is_some);
        let sided = self.one_sided.iter().any(Option::is_some);
        match (shaped, sided, self.rho, self.beta) {
            (false, false, None, None) => Ok((self.linear(), None)),
            (true, false, None, None) => {
                // native per-DoF curves (FunctionBasedBushingForce)
                let k = self.k;
                let curves = Box::new([
                    self.curve(0),
                    self.curve(1),
                    self.curve(2),
                    Curve::Linear { k: k[3] },
                    Curve::Linear { k: k[4] },
                    Curve::Linear { k: k[5] },
                ]);
                let damping = self.damping;
                Ok((BushingModel::PerDof { curves, damping }, None))
            }
            (false, false, Some(rho), None) => {
                let stiffness = crate::calibrate::forms::coupled_matrix(&self.k, rho);
                let damping = self.damping;
                Ok((BushingModel::Coupled { stiffness, damping }, None))
            }
            (false, false, None, Some(beta)) => self.expression(preload_expressions(&self.k, beta)),
            _ => self.expression(self.general_expressions()),
        }
    }

    /// An expression law of `ex`.
    fn expression(&self, ex: [String; 6]) -> Result<(BushingModel, Option<[String; 6]>)> {
        let parsed: Vec<Expr> = ex
            .iter()
            .map(|s| {
                Expr::parse(s).map_err(|e| Error::invalid("law expression", format!("{s}: {e}")))
            })
            .collect::<Result<_>>()?;
        let exprs: [Expr; 6] = parsed
            .try_into()
            .map_err(|_| Error::invalid("law expression", "six expressions"))?;
        let damping = self.damping;
        let model = BushingModel::Expression {
            exprs: Box::new(exprs),
            damping,
        };
        Ok((model, Some(ex)))
    }

    /// The diagonal moment of DoF `d`: its curve plus the one-sided term.
    fn diagonal(&self, d: usize) -> String {
        let t = THETA[d];
        let mut s = match self.curve(d) {
            Curve::Sinh { k, a } => format!("{}*{}*sinh({t}/{})", num(k), num(a), num(a)),
            Curve::Cubic { k, c } => format!("({}*{t}+{}*{t}^3)", num(k), num(c)),
            // the slope k_neg, plus the difference beyond 0 (never a zero
            // slope at 0, where max and min have no derivative)
            Curve::Bilinear { k_neg, k_pos } => {
                format!("({}*{t}+{}*max(0,{t}))", num(k_neg), num(k_pos - k_neg))
            }
            Curve::Linear { k } => format!("{}*{t}", num(k)),
            Curve::Function(_) => format!("{}*{t}", num(self.k[d])),
        };
        if let Some(o) = self.one_sided[d] {
            // beyond the threshold the tangent stiffness is factor * k
            let kc = num((o.factor - 1.0) * self.k[d]);
            let th = num(o.threshold);
            if o.positive {
                s = format!("{s}+{kc}*max(0,{t}-{th})");
            } else {
                s = format!("{s}-{kc}*max(0,-{t}-{th})");
            }
        }
        s
    }

    /// Every contribution as Lepton expressions: the rotational moments
    /// `g (diag_i + sum_j K_ij theta_j)` with `g` the preload factor and
    /// `K` the coupled matrix's off-diagonal terms; linear forces.
    fn general_expressions(&self) -> [String; 6] {
        let kmat = self
            .rho
            .map(|rho| crate::calibrate::forms::coupled_matrix(&self.k, rho));
        let g = self
            .beta
            .map(|b| format!("*(1+{}*max(0,-delta_y))", num(b)))
            .unwrap_or_default();
        std::array::from_fn(|i| {
            if i >= 3 {
                return format!("{}*{}", num(self.k[i]), DELTA[i - 3]);
            }
            let mut m = self.diagonal(i);
            if let Some(km) = &kmat {
                for j in (0..3).filter(|&j| j != i) {
                    m = format!("{m}+{}*{}", num(km[(i, j)]), THETA[j]);
                }
            }
            if g.is_empty() {
                m
            } else {
                format!("({m}){g}")
            }
        })
    }
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

#[cfg(test)]
mod tests {
    use super::*;

    fn moment(m: &BushingModel, th: [f64; 3], dy: f64) -> [f64; 3] {
        match m {
            BushingModel::Expression { exprs, .. } => {
                let q = [th[0], th[1], th[2], 0.0, dy, 0.0];
                std::array::from_fn(|i| exprs[i].eval::<f64>(&q))
            }
            _ => panic!("not an expression law"),
        }
    }

    #[test]
    fn one_contribution_keeps_the_native_law() {
        let k = [10.0, 20.0, 30.0, 1e5, 2e5, 3e5];
        let mut p = LawParts::new(k, [0.0; 6]);
        assert!(matches!(p.model().unwrap().0, BushingModel::Linear { .. }));
        p.rot[2] = Some(Curve::Sinh { k: 30.0, a: 0.05 });
        assert!(matches!(p.model().unwrap().0, BushingModel::PerDof { .. }));
        let mut c = LawParts::new(k, [0.0; 6]);
        c.rho = Some([0.3, 0.0, 0.0]);
        assert!(matches!(c.model().unwrap().0, BushingModel::Coupled { .. }));
        let mut b = LawParts::new(k, [0.0; 6]);
        b.beta = Some(200.0);
        let (m, ex) = b.model().unwrap();
        assert_eq!(ex.unwrap(), preload_expressions(&k, 200.0));
        assert!(matches!(m, BushingModel::Expression { .. }));
    }

    #[test]
    fn two_contributions_combine_in_one_expression() {
        let k = [10.0, 20.0, 30.0, 1e5, 2e5, 3e5];
        let mut p = LawParts::new(k, [0.0; 6]);
        p.rot[0] = Some(Curve::Cubic { k: 10.0, c: 400.0 });
        p.one_sided[0] = Some(OneSided {
            positive: false,
            threshold: 0.01,
            factor: 3.0,
        });
        p.rho = Some([0.5, 0.0, 0.0]);
        p.beta = Some(100.0);
        let (m, _) = p.model().unwrap();
        let (th, dy): ([f64; 3], f64) = ([-0.05, 0.02, 0.0], -0.002);
        let g = 1.0 + 100.0 * 0.002;
        let kxy = 0.5 * (10.0f64 * 20.0).sqrt();
        // cubic curve, contact beyond -0.01 rad at (3 - 1) k, coupling, preload
        let mx = g * (10.0 * th[0] + 400.0 * th[0].powi(3) - 20.0 * (0.05 - 0.01) + kxy * th[1]);
        let my = g * (20.0 * th[1] + kxy * th[0]);
        let got = moment(&m, th, dy);
        assert!((got[0] - mx).abs() < 1e-12, "{} {mx}", got[0]);
        assert!((got[1] - my).abs() < 1e-12, "{} {my}", got[1]);
        assert!(got[2].abs() < 1e-15);
        // the expression of a native law evaluates like the native law
        let mut s = LawParts::new(k, [0.0; 6]);
        s.rot[1] = Some(Curve::Sinh { k: 20.0, a: 0.04 });
        s.beta = Some(0.0);
        let (m, _) = s.model().unwrap();
        let want = Curve::Sinh { k: 20.0, a: 0.04 }.eval(0.1f64);
        assert!((moment(&m, [0.0, 0.1, 0.0], 0.0)[1] - want).abs() < 1e-12);
    }
}
