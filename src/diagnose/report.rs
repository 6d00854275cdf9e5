//! Outputs of a diagnosis: `diagnosis.json` (the contract of
//! `../shared/formats/experiment.md`, extended), the Markdown report, the
//! SVG figures (residual maps before/after, measured vs predicted curves)
//! and the improved `.osim` (the chosen effect's laws and joint frames).
//! Everything is computed in memory; the CLI writes it.

use super::family::Variant;
use super::select::Outcome;
use super::sim::Sim;
use crate::calibrate::experiment::{Experiment, DOF_NAMES};
use crate::error::{Error, Result};
use crate::osim::Document;
use crate::personalise;
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use serde_json::{json, Value};
use std::fmt::Write as _;

/// Top cells listed in `where`.
pub const TOP_CELLS: usize = 20;

fn r4(x: f64) -> f64 {
    if x.is_finite() {
        (x * 1e4).round() / 1e4
    } else {
        0.0
    }
}

/// The `n` best candidates as `family:score` (`*` when it earns its
/// parameters), for one-line summaries.
pub fn best_candidates(o: &Outcome, n: usize) -> String {
    let best: Vec<String> = o
        .ranked
        .iter()
        .take(n)
        .map(|&j| {
            let s = &o.stats[j];
            let earns = if s.earns { "*" } else { "" };
            format!("{}:{:.0}{earns}", s.label, s.score)
        })
        .collect();
    best.join(" ")
}

/// `verdict.ranked`: the best variant of each effect, by score.
fn ranked_json(o: &Outcome) -> Vec<Value> {
    o.ranked
        .iter()
        .map(|&i| {
            let s = &o.stats[i];
            json!({"effect": s.effect.name(), "score": r4(s.score), "family": s.label,
                   "earns": s.earns, "n_params": s.n_params, "p_train": s.p_train,
                   "dchi2_train": r4(s.dchi2_train), "dchi2_heldout": r4(s.dchi2_heldout)})
        })
        .collect()
}

/// Every fitted family's statistics and parameters (physical units).
fn candidates_json(o: &Outcome) -> Vec<Value> {
    o.stats
        .iter()
        .map(|s| {
            json!({"family": s.label, "effect": s.effect.name(), "n_params": s.n_params,
                   "chi2_train": r4(s.chi2_train), "chi2_heldout": r4(s.chi2_heldout),
                   "heldout_rotation_rmse": r4(s.heldout_rot_rmse),
                   "dchi2_train": r4(s.dchi2_train), "p_train": s.p_train, "dbic_train": r4(s.dbic_train),
                   "dchi2_heldout": r4(s.dchi2_heldout), "score": r4(s.score), "earns": s.earns,
                   "iterations": s.iterations, "params": s.params.iter().map(|(k, v)| (k.clone(), r4(*v))).collect::<std::collections::BTreeMap<_, _>>()})
        })
        .collect()
}

/// The aggregates of the baseline's held-out gap.
fn tables_json(o: &Outcome) -> serde_json::Map<String, Value> {
    o.gap_tables()
        .into_iter()
        .map(|(k, v)| {
            let rows = v
                .iter()
                .map(|s| json!({"key": s.key, "share": r4(s.share)}))
                .collect();
            (k, Value::Array(rows))
        })
        .collect()
}

/// The `heldout` block: cases, rotation RMSE and shrink (with every
/// effect reported), translations, per level and DoF, and the primary
/// effect alone when two are reported.
fn heldout_json(o: &Outcome) -> Value {
    let (b, a) = o.heldout_rmse();
    let shrink = if b > 0.0 { 1.0 - a / b } else { 0.0 };
    let held: Vec<&str> = o
        .design
        .heldout
        .iter()
        .map(|&i| o.design.cases[i].id.as_str())
        .collect();
    let per: Vec<Value> = o
        .per_level_dof()
        .iter()
        .map(|r| {
            json!({"level": r.level, "dof": r.dof, "baseline_rmse": r4(r.baseline_rmse),
                   "augmented_rmse": r4(r.augmented_rmse), "shrink": r4(r.shrink)})
        })
        .collect();
    let trans = o.heldout_trans_rmse().map(|(b, a)| {
        json!({"baseline_rmse": r4(b), "augmented_rmse": r4(a), "shrink": if b > 0.0 { r4(1.0 - a / b) } else { 0.0 }, "units": "mm"})
    });
    json!({
        "cases": held,
        "folds": o.design.folds,
        "baseline_rmse": r4(b),
        "augmented_rmse": r4(a),
        "shrink": r4(shrink),
        "units": "deg: RMSE over every measured rotational cell (rx, ry, rz) of the held-out cases (each predicted by a fit that never saw it)",
        "translations": trans,
        "per_level_dof": per,
        "primary_alone": primary_alone(o),
    })
}

/// Quantities that were not measured where the two best candidates
/// predict values furthest apart (in units of the noise, the rig floor
/// for an unmeasured class): the measurements that would separate them.
pub fn separating_measurements(o: &Outcome) -> Vec<Value> {
    let [a, b] = match o.ranked.as_slice() {
        [a, b, ..] => [*a, *b],
        _ => return Vec::new(),
    };
    let (fa, fb) = (&o.fits[a], &o.fits[b]);
    let measured: std::collections::BTreeSet<(usize, usize)> =
        o.sim.cells.iter().map(|c| (c.row, c.dof)).collect();
    let sigma = |d: usize| {
        let class = if d < 3 {
            o.noise_model.rotation
        } else {
            o.noise_model.translation
        };
        class.map(|c| c.sigma).unwrap_or(if d < 3 {
            super::noise::FLOOR_DEG
        } else {
            super::noise::FLOOR_MM
        })
    };
    let mut best: Vec<(f64, usize, usize, f64)> = Vec::new();
    for (row, (pa, pb)) in fa.pred.iter().zip(&fb.pred).enumerate() {
        for d in (0..6).filter(|d| !measured.contains(&(row, *d))) {
            let diff = pa[d] - pb[d];
            best.push((diff.abs() / sigma(d), row, d, diff));
        }
    }
    best.sort_by(|x, y| y.0.total_cmp(&x.0).then(x.1.cmp(&y.1)).then(x.2.cmp(&y.2)));
    let names = format!(
        "{} vs {}",
        o.stats[a].effect.name(),
        o.stats[b].effect.name()
    );
    best.iter()
        .filter(|x| x.0 >= 2.0)
        .take(3)
        .map(|&(z, row, d, diff)| {
            let r = &o.sim.levels[o.sim.cells.iter().find(|c| c.row == row).map(|c| c.level).unwrap_or(0)];
            let case = o.sim.cells.iter().find(|c| c.row == row).map(|c| c.case).unwrap_or(0);
            json!({"case": o.design.cases.get(case).map(|c| c.id.as_str()).unwrap_or(""),
                   "upper": r.level.upper_body, "lower": r.level.lower_body, "dof": DOF_NAMES[d],
                   "effect": names, "difference": r4(diff),
                   "reason": format!("not measured: the two fitted models predict values {:.3} {} apart ({z:.1} noise SD)",
                                     diff.abs(), if d < 3 { "deg" } else { "mm" })})
        })
        .collect()
}

/// `where`: the cells carrying the held-out gap; for `unidentifiable` the
/// load cases or measurements that would separate the candidates.
fn where_json(o: &Outcome, gap_json: &[Value], missing: &[Value]) -> Vec<Value> {
    if o.verdict != "unidentifiable" {
        return gap_json.to_vec();
    }
    let mut w = missing.to_vec();
    w.extend(separating_measurements(o));
    if w.is_empty() {
        w.push(json!({
            "case": "a second moment magnitude in both directions, the rotations about the unloaded axes and the translations of every case, and follower-load series",
            "effect": o.ranked.iter().take(2).map(|&i| o.stats[i].effect.name()).collect::<Vec<_>>().join(" vs "),
            "reason": o.reasons.join("; "),
        }));
    }
    w
}

/// `diagnosis.json`.
pub fn diagnosis_json(o: &Outcome, exp: &Experiment, model_file: Option<&str>) -> Value {
    let gap_json: Vec<Value> = o
        .gap_cells(exp)
        .iter()
        .take(TOP_CELLS)
        .map(|g| {
            json!({"upper": g.upper, "lower": g.lower, "level": g.level, "dof": g.dof,
                   "case": g.case, "share": r4(g.share), "residual": r4(g.residual)})
        })
        .collect();
    let missing: Vec<Value> = o
        .design
        .missing
        .iter()
        .map(|m| json!({"case": m.case, "effect": m.effect, "reason": m.reason}))
        .collect();
    let train: Vec<&str> = o
        .design
        .train
        .iter()
        .map(|&i| o.design.cases[i].id.as_str())
        .collect();
    let params = |f: &crate::diagnose::fit::Fitted| -> std::collections::BTreeMap<String, f64> {
        f.family
            .physical_params(&o.sim, &f.x)
            .into_iter()
            .map(|(k, v)| (k, r4(v)))
            .collect()
    };
    json!({
        "verdict": {
            "effect": o.verdict,
            "confidence": r4(o.confidence),
            "effects": o.effects.iter().map(|e| json!({"effect": e.effect.name(), "share": r4(e.share), "family": e.family})).collect::<Vec<_>>(),
            "ranked": ranked_json(o),
            "family": o.augmented().family.label(),
            "reasons": o.reasons,
            "ratios": o.ratios.iter().map(|r| json!({"quantity": r.quantity, "ratio": r4(r.ratio),
                "ci95": r.ci95.map(r4), "text": r.text})).collect::<Vec<_>>(),
            "assumptions": o.assumptions,
        },
        "where": where_json(o, &gap_json, &missing),
        "gap_cells": gap_json,
        "gap_tables": tables_json(o),
        "heldout": heldout_json(o),
        "pairs": pairs_json(o),
        "remaining": remaining_json(o),
        "design": {
            "rule": o.design.rule,
            "train_cases": train,
            "separable": separable_line(o),
            "separating_measurements": separating_measurements(o),
        },
        "untestable": o.design.untestable.iter().map(|(e, w)| json!({"effect": e, "reason": w})).collect::<Vec<_>>(),
        "weakly_tested": o.design.weakly_tested.iter().map(|(e, w)| json!({"effect": e, "reason": w})).collect::<Vec<_>>(),
        "missing_cases": missing,
        "noise": noise_json(o),
        "baseline": {"params": params(&o.baseline)},
        "augmented": {"family": o.augmented().family.label(), "params": params(o.augmented())},
        "candidates": candidates_json(o),
        "model": model_file,
        "experiment": exp.name,
    })
}

/// With two effects reported, the held-out rotation RMSE and shrink of the
/// primary effect alone (the `heldout` figures are those with both).
fn primary_alone(o: &Outcome) -> Value {
    let (Some(_), Some(i)) = (o.chosen_pair, o.chosen) else {
        return Value::Null;
    };
    let (b, _) = o.heldout_rmse();
    let a = o.stats[i].heldout_rot_rmse;
    json!({"family": o.stats[i].label, "augmented_rmse": r4(a),
           "shrink": if b > 0.0 { r4(1.0 - a / b) } else { 0.0 }})
}

/// Every pair of effects fitted together and how it compares.
fn pairs_json(o: &Outcome) -> Value {
    let v: Vec<Value> = o
        .pairs
        .iter()
        .map(|p| {
            json!({"effects": p.effects.map(|e| e.name()), "family": p.fit.family.label(),
                   "chi2_train": r4(p.chi2_train), "chi2_heldout": r4(p.chi2_heldout),
                   "dchi2_train_over_better_member": r4(p.dchi2_train), "p_train": p.p_train,
                   "dchi2_heldout_over_best_single": r4(p.dchi2_heldout),
                   "win_probability": r4(p.win), "accepted": p.accepted,
                   "params": p.fit.family.physical_params(&o.sim, &p.fit.x).into_iter().map(|(k, v)| (k, r4(v))).collect::<std::collections::BTreeMap<_, _>>()})
        })
        .collect();
    Value::Array(v)
}

/// What the augmented model leaves of the held-out gap: its size against
/// the noise and its structure (the three most significant groupings,
/// five groups each).
fn remaining_json(o: &Outcome) -> Value {
    let r = &o.remaining;
    let structure: Vec<Value> = r
        .structure
        .iter()
        .take(3)
        .map(|s| {
            let groups: Vec<Value> = s
                .groups
                .iter()
                .take(5)
                .map(|g| json!({"key": g.key, "cells": g.cells, "mean_residual_noise_units": r4(g.mean), "share": r4(g.share)}))
                .collect();
            json!({"by": s.by, "f": r4(s.f), "p": s.p, "groups": groups})
        })
        .collect();
    json!({"model": r.model, "cells": r.cells, "chi2": r4(r.chi2), "reduced_chi2": r4(r.reduced_chi2),
           "p_noise": r.p_noise, "closed": r4(r.closed), "p_structure": r.p_structure(),
           "structure": structure})
}

/// Move the PhysicalOffsetFrame a bushing socket points to (`/jointset/J/F`)
/// by `t`: `X -> X * t`.
fn move_socket_frame(doc: &mut Document, socket: &str, t: &Isometry3<f64>) -> Result<()> {
    let file = doc.path().display().to_string();
    let parts: Vec<&str> = socket.trim_start_matches('/').split('/').collect();
    let [set, joint, frame] = parts.as_slice() else {
        return Err(Error::invalid(
            file,
            format!("bushing socket '{socket}' is not /jointset/JOINT/FRAME"),
        ));
    };
    if *set != "jointset" {
        return Err(Error::invalid(
            file,
            format!("bushing socket '{socket}' is not a joint frame"),
        ));
    }
    let j = doc
        .component_mut("JointSet", joint)
        .ok_or_else(|| Error::invalid(file.clone(), format!("joint '{joint}' not found")))?;
    let frames = j
        .child_mut("frames")
        .ok_or_else(|| Error::invalid(file.clone(), format!("joint '{joint}' has no frames")))?;
    let f = frames
        .elements_mut()
        .find(|e| e.name_attr() == *frame)
        .ok_or_else(|| {
            Error::invalid(
                file.clone(),
                format!("frame '{frame}' of joint '{joint}' not found"),
            )
        })?;
    let nums = |s: Option<String>| -> Vector3<f64> {
        let v: Vec<f64> = s
            .unwrap_or_default()
            .split_whitespace()
            .filter_map(|x| x.parse().ok())
            .collect();
        if v.len() == 3 {
            Vector3::new(v[0], v[1], v[2])
        } else {
            Vector3::zeros()
        }
    };
    let p = nums(f.child_text("translation"));
    let o = nums(f.child_text("orientation"));
    let x = Isometry3::from_parts(
        Translation3::from(p),
        UnitQuaternion::from_rotation_matrix(&crate::osim::model::body_fixed_xyz(&o)),
    );
    let y = x * t;
    let ang = crate::osim::model::xyz_angles(&y.rotation.to_rotation_matrix());
    crate::osim::props::set_vec3(f, "translation", &y.translation.vector);
    crate::osim::props::set_vec3(f, "orientation", &ang);
    Ok(())
}

/// The nominal model with the variant's laws and joint frames.
pub fn improved_model(sim: &Sim, exp: &Experiment, v: &Variant) -> Result<Document> {
    let mut doc = exp.doc.clone();
    let levels = personalise::levels(&doc)?;
    let mut laws = Vec::new();
    for (li, l) in sim.levels.iter().enumerate() {
        let bname = sim
            .base
            .bushing_names()
            .nth(l.bushing.0)
            .unwrap_or("")
            .to_string();
        let Some(pl) = levels.iter().find(|x| x.bushing == bname) else {
            return Err(Error::invalid(
                exp.model_path.display().to_string(),
                format!("bushing '{bname}' is not a level of the document"),
            ));
        };
        if let Some(m) = v.laws.get(li) {
            let e = v.expressions.get(li).and_then(|e| e.as_ref());
            laws.push((pl.clone(), personalise::law_of_model(m, e)?));
        }
        if let Some(Some(t)) = v.frames.get(li) {
            let e = doc.component("ForceSet", &bname).ok_or_else(|| {
                Error::invalid(
                    exp.model_path.display().to_string(),
                    format!("bushing '{bname}' not found"),
                )
            })?;
            let s1 = e.child_text("socket_frame1").unwrap_or_default();
            let s2 = e.child_text("socket_frame2").unwrap_or_default();
            move_socket_frame(&mut doc, s1.trim(), t)?;
            move_socket_frame(&mut doc, s2.trim(), t)?;
        }
    }
    personalise::apply(&mut doc, &laws)?;
    Ok(doc)
}

/// Residual map (levels x (case, DoF)) of the baseline and the augmented
/// model on every case, held-out cases marked; colour scaled by the
/// largest baseline residual of each DoF class, with a colour scale.
pub fn residual_map_svg(o: &Outcome, exp: &Experiment) -> String {
    use crate::util::charts::{self, ColourScale, HeatMap, HeatPanel};
    let sim = &o.sim;
    let dofs: Vec<usize> = (0..6)
        .filter(|d| sim.cells.iter().any(|c| c.dof == *d))
        .collect();
    let nc = exp.cases.len();
    let nd = dofs.len().max(1);
    let scale = |rot: bool| {
        sim.cells
            .iter()
            .enumerate()
            .filter(|(_, c)| (c.dof < 3) == rot)
            .map(|(i, _)| o.baseline.residual(sim, i).abs())
            .fold(1e-9, f64::max)
    };
    let (sr, st) = (scale(true), scale(false));
    let dof_list = dofs
        .iter()
        .map(|d| DOF_NAMES[*d])
        .collect::<Vec<_>>()
        .join(", ");
    let panel = |title: &str, fit: &crate::diagnose::fit::Fitted| HeatPanel {
        title: title.to_string(),
        cells: sim
            .cells
            .iter()
            .enumerate()
            .filter_map(|(ci, c)| {
                let dk = dofs.iter().position(|d| *d == c.dof)?;
                let r = fit.residual(sim, ci) / if c.dof < 3 { sr } else { st };
                Some((c.level, c.case * nd + dk, r))
            })
            .collect(),
    };
    // every case numbered when a case is wide enough, else every fifth
    let every = if 6 * nd >= 14 { 1 } else { 5 };
    let column_ticks = (0..nc)
        .filter(|i| i % every == every - 1 || *i == 0)
        .map(|i| ((i as f64 + 0.5) * nd as f64, (i + 1).to_string()))
        .collect();
    let ticks = vec![-1.0, -0.5, 0.0, 0.5, 1.0];
    let labels = |s: f64| ticks.iter().map(|t| format!("{:+.3}", t * s)).collect();
    let mut rows = Vec::new();
    if dofs.iter().any(|d| *d < 3) {
        rows.push(("rotations (deg)".to_string(), labels(sr)));
    }
    if dofs.iter().any(|d| *d >= 3) {
        rows.push(("translations (mm)".to_string(), labels(st)));
    }
    charts::heatmap_svg(&HeatMap {
        title: format!("{}: residual map", exp.name),
        subtitle: format!(
            "predicted - measured; rows: levels; columns: cases 1..{nc}, each DoF {dof_list} in turn; held-out cases underlined"
        ),
        rows: sim.levels.iter().map(|l| l.level.name.clone()).collect(),
        columns: nc * nd,
        cell: (6, 14),
        x_label: "load case".into(),
        column_ticks,
        marked: o
            .design
            .heldout
            .iter()
            .map(|&i| (i * nd, (i + 1) * nd))
            .collect(),
        panels: vec![
            panel("baseline model", &o.baseline),
            panel("augmented model (chosen effect added)", o.augmented()),
        ],
        scale: ColourScale {
            title: "colour: blue, model below the measurement; red, above (scaled by the largest baseline residual)".into(),
            ticks,
            rows,
        },
    })
}

/// Measured vs predicted total rotation (sum over levels of the primary
/// DoF) against the signed moment, one panel per load axis, pure-moment
/// cases and each follower load as a separate line.
pub fn curves_svg(o: &Outcome, exp: &Experiment) -> String {
    use crate::util::charts::{self, XyFigure};
    let panels = (0..3).map(|a| curve_panel(o, a)).collect();
    charts::xy_svg(&XyFigure {
        title: format!("{}: load-displacement curves", exp.name),
        subtitle: "total rotation over the levels against the signed moment; each follower load its own line".into(),
        panels,
        columns: 3,
        panel: (280, 250),
    })
}

/// The curves of one load axis: measured totals (dots; held-out cases
/// larger), the baseline and augmented predictions (lines).
fn curve_panel(o: &Outcome, a: usize) -> crate::util::charts::XyPanel {
    use crate::util::charts::{self, Axis, Layer, LayerKind, XyPanel};
    let sim = &o.sim;
    let info = &o.design.cases;
    // (signed moment, follower, total, held out) per case, per source
    let sources = [None, Some(&o.baseline), Some(o.augmented())];
    let mut pts: Vec<Vec<(f64, f64, f64, bool)>> = vec![Vec::new(); 3];
    for (ci, c) in info.iter().enumerate() {
        if c.axis != Some(a) {
            continue;
        }
        let m = c.sign as f64 * c.magnitude;
        for (k, f) in sources.iter().enumerate() {
            let tot: f64 = sim
                .cells
                .iter()
                .filter(|x| x.case == ci && x.dof == a)
                .map(|x| match f {
                    None => x.measured,
                    Some(f) => f.pred[x.row][x.dof],
                })
                .sum();
            pts[k].push((m, c.follower, tot, o.design.heldout.contains(&ci)));
        }
    }
    let mx = pts.iter().flatten().map(|p| p.0.abs()).fold(1e-9, f64::max) * 1.08;
    let my = pts.iter().flatten().map(|p| p.2.abs()).fold(1e-9, f64::max) * 1.08;
    let dots = |held: bool, label: &str, radius: u32| Layer {
        label: label.into(),
        colour: plotters::style::colors::BLACK,
        kind: LayerKind::Dots {
            points: pts[0]
                .iter()
                .filter(|p| p.3 == held)
                .map(|p| (p.0, p.2))
                .collect(),
            radius,
        },
    };
    let line = |k: usize, label: String, colour| {
        let mut series = pts[k].clone();
        series.sort_by(|p, q| p.1.total_cmp(&q.1).then(p.0.total_cmp(&q.0)));
        let mut lines: Vec<Vec<(f64, f64)>> = Vec::new();
        let mut fl = f64::NAN;
        for p in series {
            if p.1 != fl || lines.is_empty() {
                lines.push(Vec::new());
                fl = p.1;
            }
            if let Some(l) = lines.last_mut() {
                l.push((p.0, p.2));
            }
        }
        Layer {
            label,
            colour,
            kind: LayerKind::Lines {
                lines,
                width: 2,
                dashed: false,
            },
        }
    };
    XyPanel {
        title: format!("{} ({})", super::design::AXIS_NAMES[a], DOF_NAMES[a]),
        x: Axis {
            label: "moment (N m)".into(),
            range: (-mx, mx),
        },
        y: Axis {
            label: format!("total {} (deg)", DOF_NAMES[a]),
            range: (-my, my),
        },
        layers: vec![
            line(1, "baseline".into(), charts::POINT),
            line(
                2,
                format!("augmented ({})", o.augmented().family.label()),
                charts::HIGHLIGHT,
            ),
            dots(false, "measured (fitted)", 2),
            dots(true, "measured (held out)", 4),
        ],
    }
}

/// Which candidate effects the design's held-out split can test, and for
/// those it cannot, the load cases or measurements that would test them.
pub fn separable_line(o: &Outcome) -> String {
    let (can, cannot): (Vec<_>, Vec<_>) = super::family::Effect::CANDIDATES
        .iter()
        .map(|e| e.name())
        .partition(|e| !o.design.is_untestable(e));
    let needs = |e: &str| -> String {
        let cases: Vec<&str> = o
            .design
            .missing
            .iter()
            .filter(|m| m.effect == e)
            .map(|m| m.case.as_str())
            .take(4)
            .collect();
        if cases.is_empty() {
            e.to_string()
        } else {
            format!("{e} (would need: {})", cases.join(", "))
        }
    };
    let cannot: Vec<String> = cannot.iter().map(|e| needs(e)).collect();
    let weak: Vec<String> = o
        .design
        .weakly_tested
        .iter()
        .map(|(e, _)| needs(e))
        .collect();
    let list = |v: &[String]| {
        if v.is_empty() {
            "-".to_string()
        } else {
            v.join("; ")
        }
    };
    format!(
        "The held-out design can test: {} (only indirectly: {}); it cannot test: {}.",
        can.join(", "),
        list(&weak),
        list(&cannot)
    )
}

/// The noise of each measured class (an unmeasured class is left out),
/// its source and degrees of freedom.
fn noise_json(o: &Outcome) -> Value {
    let class = |c: &super::noise::ClassNoise, unit: &str| {
        json!({"sd": r4(c.sigma), "units": unit, "source": c.source, "dof": r4(c.dof),
               "how": c.source.describe()})
    };
    let n = &o.noise_model;
    json!({
        "rotation": n.rotation.as_ref().map(|c| class(c, "deg")),
        "translation": n.translation.as_ref().map(|c| class(c, "mm")),
        "rotation_deg": n.rotation.map(|c| r4(c.sigma)),
        "translation_mm": n.translation.map(|c| r4(c.sigma)),
        "cells_with_own_sd": o.sim.cells.iter().filter(|c| c.sd.is_some()).count(),
    })
}

/// One line on the noise for the report and the console.
pub fn noise_line(o: &Outcome) -> String {
    let n = &o.noise_model;
    let part = |c: &Option<super::noise::ClassNoise>, what: &str, unit: &str| {
        c.map(|c| format!("{what} {:.4} {unit} ({})", c.sigma, c.source.describe()))
    };
    let parts: Vec<String> = [
        part(&n.rotation, "rotations", "deg"),
        part(&n.translation, "translations", "mm"),
    ]
    .into_iter()
    .flatten()
    .collect();
    let own = o.sim.cells.iter().filter(|c| c.sd.is_some()).count();
    let mut line = format!("Noise: {}", parts.join("; "));
    if n.translation.is_none() {
        line.push_str("; translations not measured");
    }
    let stated = [n.rotation, n.translation]
        .iter()
        .flatten()
        .any(|c| c.source == super::noise::NoiseSource::Stated);
    if own > 0 && stated {
        let _ = write!(line, "; {own} cells weighted by their own stated SD");
    }
    line
}

/// The chosen family's parameters in physical units (one line).
pub fn params_line(o: &Outcome) -> String {
    let f = o.augmented();
    let p = f.family.physical_params(&o.sim, &f.x);
    format!(
        "Fitted parameters ({}): {}",
        f.family.label(),
        p.iter()
            .map(|(k, v)| format!("{k} = {v:.4}"))
            .collect::<Vec<_>>()
            .join(", ")
    )
}

/// The effects reported with their shares of the held-out gap, and the
/// pairs of effects tried.
fn effects_md(m: &mut String, o: &Outcome) {
    if !o.effects.is_empty() {
        let list: Vec<String> = o
            .effects
            .iter()
            .map(|e| {
                format!(
                    "`{}` ({}) {:.0}%",
                    e.effect.name(),
                    e.family,
                    100.0 * e.share
                )
            })
            .collect();
        let _ = writeln!(
            m,
            "\nEffects and the share of the held-out gap each explains: {}.",
            list.join(", ")
        );
    }
    if o.pairs.is_empty() {
        return;
    }
    let _ = writeln!(m, "\n| pair | dchi2 train over better member | p train | dchi2 held-out over best single | P(stays better) | accepted |\n|---|---|---|---|---|---|");
    for p in &o.pairs {
        let _ = writeln!(
            m,
            "| {} + {} | {:.1} | {:.2e} | {:.1} | {:.3} | {} |",
            p.effects[0].name(),
            p.effects[1].name(),
            p.dchi2_train,
            p.p_train,
            p.dchi2_heldout,
            p.win,
            if p.accepted { "yes" } else { "no" }
        );
    }
}

/// The fitted ratios with their 95% intervals.
fn ratios_md(m: &mut String, o: &Outcome) {
    if o.ratios.is_empty() {
        return;
    }
    let _ = writeln!(m, "\nFitted stiffness ratios (95% intervals):\n");
    for r in &o.ratios {
        let _ = writeln!(m, "- {}", r.text);
    }
}

/// One line on the fitted ratios for the console (the first few).
pub fn ratios_line(o: &Outcome) -> Option<String> {
    const SHOWN: usize = 6;
    if o.ratios.is_empty() {
        return None;
    }
    let mut parts: Vec<String> = o
        .ratios
        .iter()
        .take(SHOWN)
        .map(|r| r.text.clone())
        .collect();
    if o.ratios.len() > SHOWN {
        parts.push(format!(
            "... and {} more in diagnosis.json",
            o.ratios.len() - SHOWN
        ));
    }
    Some(format!(
        "Fitted ratios (95% intervals): {}",
        parts.join("; ")
    ))
}

/// What the augmented model leaves of the held-out gap, and its structure.
fn remaining_md(m: &mut String, o: &Outcome) {
    let r = &o.remaining;
    let _ = writeln!(
        m,
        "\n## What is left\n\nThe augmented model ({}) closes {:.0}% of the baseline's held-out chi-square and leaves {:.1} over {} cells (reduced {:.2}, P(noise) {:.2e}); structure of the rest, most significant first:\n",
        r.model, 100.0 * r.closed, r.chi2, r.cells, r.reduced_chi2, r.p_noise
    );
    for s in r.structure.iter().take(3) {
        let groups: Vec<String> = s
            .groups
            .iter()
            .take(4)
            .map(|g| format!("{} {:+.2} ({:.0}%)", g.key, g.mean, 100.0 * g.share))
            .collect();
        let _ = writeln!(
            m,
            "- by {} (F {:.1}, p {:.1e}): {}",
            s.by,
            s.f,
            s.p,
            groups.join(", ")
        );
    }
}

/// The design: the held-out rule, what it can and cannot test, and the
/// load cases or measurements that would.
fn design_md(m: &mut String, o: &Outcome) {
    let _ = writeln!(m, "\n## Design\n\n{}\n", o.design.rule);
    let _ = writeln!(
        m,
        "Training cases: {}; held-out cases: {}.\n",
        o.design.train.len(),
        o.design.heldout.len()
    );
    let _ = writeln!(m, "{}\n", separable_line(o));
    if !o.design.untestable.is_empty() || !o.design.weakly_tested.is_empty() {
        for (title, list) in [
            ("Untestable by design", &o.design.untestable),
            ("Tested only indirectly", &o.design.weakly_tested),
        ] {
            if !list.is_empty() {
                let _ = writeln!(m, "{title}:\n");
                for (e, w) in list {
                    let _ = writeln!(m, "- `{e}`: {w}");
                }
            }
        }
        let _ = writeln!(
            m,
            "\nLoad cases or measurements that would make them testable:\n"
        );
        for c in &o.design.missing {
            let _ = writeln!(m, "- `{}` ({}): {}", c.case, c.effect, c.reason);
        }
        let _ = writeln!(m);
    }
    let sep = separating_measurements(o);
    if !sep.is_empty() {
        let _ = writeln!(
            m,
            "Unmeasured quantities that would separate the two best candidates:\n"
        );
        for x in &sep {
            let _ = writeln!(
                m,
                "- {} at {}/{} in `{}` ({}): {}",
                x["dof"].as_str().unwrap_or(""),
                x["upper"].as_str().unwrap_or(""),
                x["lower"].as_str().unwrap_or(""),
                x["case"].as_str().unwrap_or(""),
                x["effect"].as_str().unwrap_or(""),
                x["reason"].as_str().unwrap_or("")
            );
        }
        let _ = writeln!(m);
    }
}

/// The Markdown report.
pub fn markdown(o: &Outcome, exp: &Experiment, json: &Value) -> String {
    let mut m = String::new();
    let _ = writeln!(m, "# Sim-to-real gap diagnosis: {}\n", exp.name);
    let _ = writeln!(
        m,
        "**Verdict: `{}`** (confidence {:.2})\n",
        o.verdict, o.confidence
    );
    for r in &o.reasons {
        let _ = writeln!(m, "- {r}");
    }
    for a in &o.assumptions {
        let _ = writeln!(m, "- ASSUMED: {a}");
    }
    effects_md(&mut m, o);
    ratios_md(&mut m, o);
    design_md(&mut m, o);
    let _ = writeln!(m, "{}\n", noise_line(o));
    let _ = writeln!(m, "{}\n", params_line(o));
    let _ = writeln!(m, "## Candidates\n\n| family | effect | params | dchi2 train | p train | dchi2 held-out | score | earns |\n|---|---|---|---|---|---|---|---|");
    for &i in &o.ranked {
        let s = &o.stats[i];
        let _ = writeln!(
            m,
            "| {} | {} | {} | {:.1} | {:.2e} | {:.1} | {:.1} | {} |",
            s.label,
            s.effect.name(),
            s.n_params,
            s.dchi2_train,
            s.p_train,
            s.dchi2_heldout,
            s.score,
            if s.earns { "yes" } else { "no" }
        );
    }
    remaining_md(&mut m, o);
    let (b, a) = o.heldout_rmse();
    let _ = writeln!(m, "\n## How far: held-out rotation RMSE\n\nbaseline {:.4} deg, augmented {:.4} deg, shrink {:.3}.\n", b, a, if b > 0.0 { 1.0 - a / b } else { 0.0 });
    let _ = writeln!(
        m,
        "| level | DoF | baseline | augmented | shrink |\n|---|---|---|---|---|"
    );
    for r in o.per_level_dof() {
        let _ = writeln!(
            m,
            "| {} | {} | {:.4} | {:.4} | {:.2} |",
            r.level, r.dof, r.baseline_rmse, r.augmented_rmse, r.shrink
        );
    }
    let _ = writeln!(m, "\n## Where: cells carrying the held-out gap (baseline)\n\n| level | DoF | case | share | residual |\n|---|---|---|---|---|");
    for g in o.gap_cells(exp).iter().take(TOP_CELLS) {
        let _ = writeln!(
            m,
            "| {} | {} | {} | {:.3} | {:.4} |",
            g.level, g.dof, g.case, g.share, g.residual
        );
    }
    for (name, rows) in o.gap_tables() {
        let _ = writeln!(
            m,
            "\n**{name}**: {}",
            rows.iter()
                .map(|r| format!("{} {:.2}", r.key, r.share))
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
    if o.verdict == "unidentifiable" {
        let _ = writeln!(m, "\n## Load cases that would separate the candidates\n");
        if let Some(Value::Array(w)) = json.get("where") {
            for x in w {
                let _ = writeln!(
                    m,
                    "- `{}` ({}): {}",
                    x["case"].as_str().unwrap_or(""),
                    x["effect"].as_str().unwrap_or(""),
                    x["reason"].as_str().unwrap_or("")
                );
            }
        }
    }
    let _ = writeln!(
        m,
        "\n## Figures\n\n![residual map](residual_map.svg)\n\n![curves](curves.svg)\n"
    );
    m
}
