//! Findings: the protocol's invariants on a palpated vertebra (14 distinct
//! points, midline codes on the mid-sagittal plane, right/left and
//! superior/inferior order) and anatomical plausibility of the mesh
//! (pedicles on the upper body, posterior elements behind them): errors,
//! the landmarks cannot be placed. The auxiliary quantities (left-right
//! symmetry, the centre's sphere inside the body) are warnings that lower
//! the confidence of what they concern: an ordinary vertebra can be 2-4 %
//! asymmetric, and the sphere through a flat-fronted body's anterior
//! surface can centre a few millimetres behind its posterior wall.

use super::{BodyState, Finding, Severity, VertebraPalpation};
use crate::landmarks::Code;
use nalgebra::Point3;

/// Two landmarks closer than this are "the same point" (m).
pub(super) const DISTINCT_M: f64 = 0.001;
/// Midline codes must lie this close to the mid-sagittal plane (m).
pub(super) const MIDLINE_M: f64 = 0.002;
/// The posterior elements (laminae, spinous process) reach at least this
/// share of the body depth behind the pedicle cut on a whole vertebra.
const POSTERIOR_REACH: f64 = 0.3;
/// Relative mirror cost above which a mesh is not left-right symmetric
/// (a warning), and above which the mid-sagittal plane is doubtful enough
/// to lower the midline landmarks' confidence further.
const ASYMMETRY_WARN: f64 = 0.02;
const ASYMMETRY_STRONG: f64 = 0.04;
/// Confidence factor of the landmarks placed on (or mirrored about) a
/// doubtful mid-sagittal plane: mildly and strongly asymmetric meshes.
const ASYMMETRY_CONFIDENCE: [f64; 2] = [0.8, 0.6];

fn finding(
    p: &VertebraPalpation,
    code: Option<Code>,
    severity: Severity,
    message: String,
) -> Finding {
    Finding {
        level: p.level,
        code,
        severity,
        message,
    }
}

/// The protocol invariants, checked in the palpation's own frame.
pub fn protocol_findings(p: &VertebraPalpation) -> Vec<Finding> {
    use Code::*;
    let mut out = Vec::new();
    let local: Vec<(Code, Point3<f64>)> = p
        .landmarks
        .keys()
        .filter_map(|c| p.local(*c).map(|q| (*c, q)))
        .collect();
    for (i, (a, pa)) in local.iter().enumerate() {
        for (b, pb) in &local[i + 1..] {
            let d = (pa - pb).norm();
            if d < DISTINCT_M {
                let msg = format!(
                    "{a} and {b} are {:.2} mm apart: two codes on one point",
                    d * 1e3
                );
                out.push(finding(p, Some(*b), Severity::Error, msg));
            }
        }
    }
    for (c, q) in &local {
        if matches!(c, SA | SP | SEC | IEC | IA | IP) && q.z.abs() > MIDLINE_M {
            let msg = format!(
                "{:.1} mm off the mid-sagittal plane (limit {:.0} mm)",
                q.z.abs() * 1e3,
                MIDLINE_M * 1e3
            );
            out.push(finding(p, Some(*c), Severity::Error, msg));
        }
    }
    let get = |c: Code| local.iter().find(|(k, _)| *k == c).map(|(_, q)| *q);
    let mut order = |a: Code, b: Code, axis: usize, what: &str| {
        if let (Some(pa), Some(pb)) = (get(a), get(b)) {
            if pa[axis] <= pb[axis] {
                let msg = format!(
                    "{a} is not {what} of {b} ({:.1} mm the wrong way)",
                    (pb[axis] - pa[axis]) * 1e3
                );
                out.push(finding(p, Some(a), Severity::Error, msg));
            }
        }
    };
    for (a, b) in [(SR, SL), (IR, IL), (PTR, PTL), (PBR, PBL)] {
        order(a, b, 2, "right");
    }
    for (a, b) in [(SEC, IEC), (SA, IA), (SP, IP), (PTR, PBR), (PTL, PBL)] {
        order(a, b, 1, "superior");
    }
    for (a, b) in [(SA, SP), (IA, IP)] {
        order(a, b, 0, "anterior");
    }
    out
}

/// Plausibility of the mesh as a vertebra (local coordinates of `st`).
pub(crate) fn anatomy_findings(st: &BodyState, sym_cost: f64, p: &mut VertebraPalpation) {
    let mut out = Vec::new();
    if sym_cost > ASYMMETRY_WARN {
        let factor = ASYMMETRY_CONFIDENCE[usize::from(sym_cost > ASYMMETRY_STRONG)];
        let msg = format!(
            "the mesh is {:.1} % left-right asymmetric (mirror mismatch; ordinary vertebrae reach 2-4 %): SEC..IL are placed on a less certain mid-sagittal plane, their confidence x {factor}",
            sym_cost * 100.0
        );
        for l in p.landmarks.values_mut() {
            l.confidence *= factor;
            l.note.get_or_insert_with(|| {
                format!(
                    "mid-sagittal plane from a {:.1} % asymmetric mesh",
                    sym_cost * 100.0
                )
            });
        }
        out.push(finding(p, None, Severity::Warning, msg));
    }
    // Pedicles leave the upper half of the body: below it, the mesh is upside-down.
    let w = &st.walls;
    let ped_mid = [Code::PTR, Code::PBR, Code::PTL, Code::PBL]
        .iter()
        .filter_map(|c| p.local(*c).map(|q| q.y))
        .sum::<f64>()
        / 4.0;
    let body_mid = p
        .local(Code::SEC)
        .zip(p.local(Code::IEC))
        .map(|(a, b)| 0.5 * (a.y + b.y))
        .unwrap_or(0.0);
    if ped_mid < body_mid - 0.1 * w.height() {
        let msg = format!(
            "the pedicles join the lower half of the body ({:.1} mm below its mid-height): is the mesh upside-down or the hint's cranial reversed?",
            (body_mid - ped_mid) * 1e3
        );
        out.push(finding(p, Some(Code::PTR), Severity::Error, msg));
    }
    out.extend(posterior_elements(st, p));
    out.extend(centre_findings(st, p));
    p.findings.extend(out);
}

/// A whole vertebra has posterior elements behind its pedicles; a body
/// alone, a ball or a box has none, and its "pedicle" landmarks are not.
fn posterior_elements(st: &BodyState, p: &VertebraPalpation) -> Option<Finding> {
    let x_cut = super::pedicle::pedicle_cut_x(&st.sup_pts, &st.inf_pts);
    let depth = 0.5 * (st.sup_pts.front.x + st.inf_pts.front.x)
        - 0.5 * (st.sup_pts.back.x + st.inf_pts.back.x);
    let x_min = st
        .lm
        .verts
        .iter()
        .map(|q| q.x)
        .fold(f64::INFINITY, f64::min);
    let reach = x_cut - x_min;
    (reach < POSTERIOR_REACH * depth).then(|| {
        finding(
            p,
            Some(Code::PTR),
            Severity::Error,
            format!(
                "nothing behind the pedicles ({:.1} mm of mesh behind the pedicle cut, a whole vertebra has at least {:.0} % of the body depth, {:.1} mm): a vertebral body alone or not a vertebra; PTR, PTL, PBR, PBL are not pedicle points",
                reach * 1e3,
                POSTERIOR_REACH * 100.0,
                POSTERIOR_REACH * depth * 1e3
            ),
        )
    })
}

/// The vertebral centre should lie between the walls (the endplates'
/// mid-sagittal ends, as the centre rule and the pedicle cut use them) and
/// between the endplates: a warning on the centre (not a landmark of the
/// set), with [`VertebraPalpation::centre_confidence`] lowered.
fn centre_findings(st: &BodyState, p: &mut VertebraPalpation) -> Vec<Finding> {
    let c = st.lm.to_mesh.inverse() * p.centre;
    let (s, i) = (&st.sup_pts, &st.inf_pts);
    let x_post = s.back.x.min(i.back.x);
    let x_ant = s.front.x.max(i.front.x);
    let mut why = Vec::new();
    if c.x < x_post || c.x > x_ant {
        why.push(format!(
            "x = {:.1} mm outside the walls {:.1}..{:.1} mm",
            c.x * 1e3,
            x_post * 1e3,
            x_ant * 1e3
        ));
    }
    if st.sup.normal.dot(&c.coords) > st.sup.offset || st.inf.normal.dot(&c.coords) > st.inf.offset
    {
        why.push("not between the endplate planes".to_string());
    }
    if c.z.abs() > 0.003 {
        why.push(format!(
            "{:.1} mm off the mid-sagittal plane",
            c.z.abs() * 1e3
        ));
    }
    if !why.is_empty() {
        p.centre_confidence = 0.5;
    }
    why.into_iter()
        .map(|m| {
            finding(
                p,
                None,
                Severity::Warning,
                format!("vertebral centre {m} (the sphere through the body's anterior surface; the landmarks are not affected)"),
            )
        })
        .collect()
}
