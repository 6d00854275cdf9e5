//! Guards of `base`: the palpation protocol's invariants on every
//! vertebra's landmarks and the vertebral-body sphere centre, checked in the
//! vertebra's own frame (from [`crate::palpation`]). A base model that fails
//! one is refused (naming level, landmark and distance) unless
//! `--allow-implausible`, which writes it with the failures as warnings.

use crate::landmarks::{Code, Level};
use crate::palpation::VertebraPalpation;

/// One invariant.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, serde::Serialize)]
pub enum Guard {
    /// The 14 landmarks are 14 points (no two within 1 mm).
    DistinctPoints,
    /// SA, SP, SEC, IEC, IA, IP within 2 mm of the mid-sagittal plane.
    Midline,
    /// Right codes right of their left mirror codes.
    RightLeftOrder,
    /// Superior codes above their inferior counterparts.
    SuperiorInferiorOrder,
    /// Sphere centre between the walls, between the endplates, within 3 mm
    /// of the mid-sagittal plane.
    CentreInBody,
}

impl Guard {
    /// Every guard, in the order they are checked.
    pub const ALL: [Guard; 5] = [
        Guard::DistinctPoints,
        Guard::Midline,
        Guard::RightLeftOrder,
        Guard::SuperiorInferiorOrder,
        Guard::CentreInBody,
    ];

    /// What the guard asserts, for the console.
    pub fn describe(self) -> &'static str {
        match self {
            Guard::DistinctPoints => "14 distinct landmarks (none within 1 mm)",
            Guard::Midline => "SA/SP/SEC/IEC/IA/IP within 2 mm of the mid-sagittal plane",
            Guard::RightLeftOrder => "right codes right of left codes",
            Guard::SuperiorInferiorOrder => "superior codes above inferior codes",
            Guard::CentreInBody => "sphere centre inside the vertebral body",
        }
    }
}

/// One failed guard.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct GuardFailure {
    /// The guard that failed.
    pub guard: Guard,
    /// Vertebral level (e.g. `T7`).
    pub level: Level,
    /// The landmark concerned (e.g. `T7_SP`); `None` for the vertebra as a whole.
    pub landmark: Option<String>,
    /// The offending distance (mm).
    pub distance_mm: f64,
    /// What was expected and found.
    pub message: String,
}

impl std::fmt::Display for GuardFailure {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match &self.landmark {
            Some(l) => write!(f, "{}_{l}: {}", self.level, self.message),
            None => write!(f, "{}: {}", self.level, self.message),
        }
    }
}

fn fail(guard: Guard, level: Level, code: Option<Code>, d: f64, message: String) -> GuardFailure {
    GuardFailure {
        guard,
        level,
        landmark: code.map(|c| c.to_string()),
        distance_mm: d * 1e3,
        message,
    }
}

/// Every failed guard of one vertebra (empty: all pass).
pub fn check_vertebra(p: &VertebraPalpation) -> Vec<GuardFailure> {
    use Code::*;
    let lv = p.level;
    let pts: Vec<(Code, nalgebra::Point3<f64>)> = Code::ALL
        .iter()
        .filter_map(|c| p.local(*c).map(|q| (*c, q)))
        .collect();
    let mut out = Vec::new();
    for (i, (a, pa)) in pts.iter().enumerate() {
        for (b, pb) in &pts[i + 1..] {
            let d = (pa - pb).norm();
            if d < 1e-3 {
                out.push(fail(
                    Guard::DistinctPoints,
                    lv,
                    Some(*b),
                    d,
                    format!("{:.2} mm from {a} (two codes on one point)", d * 1e3),
                ));
            }
        }
    }
    for (c, q) in &pts {
        if matches!(c, SA | SP | SEC | IEC | IA | IP) && q.z.abs() > 2e-3 {
            out.push(fail(
                Guard::Midline,
                lv,
                Some(*c),
                q.z.abs(),
                format!(
                    "{:.1} mm off the mid-sagittal plane (limit 2 mm)",
                    q.z.abs() * 1e3
                ),
            ));
        }
    }
    let get = |c: Code| pts.iter().find(|(k, _)| *k == c).map(|(_, q)| *q);
    for (g, axis, pairs) in [
        (
            Guard::RightLeftOrder,
            2,
            &[(SR, SL), (IR, IL), (PTR, PTL), (PBR, PBL)][..],
        ),
        (
            Guard::SuperiorInferiorOrder,
            1,
            &[(SEC, IEC), (SA, IA), (SP, IP), (PTR, PBR), (PTL, PBL)][..],
        ),
    ] {
        for (a, b) in pairs {
            if let (Some(pa), Some(pb)) = (get(*a), get(*b)) {
                if pa[axis] <= pb[axis] {
                    let d = pb[axis] - pa[axis];
                    out.push(fail(
                        g,
                        lv,
                        Some(*a),
                        d,
                        format!("{:.1} mm on the wrong side of {b}", d * 1e3),
                    ));
                }
            }
        }
    }
    out.extend(centre_failure(p));
    out
}

/// The sphere centre between the walls (SP..SA, IP..IA), the endplates
/// (IEC..SEC) and within 3 mm of the mid-sagittal plane.
fn centre_failure(p: &VertebraPalpation) -> Option<GuardFailure> {
    use Code::*;
    let c = p.frame.inverse() * p.centre;
    let (sa, sp, ia, ip, sec, iec) = (
        p.local(SA)?,
        p.local(SP)?,
        p.local(IA)?,
        p.local(IP)?,
        p.local(SEC)?,
        p.local(IEC)?,
    );
    let (x0, x1) = (sp.x.max(ip.x), sa.x.min(ia.x));
    let out_x = (x0 - c.x).max(c.x - x1).max(0.0);
    let out_y = (iec.y - c.y).max(c.y - sec.y).max(0.0);
    let out_z = (c.z.abs() - 3e-3).max(0.0);
    let d = out_x.max(out_y).max(out_z);
    (d > 0.0).then(|| {
        fail(Guard::CentreInBody, p.level, None, d, format!(
            "vertebral-body sphere centre {:.1} mm outside the body (x {:.1} mm in {:.1}..{:.1}, y {:.1} in {:.1}..{:.1}, {:.1} mm off the mid-sagittal plane)",
            d * 1e3, c.x * 1e3, x0 * 1e3, x1 * 1e3, c.y * 1e3, iec.y * 1e3, sec.y * 1e3, c.z.abs() * 1e3
        ))
    })
}
