//! Calibration outputs: the JSON report structure, per-case errors and the
//! SVG figures (measured vs predicted per level and DoF; parameter spread
//! over the multi-start with confidence intervals), drawn with
//! [`crate::util::charts`]. [`calibrated_document`] is the
//! calibrated `.osim` (the family's laws written by the stiffness writer).

use super::experiment::DOF_NAMES;
use super::fit::{Calibration, ErrorTable};
use super::problem::Problem;
use serde::Serialize;

/// Errors of one load case (experiment units).
#[derive(Debug, Clone, Serialize)]
pub struct CaseError {
    /// Load case id.
    pub case: String,
    /// RMSE over the case's measured rotational cells in the cost.
    pub rotation_rmse: Option<f64>,
    /// RMSE over the case's measured translational cells in the cost.
    pub translation_rmse: Option<f64>,
}

/// Per-case RMSEs of `pred` (SI) over the problem's cells, in file units.
pub fn case_errors(pb: &Problem, pred: &[[f64; 6]]) -> Vec<CaseError> {
    pb.exp
        .cases
        .iter()
        .enumerate()
        .filter_map(|(ci, c)| {
            let mut acc = [(0.0, 0usize); 2];
            for cell in pb.cells.iter().filter(|cell| cell.case == ci) {
                let e = (pred[cell.row][cell.dof] - cell.measured) * pb.exp.units.from_si(cell.dof);
                let k = usize::from(cell.dof >= 3);
                acc[k].0 += e * e;
                acc[k].1 += 1;
            }
            if acc[0].1 + acc[1].1 == 0 {
                return None;
            }
            let f = |(ss, n): (f64, usize)| (n > 0).then(|| (ss / n as f64).sqrt());
            Some(CaseError {
                case: c.id.clone(),
                rotation_rmse: f(acc[0]),
                translation_rmse: f(acc[1]),
            })
        })
        .collect()
}

/// One measured row with its prediction (experiment units).
#[derive(Debug, Clone, Serialize)]
pub struct RowOut {
    /// Load case id.
    pub case: String,
    /// Cranial body.
    pub upper: String,
    /// Caudal body.
    pub lower: String,
    /// Measured increments, rx..tz (`None` where not measured).
    pub measured: [Option<f64>; 6],
    /// Predicted increments, rx..tz.
    pub predicted: [f64; 6],
}

/// Rows with predictions in file units.
pub fn rows_out(pb: &Problem, pred: &[[f64; 6]]) -> Vec<RowOut> {
    pb.exp
        .rows
        .iter()
        .zip(pred)
        .map(|(r, p)| RowOut {
            case: pb
                .exp
                .cases
                .get(r.case)
                .map(|c| c.id.clone())
                .unwrap_or_default(),
            upper: r.upper.clone(),
            lower: r.lower.clone(),
            measured: std::array::from_fn(|d| r.values[d].map(|v| v * pb.exp.units.from_si(d))),
            predicted: std::array::from_fn(|d| p[d] * pb.exp.units.from_si(d)),
        })
        .collect()
}

/// Summary of a model's fit to the data.
#[derive(Debug, Clone, Serialize)]
pub struct FitSummary {
    /// Pooled RMSE of rotations / translations (experiment units).
    pub rotation_rmse: f64,
    /// Pooled translation RMSE; `None` when no translation is in the cost.
    pub translation_rmse: Option<f64>,
    /// Errors per load case.
    pub per_case: Vec<CaseError>,
    /// Errors per level (pair) and DoF.
    pub per_level_dof: ErrorTable,
}

/// A tick label: 3 significant decimals near 1, scientific far from it.
fn nice(v: f64) -> String {
    let a = v.abs();
    if a == 0.0 {
        "0".into()
    } else if !(1e-3..1e4).contains(&a) {
        format!("{v:.1e}")
    } else if a >= 100.0 {
        format!("{v:.0}")
    } else if a >= 1.0 {
        format!("{v:.2}")
    } else {
        format!("{v:.3}")
    }
}

/// Measured vs predicted scatter, one panel per level (pair) and cost DoF,
/// identity line in each panel, experiment units.
pub fn fit_svg(pb: &Problem, pred: &[[f64; 6]], title: &str) -> String {
    use crate::util::charts::{self, Axis, Layer, LayerKind, XyFigure, XyPanel};
    let mut pairs: Vec<(String, String)> = Vec::new();
    for r in &pb.exp.rows {
        let k = (r.upper.clone(), r.lower.clone());
        if !pairs.contains(&k) {
            pairs.push(k);
        }
    }
    let dofs = &pb.opts.dofs;
    let mut panels = Vec::new();
    for (u, l) in &pairs {
        for &d in dofs {
            let f = pb.exp.units.from_si(d);
            let pts: Vec<(f64, f64)> = pb
                .exp
                .rows
                .iter()
                .enumerate()
                .filter(|(_, r)| &r.upper == u && &r.lower == l)
                .filter_map(|(ri, r)| Some((r.values[d]? * f, pred.get(ri)?[d] * f)))
                .collect();
            let unit = if d < 3 {
                pb.exp.units.angle
            } else {
                pb.exp.units.length
            };
            let lo = pts.iter().fold(f64::INFINITY, |m, p| m.min(p.0).min(p.1));
            let hi = pts
                .iter()
                .fold(f64::NEG_INFINITY, |m, p| m.max(p.0).max(p.1));
            let (lo, hi) = if lo.is_finite() && hi - lo >= 1e-12 {
                (lo, hi)
            } else if lo.is_finite() {
                (lo - 1.0, hi + 1.0)
            } else {
                (-1.0, 1.0)
            };
            let pad = 0.05 * (hi - lo);
            let range = (lo - pad, hi + pad);
            panels.push(XyPanel {
                title: format!("{u}/{l} {}", DOF_NAMES[d]),
                x: Axis {
                    label: format!("measured ({unit})"),
                    range,
                },
                y: Axis {
                    label: format!("predicted ({unit})"),
                    range,
                },
                layers: vec![
                    Layer {
                        label: "identity (predicted = measured)".into(),
                        colour: charts::REFERENCE,
                        kind: LayerKind::Lines {
                            lines: vec![vec![(range.0, range.0), (range.1, range.1)]],
                            width: 1,
                            dashed: true,
                        },
                    },
                    Layer {
                        label: "load case".into(),
                        colour: charts::POINT,
                        kind: LayerKind::Dots {
                            points: pts,
                            radius: 3,
                        },
                    },
                ],
            });
        }
    }
    charts::xy_svg(&XyFigure {
        title: title.to_string(),
        subtitle: "measured vs predicted per level and DoF, experiment units".into(),
        panels,
        columns: dofs.len(),
        panel: (250, 230),
    })
}

/// Parameter spread: per parameter, the end points of every start (dots),
/// the best value with its 95% interval (bar) and the bounds (grey), as
/// value / nominal on a log axis. Stiffness (log-scale) parameters only:
/// the dimensionless shape and coupling parameters are in `report.json`.
pub fn params_svg(cal: &Calibration, title: &str) -> String {
    use crate::util::charts::{self, Category, CategoryChart, Mark, ValueAxis};
    let shown: Vec<(usize, &super::fit::ParamEstimate)> = cal
        .estimates
        .iter()
        .enumerate()
        .filter(|(_, e)| e.scale == super::family::Scale::Log)
        .collect();
    let mut vals: Vec<f64> = Vec::new();
    for &(k, e) in &shown {
        let nom = e.nominal;
        vals.push(e.lower / nom);
        vals.push(e.upper / nom);
        for st in &cal.starts {
            if let Some(v) = st.params.get(k) {
                vals.push(v / nom);
            }
        }
    }
    let positive = || vals.iter().filter(|v| **v > 0.0).map(|v| v.log10());
    let lmin = positive().fold(f64::INFINITY, f64::min).floor();
    let lmax = positive().fold(f64::NEG_INFINITY, f64::max).ceil();
    let (lmin, lmax) = if lmin.is_finite() && lmax > lmin {
        (lmin, lmax)
    } else {
        (-1.0, 1.0)
    };
    let categories = shown
        .iter()
        .map(|&(k, e)| {
            let nom = e.nominal;
            let mut marks = vec![Mark::Span {
                lo: e.lower / nom,
                hi: e.upper / nom,
                dx: 0,
                colour: plotters::style::RGBColor(0xcc, 0xcc, 0xcc),
                width: 6,
            }];
            marks.extend(
                cal.starts
                    .iter()
                    .filter_map(|st| st.params.get(k))
                    .map(|v| Mark::Dot {
                        at: v / nom,
                        dx: -6,
                        radius: 2,
                        colour: charts::POINT,
                        filled: true,
                    }),
            );
            let (lo, hi) = (e.ci95[0], e.ci95[1]);
            if lo.is_finite() && hi.is_finite() {
                marks.push(Mark::Span {
                    lo: lo / nom,
                    hi: hi / nom,
                    dx: 5,
                    colour: charts::HIGHLIGHT,
                    width: 2,
                });
            }
            marks.push(Mark::Dot {
                at: e.value / nom,
                dx: 5,
                radius: 3,
                colour: charts::HIGHLIGHT,
                filled: true,
            });
            Category {
                label: e.name.clone(),
                marks,
            }
        })
        .collect();
    let n = shown.len().max(1) as f64;
    charts::category_svg(&CategoryChart {
        title: title.to_string(),
        subtitle: "dots: end of each start; red: best with 95% CI; grey: literature bounds".into(),
        axis: ValueAxis {
            label: "value / nominal (log)".into(),
            range: (10f64.powf(lmin), 10f64.powf(lmax)),
            ticks: (lmin as i32..=lmax as i32).map(|e| 10f64.powi(e)).collect(),
            format: nice,
            log: true,
            grid: true,
            reference: Some(1.0),
        },
        categories,
        slot: (600.0 / n).clamp(36.0, 80.0) as u32,
        min_width: 400,
        plot_h: 260,
    })
}

/// The experiment's model with the calibrated laws of parameters `p`
/// written by the stiffness writer of `osim-spine stiffness`
/// (`personalise::apply`): linear families as `BushingForce` (damping of
/// the document kept), `nonlinear:cubic` as `FunctionBasedBushingForce`,
/// `nonlinear:sinh` and `coupled` as `ExpressionBasedBushingForce`.
/// `sys` is the problem's system (bushing names).
pub fn calibrated_document(
    exp: &super::experiment::Experiment,
    fam: &super::family::StiffnessFamily,
    sys: &crate::solver::System,
    p: &[f64],
) -> crate::error::Result<crate::osim::Document> {
    use crate::error::Error;
    use crate::personalise::{self, LevelLaw};
    let mut doc = exp.doc.clone();
    let levels = personalise::levels(&doc)?;
    let path = doc.path().to_path_buf();
    let names: Vec<&str> = sys.bushing_names().collect();
    let stiff = fam.bushing_stiffness(p);
    let mut laws = Vec::new();
    for (b, model) in fam.level_models(p) {
        let bushing = names.get(b.0).copied().unwrap_or("");
        let Some(level) = levels.iter().find(|l| l.bushing == bushing) else {
            return Err(Error::invalid(
                path.display().to_string(),
                format!("bushing '{bushing}' is not a level of the model"),
            ));
        };
        let law = if fam.is_linear() {
            let Some(e) = doc.component("ForceSet", bushing) else {
                return Err(Error::invalid(
                    path.display().to_string(),
                    format!("bushing '{bushing}' not found"),
                ));
            };
            let c = personalise::read_law(e, &path)?.damping();
            let k = stiff.get(b.0).copied().unwrap_or([f64::NAN; 6]);
            LevelLaw::Linear { k, c }
        } else {
            personalise::law_of_model(&model, None)?
        };
        laws.push((level.clone(), law));
    }
    personalise::apply(&mut doc, &laws)?;
    Ok(doc)
}
