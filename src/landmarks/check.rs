//! `osim-spine check`: validation of landmark sets against the protocol of
//! `../shared/formats/landmarks.md` and against anatomy.
//!
//! Every finding has a stable code, a severity, the landmark(s) involved and
//! a one-line reason. Codes (see also `docs/check-codes.md`):
//!
//! | code | severity | meaning |
//! |---|---|---|
//! | LM001 | error | file unreadable or malformed (parse error) |
//! | LM002 | error | declared units contradict the vertebral dimensions |
//! | LM003 | error | declared frame contradicts the anatomical directions |
//! | LM004 | info | units not declared: detected from the anatomy |
//! | LM005 | info | frame not declared: detected from the anatomy |
//! | LM006 | error | units neither declared nor detectable |
//! | LM007 | error | frame neither declared nor detectable |
//! | LM008 | info | reader remark (TRC frames averaged, non-landmark markers or JSON keys ignored) |
//! | LM010 | warning | unknown landmark name (ignored) |
//! | LM011 | warning | non-canonical spelling of a landmark name |
//! | LM012 | error | duplicate landmark name |
//! | LM013 | error | coordinates in a body's frame (`body` column: a model palpation for `base --palpation`) |
//! | LM020 | error | landmark(s) missing at a level that is present |
//! | LM021 | warning | level missing between landmarked levels (a gap: `generate` fills it from its neighbours) |
//! | LM022 | error | no S1 (the run must end at the sacrum) |
//! | LM023 | info | levels covered |
//! | LM030 | error/warning | superior endplate centre not cranial of the inferior one |
//! | LM031 | error/warning | pedicle top not cranial of its base |
//! | LM032 | error | right landmark not to the right of its left partner |
//! | LM033 | info/warning/error | endplate centre outside its four extreme points (beyond palpation noise) |
//! | LM034 | warning/error | endplate width outside the anatomical range of the level |
//! | LM035 | warning/error | endplate depth outside the anatomical range of the level |
//! | LM036 | warning/error | vertebral body height outside the anatomical range |
//! | LM037 | error | anterior/posterior inverted (SA behind SP, pedicles in front of the body) |
//! | LM040 | error | consecutive levels out of order along the spine |
//! | LM041 | warning/error | spacing between consecutive vertebrae implausible |
//! | LM042 | error | consecutive vertebrae overlap (negative disc height) |
//! | LM043 | error | vertebra displaced with respect to both neighbours |
//! | LM044 | warning | large intervertebral translation (listhesis) |
//! | LM045 | warning | abrupt intervertebral angulation |
//! | LM050 | warning | single-landmark outlier |
//!
//! Rules and thresholds (all distances in mm, orientation checks in the
//! resolved OpenSim frame: x anterior, y superior, z right):
//! - Orientation (LM030/031/037/032): a difference along the expected axis
//!   below -3 mm is an error, between -3 and 0 a warning (noise). Vertebral
//!   tilts even in severe scoliosis (< 60 deg) keep the sign.
//! - Ranges (LM034-036), from `templates/vertebra_dimensions.csv`: with
//!   `s = sqrt(SD_anat^2 + (2.5 mm)^2)` (anatomical SD floored at 8% of the
//!   mean and widened 1.5x for heights, to allow for wedged scoliotic
//!   vertebrae; 2.5 mm for the palpation noise of a two-landmark distance):
//!   warning outside mean +- 4 s, error below mean - max(0.65 mean, 6 s) or
//!   above mean + max(mean, 6 s) (gross errors only).
//! - Spacing (LM041): centre distance over the expected one (half heights +
//!   disc): warning outside [0.6, 1.5], error outside [0.4, 2.2]. Across a
//!   gap (LM021) the expected distance is summed over the missing levels,
//!   and the two levels must still be in order (LM040).
//! - Overlap (LM042): disc gap between the endplate means (5 points each)
//!   along the mean cranial axis below -4 mm.
//! - Displacement (LM043): the two adjacent discs' deviations from a
//!   table-height disc along the axis are opposite (cosine < -0.5) and their
//!   half-difference exceeds 10 mm. Listhesis (LM044): disc shear > 8 mm.
//!   Angulation (LM045): > 35 deg between adjacent vertebral axes.
//! - Outliers (LM050): per vertebra, an affine map of an anatomical
//!   template is fitted to its landmarks (>= 10 needed): the analytic
//!   layout ([`super::synth::local_position`]) or the default base model's
//!   palpated markers ([`base_layout`], `templates/landmark_layout.csv`),
//!   whichever fits the vertebra better; a landmark whose leave-one-out residual exceeds 6 mm
//!   and whose standardised residual exceeds 5 robust SDs (median absolute
//!   residual of the whole set / 0.6745, floored at 0.3 mm) is an outlier.
//!   The affine map absorbs size, wedging and rotation. Not applied to S1.

use super::detect::Detection;
use super::frames::mean_of;
use super::io::{read_path, RawLandmarks};
use super::synth::local_position;
use super::{Code, LandmarkId, LandmarkSet, Level};
use crate::anatomy::DimensionTable;
use crate::util::messages::shown;
use crate::util::table::CsvReader;
use nalgebra::{DMatrix, Point3, Vector3};
use std::collections::BTreeMap;
use std::path::Path;

/// Finding severity.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Severity {
    /// A note; never changes the exit code.
    Info,
    /// Suspect data: exit code 2 (1 with `strict`).
    Warning,
    /// Wrong or unusable data: exit code 1.
    Error,
}

/// One finding.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Finding {
    /// Stable code `LM0xx`.
    pub code: String,
    /// How serious the finding is.
    pub severity: Severity,
    /// Landmark names involved (may be empty for file-level findings).
    pub landmarks: Vec<String>,
    /// One-line reason.
    pub message: String,
    /// Line of the first landmark's row, when known.
    pub line: Option<usize>,
}

/// All findings for one file.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct CheckReport {
    /// The checked file's path, as displayed.
    pub file: String,
    /// Every finding, in the order the checks ran.
    pub findings: Vec<Finding>,
    /// Units and frame detection, when the file could be read.
    pub detection: Option<Detection>,
    /// Levels present in the set (empty when the file could not be read).
    pub levels: Vec<Level>,
}

impl CheckReport {
    /// Number of findings of severity `s`.
    pub fn count(&self, s: Severity) -> usize {
        self.findings.iter().filter(|f| f.severity == s).count()
    }
    /// `true` when some finding has this code.
    pub fn has(&self, code: &str) -> bool {
        self.findings.iter().any(|f| f.code == code)
    }
    /// Exit code: 0 clean, 1 errors, 2 warnings only (1 with `strict`,
    /// except LM050 outliers alone).
    pub fn exit_code(&self, strict: bool) -> i32 {
        exit_code(std::slice::from_ref(self), strict)
    }
}

/// Exit code over several reports: 0 clean, 1 any error (or, with
/// `strict`, any warning but a single-landmark outlier LM050), 2 warnings only.
pub fn exit_code(reports: &[CheckReport], strict: bool) -> i32 {
    let e: usize = reports.iter().map(|r| r.count(Severity::Error)).sum();
    let w: usize = reports.iter().map(|r| r.count(Severity::Warning)).sum();
    // A single-landmark outlier (LM050) is rejected by the lsq fit: it
    // keeps exit 2 under `strict`; every other warning fails.
    let hard_w: usize = reports
        .iter()
        .flat_map(|r| &r.findings)
        .filter(|f| f.severity == Severity::Warning && f.code != "LM050")
        .count();
    if e > 0 || (strict && hard_w > 0) {
        1
    } else if w > 0 {
        2
    } else {
        0
    }
}

struct Ctx<'a> {
    set: &'a LandmarkSet,
    lines: &'a BTreeMap<LandmarkId, usize>,
    out: Vec<Finding>,
}

impl Ctx<'_> {
    fn push(&mut self, code: &str, sev: Severity, ids: &[LandmarkId], message: String) {
        let line = ids.iter().find_map(|i| self.lines.get(i).copied());
        self.out.push(Finding {
            code: code.into(),
            severity: sev,
            landmarks: ids.iter().map(|i| i.to_string()).collect(),
            message,
            line,
        });
    }
    fn g(&self, l: Level, c: Code) -> Option<Point3<f64>> {
        self.set.get(l, c)
    }
}

fn id(l: Level, c: Code) -> LandmarkId {
    LandmarkId::new(l, c)
}

fn mm(x: f64) -> f64 {
    x * 1e3
}

/// Check codes that refuse a landmark set for model generation (`generate`,
/// each palpation of `variability`): the set cannot be read
/// unambiguously or is anatomically inverted: parse errors, units/frame
/// contradictions or undetectable, duplicates, missing landmarks or levels,
/// left/right or anterior/posterior swaps, levels out of order. Other
/// error findings of `osim-spine check` (plausibility ranges, endplate
/// centre outside its outline, overlaps) are printed as warnings: severe
/// deformities and coarse meshes can trip them legitimately.
pub const GENERATE_BLOCKING: [&str; 12] = [
    "LM001", "LM002", "LM003", "LM006", "LM007", "LM012", "LM020", "LM022", "LM030", "LM032",
    "LM037", "LM040",
];

/// Check a file: read, detect, validate. Never fails: a malformed file is
/// an LM001 finding.
pub fn check_file(path: &Path) -> CheckReport {
    match read_path(path) {
        Ok(raw) => check_raw(&raw),
        Err(e) => CheckReport {
            file: path.display().to_string(),
            findings: vec![Finding {
                code: "LM001".into(),
                severity: Severity::Error,
                landmarks: vec![],
                message: e.to_string(),
                line: line_from_error(&e),
            }],
            detection: None,
            levels: vec![],
        },
    }
}

fn line_from_error(e: &crate::Error) -> Option<usize> {
    match e {
        crate::Error::Parse { location, .. } => location
            .strip_prefix("line ")
            .and_then(|s| s.split_whitespace().next())
            .and_then(|s| s.parse().ok()),
        _ => None,
    }
}

/// Check raw file content (names, duplicates, units, frame, then the set).
pub fn check_raw(raw: &RawLandmarks) -> CheckReport {
    // Names, body frames and the first line of each landmark.
    let (mut findings, lines, seen) = name_findings(raw);
    // A landmark given more than once.
    findings.extend(duplicate_findings(&seen));
    // Units and frame: declared, detected, contradicted.
    let det = raw.detect();
    findings.extend(detection_findings(raw, &det));
    // The set itself, once units and frame are known.
    let set = raw.build_set(&det);
    let levels = set.levels();
    findings.extend(check_completeness(&set, &lines));
    if det.units.is_some() && det.frame.is_some() {
        findings.extend(check_set(&set, &lines));
    }
    CheckReport {
        file: raw.path.display().to_string(),
        findings,
        detection: Some(det),
        levels,
    }
}

/// Lines of each landmark as read (every occurrence).
type Occurrences = BTreeMap<LandmarkId, Vec<Option<usize>>>;

/// Findings on the names (LM010, LM011) and body frames (LM013); the first
/// line of each landmark and every line it occurs on.
fn name_findings(raw: &RawLandmarks) -> (Vec<Finding>, BTreeMap<LandmarkId, usize>, Occurrences) {
    let mut out = Vec::new();
    let mut lines: BTreeMap<LandmarkId, usize> = BTreeMap::new();
    let mut seen: Occurrences = BTreeMap::new();
    for p in &raw.points {
        if let Some(b) = &p.body {
            out.push(Finding {
                code: "LM013".into(),
                severity: Severity::Error,
                landmarks: vec![p.name.clone()],
                message: format!(
                    "`{}` is given in the frame of body `{b}`: a palpation of a model (base --palpation), not a patient's landmark set",
                    p.name
                ),
                line: p.line,
            });
        }
        match p.id {
            None => out.push(Finding {
                code: "LM010".into(),
                severity: Severity::Warning,
                landmarks: vec![p.name.clone()],
                message: format!(
                    "unknown landmark name `{}` (expected <LEVEL>_<CODE>, e.g. L3_SEC); ignored",
                    shown(&p.name)
                ),
                line: p.line,
            }),
            Some(i) if !i.level.allowed(i.code) => out.push(Finding {
                code: "LM010".into(),
                severity: Severity::Warning,
                landmarks: vec![p.name.clone()],
                message: format!(
                    "`{}` is not part of the protocol (S1 has SEC, SA, SP, SR, SL, PTR, PTL); ignored",
                    p.name
                ),
                line: p.line,
            }),
            Some(i) => {
                if !p.canonical {
                    out.push(Finding {
                        code: "LM011".into(),
                        severity: Severity::Warning,
                        landmarks: vec![p.name.clone()],
                        message: format!("`{}` read as `{i}`: write names exactly as `{i}`", p.name),
                        line: p.line,
                    });
                }
                if let Some(l) = p.line {
                    lines.entry(i).or_insert(l);
                }
                seen.entry(i).or_default().push(p.line);
            }
        }
    }
    (out, lines, seen)
}

/// LM012: a landmark given more than once.
fn duplicate_findings(seen: &Occurrences) -> Vec<Finding> {
    let mut out = Vec::new();
    for (i, ls) in seen {
        if ls.len() > 1 {
            let where_: Vec<String> = ls
                .iter()
                .map(|l| l.map(|l| format!("line {l}")).unwrap_or_else(|| "?".into()))
                .collect();
            out.push(Finding {
                code: "LM012".into(),
                severity: Severity::Error,
                landmarks: vec![i.to_string()],
                message: format!(
                    "`{i}` appears {} times ({}); the first is used",
                    ls.len(),
                    where_.join(", ")
                ),
                line: ls.get(1).copied().flatten(),
            });
        }
    }
    out
}

/// Units and frame findings (LM002-LM008) from the detection.
fn detection_findings(raw: &RawLandmarks, det: &Detection) -> Vec<Finding> {
    let mut out = Vec::new();
    let file_level = |code: &str, sev: Severity, msg: String| Finding {
        code: code.into(),
        severity: sev,
        landmarks: vec![],
        message: msg,
        line: None,
    };
    if det.units_conflict() {
        out.push(file_level(
            "LM002",
            Severity::Error,
            format!(
                "declared units `{}` contradict the anatomy: {}{}",
                det.declared_units
                    .map(|u| u.to_string())
                    .unwrap_or_default(),
                det.units_evidence,
                det.units
                    .map(|u| format!(" (checked as {u})"))
                    .unwrap_or_default()
            ),
        ));
    } else if det.units.is_none() {
        out.push(file_level(
            "LM006",
            Severity::Error,
            format!(
                "units not declared and not detectable: {}",
                det.units_evidence
            ),
        ));
    } else if det.declared_units.is_none() {
        out.push(file_level(
            "LM004",
            Severity::Info,
            format!("units not declared; detected: {}", det.units_evidence),
        ));
    }
    for note in &raw.notes {
        out.push(file_level("LM008", Severity::Info, note.clone()));
    }
    if det.frame_conflict() {
        out.push(file_level(
            "LM003",
            Severity::Error,
            format!(
                "declared frame `{}` contradicts the anatomy: {}{}",
                det.declared_frame
                    .map(|u| u.to_string())
                    .unwrap_or_default(),
                det.frame_evidence,
                det.frame
                    .map(|u| format!(" (checked as {u})"))
                    .unwrap_or_default()
            ),
        ));
    } else if det.frame.is_none() {
        out.push(file_level(
            "LM007",
            Severity::Error,
            format!(
                "frame not declared and not detectable: {}",
                det.frame_evidence
            ),
        ));
    } else if det.declared_frame.is_none() {
        out.push(file_level(
            "LM005",
            Severity::Info,
            format!("frame not declared; detected: {}", det.frame_evidence),
        ));
    }
    out
}

/// Completeness against the protocol: levels, contiguity, S1, landmarks.
pub fn check_completeness(set: &LandmarkSet, lines: &BTreeMap<LandmarkId, usize>) -> Vec<Finding> {
    let mut cx = Ctx {
        set,
        lines,
        out: Vec::new(),
    };
    let levels = set.levels();
    let (Some(&first), Some(&last)) = (levels.first(), levels.last()) else {
        cx.push(
            "LM020",
            Severity::Error,
            &[],
            "no valid landmarks in the file".into(),
        );
        return cx.out;
    };
    cx.push(
        "LM023",
        Severity::Info,
        &[],
        format!(
            "levels {first}..{last}: {} of {} in the run",
            levels.len(),
            last.index() - first.index() + 1
        ),
    );
    if last != Level::S1 {
        cx.push(
            "LM022",
            Severity::Error,
            &[],
            format!("the set ends at {last}: the run of levels must end at S1 (sacral endplate)"),
        );
    }
    for i in first.index()..=last.index() {
        let Some(l) = Level::from_index(i) else {
            continue;
        };
        if !levels.contains(&l) {
            cx.push(
                "LM021",
                Severity::Warning,
                &[],
                format!(
                    "level {l} missing between landmarked levels ({first}..{last}): a gap, which `generate` fills from its neighbours"
                ),
            );
            continue;
        }
        let missing: Vec<LandmarkId> = l
            .required_codes()
            .iter()
            .filter(|c| set.get(l, **c).is_none())
            .map(|c| id(l, *c))
            .collect();
        if !missing.is_empty() {
            let names: Vec<String> = missing.iter().map(|m| m.to_string()).collect();
            cx.push(
                "LM020",
                Severity::Error,
                &missing,
                format!("{l}: missing {}", names.join(", ")),
            );
        }
    }
    cx.out
}

/// Mean of the present points of the given codes at a level.
fn mean_codes(set: &LandmarkSet, l: Level, codes: &[Code]) -> Option<Point3<f64>> {
    let v: Vec<Option<Point3<f64>>> = codes.iter().map(|c| set.get(l, *c)).collect();
    mean_of(&v)
}

const SUP: [Code; 5] = [Code::SEC, Code::SA, Code::SP, Code::SR, Code::SL];
const INF: [Code; 5] = [Code::IEC, Code::IA, Code::IP, Code::IR, Code::IL];

/// Anatomical checks of a resolved set (metres, OpenSim frame).
pub fn check_set(set: &LandmarkSet, lines: &BTreeMap<LandmarkId, usize>) -> Vec<Finding> {
    let mut cx = Ctx {
        set,
        lines,
        out: Vec::new(),
    };
    let Ok(table) = DimensionTable::embedded() else {
        return cx.out;
    };
    let levels = set.levels();
    for &l in &levels {
        check_orientation(&mut cx, l);
        check_endplate_centres(&mut cx, l);
        check_dimensions(&mut cx, &table, l);
    }
    check_neighbours(&mut cx, &table, &levels);
    check_outliers(&mut cx, &table, &levels);
    cx.out
}

/// LM030-LM032, LM037: superior above inferior, anterior before
/// posterior, right right of left, pedicles behind the body.
fn check_orientation(cx: &mut Ctx, l: Level) {
    let set = cx.set;
    let (ex, ey, ez) = (Vector3::x(), Vector3::y(), Vector3::z());
    // ---- orientation
    let orient = |cx: &mut Ctx, code: &str, a: Code, b: Code, axis: Vector3<f64>, what: &str| {
        if let (Some(pa), Some(pb)) = (cx.g(l, a), cx.g(l, b)) {
            let d = mm((pa - pb).dot(&axis));
            if d < -3.0 {
                cx.push(
                    code,
                    Severity::Error,
                    &[id(l, a), id(l, b)],
                    format!("{l}_{a} is {:.1} mm {what} {l}_{b} (swapped?)", -d),
                );
            } else if d < 0.0 {
                cx.push(
                    code,
                    Severity::Warning,
                    &[id(l, a), id(l, b)],
                    format!("{l}_{a} is {:.1} mm {what} {l}_{b}", -d),
                );
            }
        }
    };
    orient(cx, "LM030", Code::SEC, Code::IEC, ey, "below");
    orient(cx, "LM031", Code::PTR, Code::PBR, ey, "below");
    orient(cx, "LM031", Code::PTL, Code::PBL, ey, "below");
    orient(cx, "LM037", Code::SA, Code::SP, ex, "posterior of");
    orient(cx, "LM037", Code::IA, Code::IP, ex, "posterior of");
    for (r, lft) in [
        (Code::PTR, Code::PTL),
        (Code::PBR, Code::PBL),
        (Code::SR, Code::SL),
        (Code::IR, Code::IL),
    ] {
        if let (Some(pr), Some(pl)) = (cx.g(l, r), cx.g(l, lft)) {
            let d = mm((pr - pl).dot(&ez));
            if d < -3.0 {
                cx.push(
                    "LM032",
                    Severity::Error,
                    &[id(l, r), id(l, lft)],
                    format!(
                        "{l}_{r} is {:.1} mm to the left of {l}_{lft} (left/right swapped?)",
                        -d
                    ),
                );
            }
        }
    }
    // pedicles behind the body
    let body = mean_codes(set, l, &[Code::SEC, Code::IEC]);
    let ped = mean_codes(set, l, &[Code::PTR, Code::PTL, Code::PBR, Code::PBL]);
    if let (Some(b), Some(p)) = (body, ped) {
        let d = mm((b - p).dot(&ex));
        if d < -3.0 {
            cx.push("LM037", Severity::Error, &[id(l, Code::SEC), id(l, Code::PTR)], format!("{l}: the pedicles are {:.1} mm anterior of the endplate centres (anterior/posterior inverted?)", -d));
        }
    }
}

/// LM033: each endplate centre inside the quadrilateral of its extreme
/// points (with the palpation noise).
fn check_endplate_centres(cx: &mut Ctx, l: Level) {
    // ---- endplate centres inside their extreme points
    for (c, a, r, p, lf) in [
        (Code::SEC, Code::SA, Code::SR, Code::SP, Code::SL),
        (Code::IEC, Code::IA, Code::IR, Code::IP, Code::IL),
    ] {
        let pts = [cx.g(l, c), cx.g(l, a), cx.g(l, r), cx.g(l, p), cx.g(l, lf)];
        if let [Some(pc), Some(pa), Some(pr), Some(pp), Some(pl)] = pts {
            if let Some(out_by) = outside_quad(pc, [pa, pr, pp, pl]) {
                if let Some((sev, why)) = lm033_severity(out_by) {
                    cx.push("LM033", sev, &[id(l, c), id(l, a), id(l, r), id(l, p), id(l, lf)], format!("{l}_{c} lies {out_by:.1} mm outside the quadrilateral of {l}_{a}/{r}/{p}/{lf} ({why})"));
                }
            }
        }
    }
}

/// LM034-LM036: endplate widths and depths and body height against the
/// published ranges of the level.
fn check_dimensions(cx: &mut Ctx, table: &DimensionTable, l: Level) {
    let set = cx.set;
    // ---- dimension ranges
    let d = table.level(l);
    let dist = |a: Code, b: Code| Some((set.get(l, a)? - set.get(l, b)?).norm());
    let range = |cx: &mut Ctx,
                 code: &str,
                 what: &str,
                 v: Option<f64>,
                 m: crate::anatomy::Measure,
                 widen: f64,
                 ids: &[LandmarkId]| {
        let Some(v) = v else { return };
        if m.is_missing() {
            return;
        }
        // Anatomical SD (widened for wedging) combined with palpation
        // noise of a distance between two landmarks (2.5 mm).
        let sd = ((m.sd * widen).max(0.08 * m.mean).powi(2) + 0.0025f64.powi(2)).sqrt();
        let (lo_w, hi_w) = (m.mean - 4.0 * sd, m.mean + 4.0 * sd);
        let (lo_e, hi_e) = (
            m.mean - (0.65 * m.mean).max(6.0 * sd),
            m.mean + m.mean.max(6.0 * sd),
        );
        let msg = format!("{l} {what} {:.1} mm; published mean {:.1} mm (warning outside {:.1}..{:.1}, error outside {:.1}..{:.1})", mm(v), mm(m.mean), mm(lo_w), mm(hi_w), mm(lo_e), mm(hi_e));
        if v < lo_e || v > hi_e {
            cx.push(code, Severity::Error, ids, msg);
        } else if v < lo_w || v > hi_w {
            cx.push(code, Severity::Warning, ids, msg);
        }
    };
    range(
        cx,
        "LM034",
        "superior endplate width",
        dist(Code::SR, Code::SL),
        d.sup_ep_width,
        1.0,
        &[id(l, Code::SR), id(l, Code::SL)],
    );
    range(
        cx,
        "LM035",
        "superior endplate depth",
        dist(Code::SA, Code::SP),
        d.sup_ep_depth,
        1.0,
        &[id(l, Code::SA), id(l, Code::SP)],
    );
    if !l.is_sacrum() {
        range(
            cx,
            "LM034",
            "inferior endplate width",
            dist(Code::IR, Code::IL),
            d.inf_ep_width,
            1.0,
            &[id(l, Code::IR), id(l, Code::IL)],
        );
        range(
            cx,
            "LM035",
            "inferior endplate depth",
            dist(Code::IA, Code::IP),
            d.inf_ep_depth,
            1.0,
            &[id(l, Code::IA), id(l, Code::IP)],
        );
        let h = crate::landmarks::frames::vertebra_dimensions(set, l).height;
        range(
            cx,
            "LM036",
            "body height",
            h,
            d.body_height(),
            1.5,
            &[id(l, Code::SA), id(l, Code::IA)],
        );
    }
}

/// Nominal palpation noise (mm, SD per coordinate) of a CT-palpated
/// landmark, as in the noise study's sets (2 mm).
pub const PALPATION_SD_MM: f64 = 2.0;

/// Severity of an endplate centre lying `out_by` mm outside its four
/// extreme points, judged against palpation noise: the signed distance of
/// a point to an edge between two other noisy points has SD
/// `sd * sqrt(1 + 1/2)` (2.4 mm at 2 mm noise). Within 2 SD it is noise
/// (info above 1 mm), up to 3 SD a warning, beyond an error.
fn lm033_severity(out_by: f64) -> Option<(Severity, String)> {
    let sd = PALPATION_SD_MM * 1.5f64.sqrt();
    if out_by <= 1.0 {
        None
    } else if out_by <= 2.0 * sd {
        Some((
            Severity::Info,
            format!("within palpation noise, 2 SD = {:.1} mm", 2.0 * sd),
        ))
    } else if out_by <= 3.0 * sd {
        Some((
            Severity::Warning,
            format!("beyond 2 SD of palpation noise, {:.1} mm", 2.0 * sd),
        ))
    } else {
        Some((
            Severity::Error,
            format!("beyond 3 SD of palpation noise, {:.1} mm", 3.0 * sd),
        ))
    }
}

/// How far (mm) `c` lies outside the quadrilateral `q` (A, R, P, L order)
/// in the best-fit plane; `None` if degenerate. Negative = inside.
fn outside_quad(c: Point3<f64>, q: [Point3<f64>; 4]) -> Option<f64> {
    let u = (q[0] - q[2]).try_normalize(1e-9)?;
    let v0 = q[1] - q[3];
    let v = (v0 - u * u.dot(&v0)).try_normalize(1e-9)?;
    let to2 = |p: Point3<f64>| (p.coords.dot(&u), p.coords.dot(&v));
    let pts: Vec<(f64, f64)> = q.iter().map(|p| to2(*p)).collect();
    let (cx, cy) = to2(c);
    let mut worst = f64::NEG_INFINITY;
    for i in 0..4 {
        let (x0, y0) = pts[i];
        let (x1, y1) = pts[(i + 1) % 4];
        let (ex, ey) = (x1 - x0, y1 - y0);
        let len = (ex * ex + ey * ey).sqrt();
        if len <= 0.0 {
            return None;
        }
        // CCW polygon: inside has positive cross product.
        let cross = (ex * (cy - y0) - ey * (cx - x0)) / len;
        worst = worst.max(-cross);
    }
    Some(mm(worst))
}

/// Cranial axis of a level from its endplate means (sign forced cranial).
fn level_axis(set: &LandmarkSet, l: Level) -> Option<Vector3<f64>> {
    let s = mean_codes(set, l, &SUP)?;
    let i = mean_codes(set, l, &INF)?;
    let a = (s - i).try_normalize(1e-9)?;
    Some(if a.y < 0.0 { -a } else { a })
}

fn centre(set: &LandmarkSet, l: Level) -> Option<Point3<f64>> {
    if l.is_sacrum() {
        set.get(l, Code::SEC).or_else(|| mean_codes(set, l, &SUP))
    } else {
        mean_codes(set, l, &[Code::SEC, Code::IEC]).or_else(|| mean_codes(set, l, &Code::ALL))
    }
}

fn check_neighbours(cx: &mut Ctx, table: &DimensionTable, levels: &[Level]) {
    let set = cx.set;
    let ey = Vector3::y();
    // Pairs of consecutive present levels (u cranial of l).
    let pairs: Vec<(Level, Level)> = levels
        .windows(2)
        .filter(|w| w[0].caudal() == Some(w[1]))
        .map(|w| (w[0], w[1]))
        .collect();
    // Disc deviation vectors per pair (for LM043).
    let mut dev: BTreeMap<Level, Vector3<f64>> = BTreeMap::new();
    for &(u, l) in &pairs {
        let (Some(cu), Some(cl)) = (centre(set, u), centre(set, l)) else {
            continue;
        };
        let du = table.level(u);
        let dl = table.level(l);
        let expected = 0.5 * du.body_height().mean
            + du.disc_height.mean
            + if l.is_sacrum() {
                0.0
            } else {
                0.5 * dl.body_height().mean
            };
        let v = cu - cl;
        let ids = [id(u, Code::SEC), id(l, Code::SEC)];
        if v.dot(&ey) <= 0.0 {
            cx.push("LM040", Severity::Error, &ids, format!("{u} is not cranial of {l} ({:.1} mm below it): levels out of order or mislabelled", mm(-v.dot(&ey))));
        }
        let ratio = v.norm() / expected;
        let msg = format!(
            "{u}-{l} centre distance {:.1} mm, expected about {:.1} mm",
            mm(v.norm()),
            mm(expected)
        );
        if !(0.4..=2.2).contains(&ratio) {
            cx.push("LM041", Severity::Error, &ids, msg);
        } else if !(0.6..=1.5).contains(&ratio) {
            cx.push("LM041", Severity::Warning, &ids, msg);
        }
        // Disc between the inferior endplate of u and the superior of l.
        let (Some(iu), Some(sl)) = (mean_codes(set, u, &INF), mean_codes(set, l, &SUP)) else {
            continue;
        };
        let axis = match (
            level_axis(set, u),
            if l.is_sacrum() {
                None
            } else {
                level_axis(set, l)
            },
        ) {
            (Some(a), Some(b)) => (a + b).normalize(),
            (Some(a), None) => a,
            (None, Some(b)) => b,
            (None, None) => ey,
        };
        let disc = iu - sl;
        let gap = mm(disc.dot(&axis));
        if gap < -4.0 {
            cx.push(
                "LM042",
                Severity::Error,
                &[id(u, Code::IEC), id(l, Code::SEC)],
                format!("{u} and {l} overlap by {:.1} mm along the spine", -gap),
            );
        }
        let shear = mm((disc - axis * disc.dot(&axis)).norm());
        if shear > 8.0 {
            cx.push("LM044", Severity::Warning, &[id(u, Code::IEC), id(l, Code::SEC)], format!("{u}-{l}: {shear:.1} mm translation across the disc (listhesis or mislabelled landmarks)"));
        }
        dev.insert(u, disc - axis * du.disc_height.mean);
        if let (Some(a), Some(b)) = (
            level_axis(set, u),
            if l.is_sacrum() {
                None
            } else {
                level_axis(set, l)
            },
        ) {
            let ang = a.angle(&b).to_degrees();
            if ang > 35.0 {
                cx.push("LM045", Severity::Warning, &[id(u, Code::SEC), id(l, Code::SEC)], format!("{u}-{l}: {ang:.0} deg between the vertebral axes (more than a severe scoliosis shows per level)"));
            }
        }
    }
    check_across_gaps(cx, table, levels);
    // LM043: vertebra v with discs above (u-v, keyed u) and below (v-l, keyed v).
    for &(u, v) in &pairs {
        let (Some(above), Some(below)) = (dev.get(&u), dev.get(&v)) else {
            continue;
        };
        let cos = above.dot(below) / (above.norm() * below.norm()).max(1e-12);
        let delta = mm(((below - above) * 0.5).norm());
        if cos < -0.5 && delta > 10.0 {
            cx.push("LM043", Severity::Error, &[id(v, Code::SEC), id(v, Code::IEC)], format!("{v} is displaced by about {delta:.1} mm with respect to both {u} and its caudal neighbour"));
        }
    }
}

/// Consecutive present levels across a gap (LM021): still in order along
/// the spine (LM040) and about as far apart as the levels between them
/// (LM041, the expected distance summed over the gap).
fn check_across_gaps(cx: &mut Ctx, table: &DimensionTable, levels: &[Level]) {
    let set = cx.set;
    for w in levels.windows(2) {
        let (u, l) = (w[0], w[1]);
        if u.caudal() == Some(l) {
            continue;
        }
        let (Some(cu), Some(cl)) = (centre(set, u), centre(set, l)) else {
            continue;
        };
        let expected: f64 = (u.index()..l.index())
            .filter_map(|i| Some((Level::from_index(i)?, Level::from_index(i + 1)?)))
            .map(|(a, b)| {
                let (da, db) = (table.level(a), table.level(b));
                0.5 * da.body_height().mean
                    + da.disc_height.mean
                    + if b.is_sacrum() {
                        0.0
                    } else {
                        0.5 * db.body_height().mean
                    }
            })
            .sum();
        let v = cu - cl;
        let ids = [id(u, Code::SEC), id(l, Code::SEC)];
        if v.y <= 0.0 {
            cx.push("LM040", Severity::Error, &ids, format!("{u} is not cranial of {l} ({:.1} mm below it): levels out of order or mislabelled", mm(-v.y)));
        }
        let ratio = v.norm() / expected;
        let msg = format!(
            "{u}-{l} centre distance {:.1} mm across the gap, expected about {:.1} mm",
            mm(v.norm()),
            mm(expected)
        );
        if !(0.4..=2.2).contains(&ratio) {
            cx.push("LM041", Severity::Error, &ids, msg);
        } else if !(0.6..=1.5).contains(&ratio) {
            cx.push("LM041", Severity::Warning, &ids, msg);
        }
    }
}

/// The default base model's landmark layout per vertebra (body frame, m):
/// `templates/landmark_layout.csv`, the markers of `base_model/base.osim`.
const LAYOUT_CSV: &str = include_str!("../../templates/landmark_layout.csv");

/// [`LAYOUT_CSV`] parsed once (rows that do not parse are skipped: the
/// file is the project's own and tested).
pub fn base_layout() -> &'static BTreeMap<Level, BTreeMap<Code, Vector3<f64>>> {
    static LAYOUT: std::sync::OnceLock<BTreeMap<Level, BTreeMap<Code, Vector3<f64>>>> =
        std::sync::OnceLock::new();
    LAYOUT.get_or_init(|| {
        let mut out: BTreeMap<Level, BTreeMap<Code, Vector3<f64>>> = BTreeMap::new();
        let path = Path::new("templates/landmark_layout.csv");
        let rows = CsvReader::new(LAYOUT_CSV, path)
            .records()
            .map_while(Result::ok);
        for row in rows.skip(1) {
            let f: Vec<&str> = row.cells().collect();
            let [lev, code, x, y, z] = f.as_slice() else {
                continue;
            };
            let Some((id, _)) = LandmarkId::parse_name(&format!("{lev}_{code}")) else {
                continue;
            };
            let (Ok(x), Ok(y), Ok(z)) = (x.parse(), y.parse(), z.parse()) else {
                continue;
            };
            out.entry(id.level)
                .or_default()
                .insert(id.code, Vector3::new(x, y, z));
        }
        out
    })
}

fn check_outliers(cx: &mut Ctx, table: &DimensionTable, levels: &[Level]) {
    struct Fit {
        ids: Vec<LandmarkId>,
        resid: Vec<Vector3<f64>>,
        lev: Vec<f64>,
    }
    // Two anatomical templates: the analytic layout from the dimension
    // table and the default base model's palpated markers. Each vertebra
    // is judged against the one that fits it better (sum of squared
    // leave-one-out residuals without the largest, so that the outlier
    // being looked for does not choose), since real vertebrae differ from
    // either by more than palpation noise (pedicles up to ~15 mm).
    let mut fits = Vec::new();
    for &l in levels.iter().filter(|l| !l.is_sacrum()) {
        let d = table.level(l);
        let layout = base_layout().get(&l);
        let mut best: Option<(f64, Fit)> = None;
        for use_layout in [false, true] {
            let mut ids = Vec::new();
            let mut xs = Vec::new();
            let mut ys = Vec::new();
            for c in Code::ALL {
                let t = if use_layout {
                    layout.and_then(|m| m.get(&c).copied())
                } else {
                    local_position(d, c)
                };
                if let (Some(p), Some(t)) = (cx.set.get(l, c), t) {
                    ids.push(id(l, c));
                    xs.push(t);
                    ys.push(p.coords);
                }
            }
            let n = ids.len();
            if n < 10 {
                continue;
            }
            let x = DMatrix::from_fn(n, 4, |i, j| if j < 3 { xs[i][j] } else { 1.0 });
            let y = DMatrix::from_fn(n, 3, |i, j| ys[i][j]);
            let xtx = x.transpose() * &x;
            let Some(inv) = xtx.try_inverse() else {
                continue;
            };
            let h = &x * inv * x.transpose();
            let e = &y - &h * &y;
            let fit = Fit {
                resid: (0..n)
                    .map(|i| Vector3::new(e[(i, 0)], e[(i, 1)], e[(i, 2)]))
                    .collect(),
                lev: (0..n).map(|i| h[(i, i)]).collect(),
                ids,
            };
            let loo: Vec<f64> = fit
                .resid
                .iter()
                .zip(&fit.lev)
                .map(|(r, h)| r.norm_squared() / (1.0 - h).max(1e-6))
                .collect();
            let score = loo.iter().sum::<f64>() - loo.iter().fold(0.0f64, |a, b| a.max(*b));
            if best.as_ref().is_none_or(|(b, _)| score < *b) {
                best = Some((score, fit));
            }
        }
        if let Some((_, f)) = best {
            fits.push(f);
        }
    }
    let mut comps: Vec<f64> = fits
        .iter()
        .flat_map(|f| {
            f.resid.iter().zip(&f.lev).flat_map(|(r, h)| {
                let s = (1.0 - h).max(1e-6).sqrt();
                [r.x.abs() / s, r.y.abs() / s, r.z.abs() / s]
            })
        })
        .collect();
    if comps.is_empty() {
        return;
    }
    comps.sort_by(f64::total_cmp);
    let sigma = (comps[comps.len() / 2] / 0.6745).max(0.0003);
    for f in &fits {
        for ((i, r), h) in f.ids.iter().zip(&f.resid).zip(&f.lev) {
            let one_minus = (1.0 - h).max(1e-6);
            let loo = r.norm() / one_minus;
            let stud = r.norm() / one_minus.sqrt();
            if mm(loo) > 6.0 && stud > 5.0 * sigma {
                cx.push("LM050", Severity::Warning, &[*i], format!("{i} is {:.1} mm from where the other {} landmarks of its vertebra put it ({:.1} robust SDs)", mm(loo), f.ids.len() - 1, stud / sigma));
            }
        }
    }
}

// ------------------------------------------------------------------ output

/// Plain-text report.
pub fn format_text(reports: &[CheckReport]) -> String {
    let mut s = String::new();
    for r in reports {
        let mut per_code: BTreeMap<&str, usize> = BTreeMap::new();
        for f in &r.findings {
            let n = per_code.entry(f.code.as_str()).or_default();
            *n += 1;
            if *n > MAX_LINES_PER_KIND {
                continue;
            }
            let sev = match f.severity {
                Severity::Error => "error",
                Severity::Warning => "warning",
                Severity::Info => "info",
            };
            let loc = f.line.map(|l| format!(":{l}")).unwrap_or_default();
            let lm = if f.landmarks.is_empty() {
                String::new()
            } else {
                let names: Vec<String> = f.landmarks.iter().map(|n| shown(n)).collect();
                format!(" [{}]", names.join(", "))
            };
            s.push_str(&format!(
                "{}{loc}: {sev} {}{lm}: {}\n",
                r.file, f.code, f.message
            ));
        }
        for (code, n) in per_code {
            if n > MAX_LINES_PER_KIND {
                s.push_str(&format!(
                    "{}: ... and {} more {code} like this (all in --format json)\n",
                    r.file,
                    n - MAX_LINES_PER_KIND
                ));
            }
        }
        if let Some(d) = &r.detection {
            s.push_str(&format!("{}: {}\n", r.file, d.summary()));
        }
        s.push_str(&format!(
            "{}: {} error(s), {} warning(s), {} info\n",
            r.file,
            r.count(Severity::Error),
            r.count(Severity::Warning),
            r.count(Severity::Info)
        ));
    }
    s
}

/// Most lines of one finding code per file in the text report; the rest
/// are counted.
pub const MAX_LINES_PER_KIND: usize = 20;

/// JSON report (array of per-file reports).
pub fn format_json(reports: &[CheckReport]) -> String {
    serde_json::to_string_pretty(reports).unwrap_or_else(|e| format!("{{\"error\": \"{e}\"}}"))
}

fn gh_escape_data(s: &str) -> String {
    s.replace('%', "%25")
        .replace('\r', "%0D")
        .replace('\n', "%0A")
}

fn gh_escape_prop(s: &str) -> String {
    gh_escape_data(s).replace(':', "%3A").replace(',', "%2C")
}

/// GitHub Actions workflow commands (`::error file=F,line=N,title=LM0xx::msg`).
pub fn format_github(reports: &[CheckReport]) -> String {
    let mut s = String::new();
    for r in reports {
        for f in &r.findings {
            let cmd = match f.severity {
                Severity::Error => "error",
                Severity::Warning => "warning",
                Severity::Info => "notice",
            };
            let line = f.line.map(|l| format!(",line={l}")).unwrap_or_default();
            s.push_str(&format!(
                "::{cmd} file={}{line},title={}::{}\n",
                gh_escape_prop(&r.file),
                f.code,
                gh_escape_data(&f.message)
            ));
        }
    }
    s
}
