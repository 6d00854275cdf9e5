//! The load-case design, read from the case definitions only (never from
//! measured values): each case's load axis, sign, moment magnitude and
//! follower load; the held-out split (magnitude and follower-load
//! extrapolation); and which effects the design cannot test, with the
//! load cases that would (named in the experiment's own id style).

use crate::calibrate::experiment::LoadCase;
use serde::Serialize;
use std::collections::{BTreeMap, BTreeSet};

/// Axis names of the format (X lateral bending, Y axial rotation, Z flexion/extension).
pub const AXIS_NAMES: [&str; 3] = ["LB", "AR", "FE"];

/// The structure of one case.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CaseInfo {
    /// The case's id in the experiment.
    pub id: String,
    /// Dominant moment axis (0 X, 1 Y, 2 Z), None without a moment.
    pub axis: Option<usize>,
    /// Sign of the dominant component (+1 / -1; 0 without a moment).
    pub sign: i8,
    /// Moment magnitude (N m).
    pub magnitude: f64,
    /// Follower load (N).
    pub follower: f64,
}

impl CaseInfo {
    /// Read the structure of a case.
    pub fn of(c: &LoadCase) -> CaseInfo {
        let m = c.moment;
        let mag = (m[0] * m[0] + m[1] * m[1] + m[2] * m[2]).sqrt();
        let (axis, sign) = if mag > 0.0 {
            let mut a = 0;
            for i in 1..3 {
                if m[i].abs() > m[a].abs() {
                    a = i;
                }
            }
            (Some(a), if m[a] > 0.0 { 1 } else { -1 })
        } else {
            (None, 0)
        };
        CaseInfo {
            id: c.id.clone(),
            axis,
            sign,
            magnitude: mag,
            follower: c.follower_load,
        }
    }
}

/// Magnitudes equal to 1e-9 relative.
fn same(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-9 * a.abs().max(b.abs()).max(1.0)
}

/// Sorted distinct values.
fn distinct(v: impl Iterator<Item = f64>) -> Vec<f64> {
    let mut out: Vec<f64> = Vec::new();
    for x in v {
        if !out.iter().any(|y| same(*y, x)) {
            out.push(x);
        }
    }
    out.sort_by(|a, b| a.total_cmp(b));
    out
}

/// A missing load case that would make an effect testable.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MissingCase {
    /// The load case to add.
    pub case: String,
    /// The effect it would make testable (`diagnosis.json` name).
    pub effect: String,
    /// Why it is needed.
    pub reason: String,
}

/// The held-out design and the identifiability of the effects.
#[derive(Debug, Clone, Serialize)]
pub struct Design {
    /// Every case's structure, in experiment order.
    pub cases: Vec<CaseInfo>,
    /// Indices of the cases used for fitting.
    pub train: Vec<usize>,
    /// Indices of the cases kept out of every fit.
    pub heldout: Vec<usize>,
    /// How the held-out cases were chosen.
    pub rule: String,
    /// Number of folds of a K-fold design over (case, level) rows, or of
    /// the leave-one-level-out design (0: a single split into `train` and
    /// `heldout` cases); set by [`Design::assign_folds`].
    pub folds: usize,
    /// The measured levels (indices into the simulated levels), in order:
    /// a K-fold design is built over these only.
    pub levels: Vec<usize>,
    /// The fold of each held-out row `(case, level)` of a K-fold design.
    #[serde(skip)]
    pub row_fold: BTreeMap<(usize, usize), usize>,
    /// Rows `(case, level)` of a K-fold design kept in training by every
    /// fold: nothing else in training could predict them (no other row
    /// loads the same axis and measures the same DoFs), so a held-out
    /// prediction would be the nominal model's, whatever the candidate.
    pub kept: Vec<(usize, usize)>,
    /// Leave-one-level-out (a published table's design): fold `l` holds
    /// out every row of level `l`.
    pub by_level: bool,
    /// Only the rotation about each case's load axis is measured (see
    /// [`Design::note_measurement`]).
    pub primary_only: bool,
    /// Effects the design cannot test at all, with the reason.
    pub untestable: Vec<(String, String)>,
    /// Effects the design tests only indirectly, with the reason: under
    /// one magnitude per direction, a deflection-dependent stiffness shows
    /// only through the different deflections of the levels, which the
    /// K-fold design cross-validates; a small one goes unseen.
    pub weakly_tested: Vec<(String, String)>,
    /// Load cases that would make them testable.
    pub missing: Vec<MissingCase>,
    /// True when a follower-load case exists.
    pub has_follower: bool,
    /// True when some translation is measured (see [`Design::note_measurement`]).
    pub translations: bool,
}

/// Format a number as the ids do (`2.5`, `7.5`, `5`).
fn fmt_num(x: f64) -> String {
    let r = (x * 1000.0).round() / 1000.0;
    if r.fract() == 0.0 {
        format!("{}", r as i64)
    } else {
        format!("{r}")
    }
}

/// The id style of the experiment: `<AXIS>_<pos|neg>_<magnitude>` with the
/// axis tokens and sign words learnt from ids of that shape (defaults
/// `LB`/`AR`/`FE`, `pos`/`neg`).
struct IdStyle {
    axis: [String; 3],
    pos: String,
    neg: String,
}

impl IdStyle {
    fn learn(cases: &[CaseInfo]) -> IdStyle {
        let mut s = IdStyle {
            axis: AXIS_NAMES.map(String::from),
            pos: "pos".into(),
            neg: "neg".into(),
        };
        for c in cases {
            let (Some(a), true) = (c.axis, c.follower == 0.0) else {
                continue;
            };
            let parts: Vec<&str> = c.id.split('_').collect();
            if let [ax, sg, mag] = parts.as_slice() {
                if mag
                    .parse::<f64>()
                    .map(|m| same(m, c.magnitude))
                    .unwrap_or(false)
                {
                    s.axis[a] = ax.to_string();
                    if c.sign > 0 {
                        s.pos = sg.to_string();
                    } else {
                        s.neg = sg.to_string();
                    }
                }
            }
        }
        s
    }
    fn id(&self, axis: usize, sign: i8, mag: f64) -> String {
        let sg = if sign > 0 { &self.pos } else { &self.neg };
        format!("{}_{}_{}", self.axis[axis], sg, fmt_num(mag))
    }
}

/// Folds of the K-fold design over (case, level) rows.
pub const FOLDS: usize = 6;

/// What a design leaves untestable and the load cases that would test it.
#[derive(Default)]
struct Gaps {
    untestable: Vec<(String, String)>,
    /// Effects tested on part of the design only.
    partial: Vec<(String, String)>,
    missing: Vec<MissingCase>,
}

impl Gaps {
    /// Single magnitudes and single directions of each loaded axis.
    fn of_axes(info: &[CaseInfo], style: &IdStyle) -> Gaps {
        let mut g = Gaps::default();
        let mut nonlinear_gaps = Vec::new();
        let mut sign_gaps = Vec::new();
        for a in 0..3 {
            let on: Vec<&CaseInfo> = info.iter().filter(|c| c.axis == Some(a)).collect();
            if on.is_empty() {
                continue;
            }
            let mags = distinct(on.iter().map(|c| c.magnitude));
            let signs: BTreeSet<i8> = on.iter().map(|c| c.sign).collect();
            if mags.len() < 2 {
                nonlinear_gaps.push(AXIS_NAMES[a]);
                g.second_magnitude(style, a, mags.first().copied().unwrap_or(1.0), &signs);
            }
            if signs.len() < 2 {
                sign_gaps.push(AXIS_NAMES[a]);
                g.other_direction(style, a, &mags, *signs.iter().next().unwrap_or(&1));
            }
        }
        if !nonlinear_gaps.is_empty() {
            let why = format!(
                "a single moment magnitude about {}",
                nonlinear_gaps.join(", ")
            );
            g.untestable.push(("nonlinear_stiffness".to_string(), why));
        }
        if !sign_gaps.is_empty() {
            let why = format!("one moment direction only about {}", sign_gaps.join(", "));
            // tested about the axes loaded both ways, untestable without one
            let loaded = (0..3).filter(|a| info.iter().any(|c| c.axis == Some(*a)));
            if loaded.count() > sign_gaps.len() {
                let why = format!("{why}: tested about the other axes only");
                g.partial.push(("asymmetric_stiffness".to_string(), why));
            } else {
                g.untestable.push(("asymmetric_stiffness".to_string(), why));
            }
        }
        if !info.iter().any(|c| c.follower > 0.0) {
            g.untestable.push((
                "preload_stiffening".to_string(),
                "no follower-load case: stiffness under compression is never probed".to_string(),
            ));
        }
        g
    }

    /// The cases of a second magnitude (half and twice `m`) about axis `a`.
    fn second_magnitude(&mut self, style: &IdStyle, a: usize, m: f64, signs: &BTreeSet<i8>) {
        for &sg in signs {
            for other in [m / 2.0, 2.0 * m] {
                self.missing.push(MissingCase {
                    case: style.id(a, sg, other),
                    effect: "nonlinear_stiffness".into(),
                    reason: format!(
                        "a single moment magnitude ({} N m) about {}: a deflection-dependent stiffness is absorbed by a linear one; a second magnitude separates them",
                        fmt_num(m),
                        AXIS_NAMES[a]
                    ),
                });
            }
        }
    }

    /// The cases of the other direction about axis `a`.
    fn other_direction(&mut self, style: &IdStyle, a: usize, mags: &[f64], have: i8) {
        for &m in mags {
            self.missing.push(MissingCase {
                case: style.id(a, -have, m),
                effect: "asymmetric_stiffness".into(),
                reason: format!(
                    "moments about {} in one direction only: the stiffness of the other side is never loaded",
                    AXIS_NAMES[a]
                ),
            });
        }
    }
}

/// The extrapolation split: the largest magnitude of every axis with two
/// or more, and every case under the largest of two or more follower
/// loads, are held out. Returns the held-out flags and the rule's parts
/// (empty when the design has no such regime).
fn extrapolation_split(info: &[CaseInfo]) -> (Vec<bool>, Vec<String>) {
    let mut held = vec![false; info.len()];
    let mut rules = Vec::new();
    for a in 0..3 {
        let on: Vec<usize> = (0..info.len())
            .filter(|&i| info[i].axis == Some(a))
            .collect();
        let mags = distinct(on.iter().map(|&i| info[i].magnitude));
        if mags.len() >= 2 {
            let top = mags[mags.len() - 1];
            for &i in &on {
                held[i] |= same(info[i].magnitude, top);
            }
            rules.push(format!("{} moments of {} N m", AXIS_NAMES[a], fmt_num(top)));
        }
    }
    let fls = distinct(info.iter().map(|c| c.follower).filter(|f| *f > 0.0));
    if fls.len() >= 2 {
        let top = fls[fls.len() - 1];
        for (i, c) in info.iter().enumerate() {
            held[i] |= same(c.follower, top);
        }
        rules.push(format!(
            "every case under the {} N follower load",
            fmt_num(top)
        ));
    }
    (held, rules)
}

impl Design {
    /// Analyse the cases.
    pub fn new(cases: &[LoadCase]) -> Design {
        let info: Vec<CaseInfo> = cases.iter().map(CaseInfo::of).collect();
        let style = IdStyle::learn(&info);
        let has_follower = info.iter().any(|c| c.follower > 0.0);
        let Gaps {
            mut untestable,
            partial,
            mut missing,
        } = Gaps::of_axes(&info, &style);
        // held-out split: largest magnitude of every axis, largest follower load
        let (held, rules) = extrapolation_split(&info);
        let train: Vec<usize> = (0..info.len()).filter(|&i| !held[i]).collect();
        // every loaded axis must stay in the training set
        let axis_ok = (0..3).all(|a| {
            !info.iter().any(|c| c.axis == Some(a))
                || train.iter().any(|&i| info[i].axis == Some(a))
        });
        if rules.is_empty() || !axis_ok || train.is_empty() {
            // no extrapolation regime: K-fold over (case, level) rows
            let all: Vec<usize> = (0..info.len()).collect();
            // a single magnitude: the levels' different deflections still
            // sample the law at different points, cross-validated
            let (weakly_tested, untestable): (Vec<_>, Vec<_>) = untestable
                .into_iter()
                .partition(|(e, _)| e == "nonlinear_stiffness");
            let weakly_tested = weakly_tested
                .into_iter()
                .map(|(e, why)| (e, format!("{why}: tested only through the levels' different deflections (cross-validated); a second magnitude tests it directly")))
                .chain(partial)
                .collect();
            return Design {
                cases: info,
                train: all.clone(),
                heldout: all,
                rule: format!(
                    "{FOLDS}-fold cross-validation over (case, level) rows: fold f holds out the row of case c at the l-th measured level when (c + l) mod {FOLDS} = f, so each fold keeps every level and both directions of every axis in training, and every row is predicted once by a fit that never saw it (the design has no second magnitude or follower load to extrapolate to)"
                ),
                folds: FOLDS,
                levels: Vec::new(),
                row_fold: BTreeMap::new(),
                kept: Vec::new(),
                by_level: false,
                primary_only: false,
                untestable,
                weakly_tested,
                missing,
                has_follower,
                translations: true,
            };
        }
        let heldout = (0..info.len()).filter(|&i| held[i]).collect();
        split_gaps(&info, &train, &style, &mut untestable, &mut missing);
        Design {
            cases: info,
            train,
            heldout,
            rule: format!("held out: {}; fitted on the rest", rules.join("; ")),
            folds: 0,
            levels: Vec::new(),
            row_fold: BTreeMap::new(),
            kept: Vec::new(),
            by_level: false,
            primary_only: false,
            untestable,
            weakly_tested: partial,
            missing,
            has_follower,
            translations: true,
        }
    }

    /// True for a published table's design: one magnitude per direction
    /// (a K-fold design) and only the primary rotations measured.
    pub fn is_table(&self) -> bool {
        self.folds > 0 && self.primary_only
    }

    /// The design of a published table: one magnitude per direction and
    /// only the primary rotations, over the `measured` levels (indices
    /// into the simulated levels; at least 3). A per-level, per-direction
    /// stiffness predicts the held-out direction of a level from nothing
    /// the fit saw, so the design holds out whole levels and predicts each
    /// from the others (leave-one-level-out): what it tests is a stiffness
    /// trend along the spine and a direction asymmetry shared by the
    /// levels. Levels on the load path that were not measured take no
    /// part. Returns false (and changes nothing) when the design is not a
    /// table's or has fewer than three measured levels.
    pub fn leave_one_level_out(&mut self, measured: &[usize]) -> bool {
        let n_levels = measured.len();
        if !self.is_table() || n_levels < 3 {
            return false;
        }
        self.by_level = true;
        self.levels = measured.to_vec();
        self.folds = n_levels;
        self.rule = format!(
            "leave-one-level-out over the {n_levels} measured levels: fold l holds out every row of level l and predicts it from a fit to the other levels (one magnitude per direction and only the primary rotations: a stiffness trend along the spine and a direction asymmetry shared by the levels are what such a table can test; a per-level, per-direction stiffness cannot be predicted for a level the fit never saw)"
        );
        true
    }

    /// A table's design over fewer than three measured levels: a trend
    /// along the spine cannot be tested (no level can be predicted from a
    /// trend through the others), and the cases measured at more levels
    /// would test it.
    pub fn note_few_levels(&mut self, n_levels: usize) {
        const LEVEL: &str = "level_dependent_stiffness";
        let what = if n_levels == 1 {
            "a single measured level".to_string()
        } else {
            format!("{n_levels} measured levels")
        };
        self.untestable.push((
            LEVEL.into(),
            format!("{what}: a trend along the spine is tested by predicting a level from a trend through the others, which needs at least three levels"),
        ));
        self.missing.push(MissingCase {
            case: "the same cases measured at three or more levels".into(),
            effect: LEVEL.into(),
            reason: "a level predicted from a trend fitted to the others tests a stiffness that changes along the spine".into(),
        });
        // One level and one magnitude: the law is sampled at one deflection
        // per direction, so there are no different deflections to test it by.
        const NONLINEAR: &str = "nonlinear_stiffness";
        if n_levels == 1 {
            if let Some(k) = self.weakly_tested.iter().position(|(e, _)| e == NONLINEAR) {
                self.weakly_tested.remove(k);
                self.untestable.push((
                    NONLINEAR.into(),
                    "a single measured level and one magnitude per direction: the law is seen at one deflection per direction, so its shape cannot be tested".into(),
                ));
            }
        }
    }

    /// Assign the rows `(case, level, measured DoFs)` of a K-fold design to
    /// folds, over the measured levels only (each level's rank among them,
    /// not its index on the load path): leave-one-level-out, or row
    /// `(c, l)` in fold `(c + rank(l)) mod FOLDS`. A row nothing else in
    /// training could predict (no training row of a case loading the same
    /// axis measures its DoFs) stays in training in every fold; the folds
    /// left with no row are dropped and the rest numbered in order. Does
    /// nothing in a single-split design.
    pub fn assign_folds(&mut self, rows: &[(usize, usize, Vec<usize>)]) {
        if self.folds == 0 {
            return;
        }
        // the measured levels, unless leave-one-level-out named them
        if self.levels.is_empty() {
            let set: BTreeSet<usize> = rows.iter().map(|r| r.1).collect();
            self.levels = set.into_iter().collect();
        }
        let rank = |l: usize| self.levels.iter().position(|&x| x == l).unwrap_or(l);
        let first: Vec<usize> = rows
            .iter()
            .map(|&(c, l, _)| {
                if self.by_level {
                    rank(l)
                } else {
                    (c + rank(l)) % FOLDS
                }
            })
            .collect();
        let kept = self.unpredictable_rows(rows, &first);
        // folds that still hold a row out, numbered in order
        let used: BTreeSet<usize> = (0..rows.len())
            .filter(|&i| !kept[i])
            .map(|i| first[i])
            .collect();
        let number = |f: usize| used.iter().position(|&u| u == f).unwrap_or(0);
        self.row_fold = (0..rows.len())
            .filter(|&i| !kept[i])
            .map(|i| ((rows[i].0, rows[i].1), number(first[i])))
            .collect();
        self.kept = (0..rows.len())
            .filter(|&i| kept[i])
            .map(|i| (rows[i].0, rows[i].1))
            .collect();
        self.folds = used.len();
        // The planned K-fold text claims every level stays in training; say
        // what is left when folds were dropped or one level is measured.
        if !self.by_level && (used.len() != FOLDS || self.levels.len() < 2) {
            self.rule = format!(
                "{}-fold cross-validation over (case, level) rows of {} measured level(s) ({FOLDS} folds planned, those with no row to hold out dropped): row (c, l) is held out in fold (c + l) mod {FOLDS}, and every held-out row is predicted once by a fit that never saw it",
                used.len(),
                self.levels.len()
            );
        }
        if !self.kept.is_empty() {
            let ids: BTreeSet<&str> = self
                .kept
                .iter()
                .filter_map(|k| self.cases.get(k.0))
                .map(|c| c.id.as_str())
                .collect();
            self.rule.push_str(&format!(
                "; {} row(s) stay in training in every fold, as nothing else in training loads the same axis and measures the same DoFs (cases {})",
                self.kept.len(),
                ids.into_iter().collect::<Vec<_>>().join(", ")
            ));
        }
        // the held-out cases: those with a row some fold holds out
        let held: BTreeSet<usize> = self.row_fold.keys().map(|k| k.0).collect();
        self.heldout = held.into_iter().collect();
    }

    /// The rows (flags) that stay in training: repeatedly, a row whose
    /// fold `first[i]` leaves in training no row of a case loading the
    /// same axis that measures each of its DoFs (rows kept so far count as
    /// training in every fold).
    fn unpredictable_rows(
        &self,
        rows: &[(usize, usize, Vec<usize>)],
        first: &[usize],
    ) -> Vec<bool> {
        let axis = |i: usize| self.cases.get(rows[i].0).and_then(|c| c.axis);
        let mut kept = vec![false; rows.len()];
        loop {
            let mut changed = false;
            for i in 0..rows.len() {
                if kept[i] {
                    continue;
                }
                let trains = |j: usize| kept[j] || first[j] != first[i];
                let predictable = rows[i].2.iter().all(|d| {
                    (0..rows.len())
                        .any(|j| trains(j) && axis(j) == axis(i) && rows[j].2.contains(d))
                });
                if !predictable {
                    kept[i] = true;
                    changed = true;
                }
            }
            if !changed {
                return kept;
            }
        }
    }

    /// True when the row of `case` at `level` is held out (in a K-fold
    /// design, by some fold; otherwise when its case is a held-out case).
    pub fn holds_out(&self, case: usize, level: usize) -> bool {
        self.heldout.contains(&case) && !self.kept.contains(&(case, level))
    }

    /// A table's design on a specimen whose levels' own axes are tilted
    /// differently about the ground axes (`tilt_spread`, deg, per axis;
    /// `primary`: the axes measured as primary rotations): a level pattern
    /// about such an axis can come from a coupling (untestable here), so a
    /// trend is tested only about the other axes, and not at all when none
    /// is left.
    pub fn note_tilt(&mut self, tilt_spread: [f64; 3], primary: [bool; 3], tol_deg: f64) {
        const LEVEL: &str = "level_dependent_stiffness";
        let tilted: Vec<usize> = (0..3)
            .filter(|&d| primary[d] && tilt_spread[d] > tol_deg)
            .collect();
        if tilted.is_empty() {
            return;
        }
        let names: Vec<String> = tilted
            .iter()
            .map(|&d| format!("{} ({:.0} deg)", ["LB", "AR", "FE"][d], tilt_spread[d]))
            .collect();
        let why = format!(
            "the levels' joint axes are tilted differently from the load axes about {}: with only the primary rotations on ground axes, a level pattern there can come from a coupling as well as from a level-dependent stiffness",
            names.join(", ")
        );
        let left = (0..3).any(|d| primary[d] && !tilted.contains(&d));
        if left {
            self.weakly_tested.push((
                LEVEL.into(),
                format!("{why}: a trend is tested about the other axes only"),
            ));
        } else {
            self.untestable.push((LEVEL.into(), why));
        }
        self.missing.push(MissingCase {
            case: "the rotations about the unloaded axes (rx, ry, rz of every case)".into(),
            effect: LEVEL.into(),
            reason: "coupled rotations separate a coupling from a level-dependent stiffness at levels whose axes are tilted".into(),
        });
    }

    /// The effect names the design cannot test.
    pub fn untestable_names(&self) -> Vec<String> {
        self.untestable.iter().map(|(e, _)| e.clone()).collect()
    }

    /// True when a joint-centre offset (joint pose error) rests on the
    /// follower-load cases alone: with no translation measured, a joint
    /// centre moved relative to the follower guides cannot be told from
    /// guides placed off the joint centres (a rig error outside the
    /// vocabulary); translations would separate them.
    pub fn offsets_confounded_with_guides(&self) -> bool {
        self.has_follower && !self.translations
    }

    /// True when the effect is untestable by design.
    pub fn is_untestable(&self, effect: &str) -> bool {
        self.untestable.iter().any(|(e, _)| e == effect)
    }

    /// The fold that holds out the row of `case` at `level` (K-fold
    /// designs only, after [`Design::assign_folds`]; `None` for a row kept
    /// in training).
    pub fn fold_of(&self, case: usize, level: usize) -> Option<usize> {
        self.row_fold.get(&(case, level)).copied()
    }

    /// Effects the measured quantities cannot show, given which DoFs
    /// (`rx .. tz`) are measured in each case: coupling shows in the
    /// rotations about the axes that were not loaded, and a joint pose
    /// error under pure moments only in those or in the translations (a
    /// misplaced centre does not change the rotation a pure moment causes,
    /// a tilted axis changes it to second order only); follower loads and
    /// forces make the centre matter.
    pub fn note_measurement(&mut self, measured: &[[bool; 6]]) {
        let off_axis = self.cases.iter().zip(measured).any(|(c, m)| match c.axis {
            Some(a) => (0..3).any(|d| d != a && m[d]),
            None => m[..3].iter().any(|&x| x),
        });
        let translations = measured.iter().any(|m| m[3..].iter().any(|&x| x));
        self.translations = translations;
        self.primary_only = !off_axis && !translations;
        let what = "the rotations about the unloaded axes (rx, ry, rz of every case)";
        if !off_axis {
            self.untestable.push((
                "coupled_stiffness".into(),
                "only the rotation about each load axis is measured: a coupling shows in the rotations about the other axes".into(),
            ));
            self.missing.push(MissingCase {
                case: what.into(),
                effect: "coupled_stiffness".into(),
                reason:
                    "coupled motion separates an off-diagonal stiffness from a softer diagonal one"
                        .into(),
            });
        }
        if !off_axis && !translations && !self.has_follower {
            self.untestable.push((
                "joint_pose_error".into(),
                "pure moments with only the primary rotations measured: a misplaced joint centre does not change them and a tilted axis only to second order".into(),
            ));
            self.missing.push(MissingCase {
                case: format!("{what}, the translations (tx, ty, tz), or follower-load cases"),
                effect: "joint_pose_error".into(),
                reason: "a moved joint centre or axis shows in coupled rotations, translations and the moment a follower load exerts".into(),
            });
        }
    }
}

/// Effects the chosen split cannot test although the design could: an
/// asymmetry needs both directions of an axis among the training cases
/// (with one magnitude per direction the interleaved split trains on one
/// direction and predicts the other). The missing cases: a second, smaller
/// magnitude in both directions, so that the larger one can be held out.
fn split_gaps(
    info: &[CaseInfo],
    train: &[usize],
    style: &IdStyle,
    untestable: &mut Vec<(String, String)>,
    missing: &mut Vec<MissingCase>,
) {
    const ASYM: &str = "asymmetric_stiffness";
    if untestable.iter().any(|(e, _)| e == ASYM) {
        return;
    }
    let both = |a: usize, set: &mut dyn Iterator<Item = &CaseInfo>| {
        let signs: BTreeSet<i8> = set.filter(|c| c.axis == Some(a)).map(|c| c.sign).collect();
        signs.len() == 2
    };
    let axes: Vec<usize> = (0..3)
        .filter(|&a| both(a, &mut info.iter()))
        .filter(|&a| !both(a, &mut train.iter().map(|&i| &info[i])))
        .collect();
    if axes.is_empty() || axes.len() < (0..3).filter(|&a| both(a, &mut info.iter())).count() {
        return;
    }
    let names: Vec<&str> = axes.iter().map(|&a| AXIS_NAMES[a]).collect();
    untestable.push((
        ASYM.to_string(),
        format!(
            "one moment magnitude per direction about {}: the held-out direction's stiffness is never seen in training",
            names.join(", ")
        ),
    ));
    for &a in &axes {
        let mags = distinct(
            info.iter()
                .filter(|c| c.axis == Some(a))
                .map(|c| c.magnitude),
        );
        let m = mags.first().copied().unwrap_or(1.0) / 2.0;
        for sg in [-1, 1] {
            missing.push(MissingCase {
                case: style.id(a, sg, m),
                effect: ASYM.into(),
                reason: format!(
                    "a second, smaller magnitude in both directions about {}: both sides are then fitted and the larger magnitude predicted",
                    AXIS_NAMES[a]
                ),
            });
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn case(id: &str, m: [f64; 3], fl: f64) -> LoadCase {
        LoadCase {
            id: id.into(),
            body: "b".into(),
            moment: m,
            moment_frame: None,
            force: [0.0; 3],
            force_point: [0.0; 3],
            force_frame: None,
            follower_load: fl,
        }
    }

    #[test]
    fn full_design_holds_out_the_largest_magnitude_and_follower_load() {
        let mut cs = Vec::new();
        for (a, n) in AXIS_NAMES.iter().enumerate() {
            for s in [-1.0, 1.0] {
                for m in [1.0, 2.5, 7.5] {
                    let mut v = [0.0; 3];
                    v[a] = s * m;
                    let sg = if s > 0.0 { "pos" } else { "neg" };
                    cs.push(case(&format!("{n}_{sg}_{m}"), v, 0.0));
                    cs.push(case(&format!("{n}_{sg}_{m}_FL250"), v, 250.0));
                    cs.push(case(&format!("{n}_{sg}_{m}_FL500"), v, 500.0));
                }
            }
        }
        let d = Design::new(&cs);
        assert!(d.untestable.is_empty());
        for &i in &d.heldout {
            let c = &d.cases[i];
            assert!(c.magnitude == 7.5 || c.follower == 500.0, "{}", c.id);
        }
        for &i in &d.train {
            let c = &d.cases[i];
            assert!(c.magnitude < 7.5 && c.follower < 500.0, "{}", c.id);
        }
        assert_eq!(d.train.len() + d.heldout.len(), cs.len());
    }

    #[test]
    fn one_magnitude_per_direction_gives_k_folds_that_keep_both_directions() {
        let mut cs = Vec::new();
        for (a, n) in AXIS_NAMES.iter().enumerate() {
            for (s, sg) in [(-1.0, "neg"), (1.0, "pos")] {
                let mut v = [0.0; 3];
                v[a] = s * 10.0;
                cs.push(case(&format!("{n}_{sg}_10"), v, 0.0));
            }
        }
        let mut d = Design::new(&cs);
        assert!(!d.is_untestable("nonlinear_stiffness"));
        assert!(d
            .weakly_tested
            .iter()
            .any(|(e, _)| e == "nonlinear_stiffness"));
        let names: Vec<&str> = d.missing.iter().map(|m| m.case.as_str()).collect();
        assert!(
            names.contains(&"FE_pos_5") && names.contains(&"FE_neg_5"),
            "{names:?}"
        );
        // every case at five levels, all three rotations measured
        let levels = 5;
        d.assign_folds(&rows(cs.len(), &[0, 1, 2, 3, 4], |_| vec![0, 1, 2]));
        assert!(d.kept.is_empty(), "{:?}", d.kept);
        // K-fold over (case, level) rows: asymmetry and level-dependent
        // stiffness stay testable
        assert_eq!(d.folds, FOLDS);
        assert!(
            !d.is_untestable("asymmetric_stiffness"),
            "{:?}",
            d.untestable
        );
        assert!(!d.is_untestable("level_dependent_stiffness"));
        for f in 0..FOLDS {
            let held: Vec<(usize, usize)> = (0..cs.len())
                .flat_map(|c| (0..levels).map(move |l| (c, l)))
                .filter(|&(c, l)| d.fold_of(c, l) == Some(f))
                .collect();
            // at most one row of a level, and never both directions of an
            // axis at one level, are held out in a fold
            for l in 0..levels {
                assert!(held.iter().filter(|h| h.1 == l).count() <= 1, "fold {f}");
            }
            for a in 0..3 {
                for l in 0..levels {
                    let both = [2 * a, 2 * a + 1].iter().all(|c| held.contains(&(*c, l)));
                    assert!(!both, "fold {f} axis {a} level {l}");
                }
            }
        }
        // every row is held out by exactly one fold
        for c in 0..cs.len() {
            for l in 0..levels {
                assert!(d.fold_of(c, l).is_some_and(|f| f < FOLDS));
            }
        }
    }

    #[test]
    fn primary_rotations_only_leave_coupling_and_pose_untestable() {
        let mut cs = Vec::new();
        for (a, n) in AXIS_NAMES.iter().enumerate() {
            for (s, sg) in [(-1.0, "neg"), (1.0, "pos")] {
                let mut v = [0.0; 3];
                v[a] = s * 7.5;
                cs.push(case(&format!("{n}_{sg}_7.5"), v, 0.0));
            }
        }
        // only the rotation about each case's load axis
        let primary: Vec<[bool; 6]> = (0..cs.len())
            .map(|c| std::array::from_fn(|d| d == c / 2))
            .collect();
        let mut d = Design::new(&cs);
        d.note_measurement(&primary);
        assert!(d.is_untestable("coupled_stiffness"));
        assert!(d.is_untestable("joint_pose_error"));
        assert!(d.missing.iter().any(|m| m.effect == "coupled_stiffness"));
        // all three rotations measured: both testable again
        let mut d = Design::new(&cs);
        d.note_measurement(&vec![[true, true, true, false, false, false]; cs.len()]);
        assert!(!d.is_untestable("coupled_stiffness"));
        assert!(!d.is_untestable("joint_pose_error"));
    }

    /// The six cases `FE/AR/LB x neg/pos` at 10 N m.
    fn table_cases() -> Vec<LoadCase> {
        let mut cs = Vec::new();
        for (a, n) in AXIS_NAMES.iter().enumerate() {
            for (s, sg) in [(-1.0, "neg"), (1.0, "pos")] {
                let mut v = [0.0; 3];
                v[a] = s * 10.0;
                cs.push(case(&format!("{n}_{sg}_10"), v, 0.0));
            }
        }
        cs
    }

    /// Rows `(case, level, DoFs)` of every case at every level.
    fn rows(
        n_cases: usize,
        levels: &[usize],
        dofs: impl Fn(usize) -> Vec<usize>,
    ) -> Vec<(usize, usize, Vec<usize>)> {
        levels
            .iter()
            .flat_map(|&l| (0..n_cases).map(move |c| (c, l)))
            .map(|(c, l)| (c, l, dofs(c)))
            .collect()
    }

    #[test]
    fn a_table_of_primary_rotations_is_left_out_level_by_level() {
        let cs = table_cases();
        let primary: Vec<[bool; 6]> = (0..cs.len())
            .map(|c| std::array::from_fn(|d| d == c / 2))
            .collect();
        let mut d = Design::new(&cs);
        d.note_measurement(&primary);
        assert!(d.primary_only && d.is_table());
        // too few levels for a trend: the design stays as it is
        assert!(!d.leave_one_level_out(&[0, 1]));
        assert!(!d.by_level);
        // five measured levels of a longer load path (levels 0 and 2 not
        // measured): the folds are over the measured ones
        let measured = [1, 3, 4, 5, 6];
        assert!(d.leave_one_level_out(&measured));
        d.assign_folds(&rows(cs.len(), &measured, |c| vec![c / 2]));
        assert!(d.by_level && d.folds == 5);
        assert!(d.kept.is_empty());
        // every row of a level in one fold, each measured level its own fold
        for c in 0..cs.len() {
            for (k, &l) in measured.iter().enumerate() {
                assert_eq!(d.fold_of(c, l), Some(k));
                assert!(d.holds_out(c, l));
            }
            assert_eq!(d.fold_of(c, 0), None);
        }
        // all three rotations measured: not a table's design
        let mut d = Design::new(&cs);
        d.note_measurement(&vec![[true, true, true, false, false, false]; cs.len()]);
        assert!(!d.is_table());
        assert!(!d.leave_one_level_out(&measured));
        assert_eq!(d.folds, FOLDS);
    }

    #[test]
    fn rows_nothing_could_predict_stay_in_training() {
        // a one-level table: flexion and extension, one side of lateral
        // bending and of axial rotation (cases FE_neg, FE_pos, LB_pos,
        // AR_pos), primary rotations only, at level 2 of the load path
        let cs: Vec<LoadCase> = table_cases()
            .into_iter()
            .filter(|c| c.id.starts_with("FE") || c.id.contains("pos"))
            .collect();
        let ids: Vec<&str> = cs.iter().map(|c| c.id.as_str()).collect();
        let axis_of = |c: usize| CaseInfo::of(&cs[c]).axis.unwrap();
        let primary: Vec<[bool; 6]> = (0..cs.len())
            .map(|c| std::array::from_fn(|d| d == axis_of(c)))
            .collect();
        let mut d = Design::new(&cs);
        d.note_measurement(&primary);
        assert!(d.is_table());
        assert!(!d.leave_one_level_out(&[2]));
        d.note_few_levels(1);
        assert!(d.is_untestable("level_dependent_stiffness"));
        assert!(!d
            .weakly_tested
            .iter()
            .any(|(e, _)| e == "nonlinear_stiffness"));
        assert!(d.is_untestable("nonlinear_stiffness"));
        assert!(d
            .missing
            .iter()
            .any(|m| m.effect == "level_dependent_stiffness"));
        let one = rows(cs.len(), &[2], |c| vec![axis_of(c)]);
        d.assign_folds(&one);
        // the one row about X and the one about Y: nothing else predicts them
        let mut kept: Vec<&str> = d.kept.iter().map(|k| ids[k.0]).collect();
        kept.sort_unstable();
        assert_eq!(kept, ["AR_pos_10", "LB_pos_10"]);
        // every held-out row is predicted by a training row of its axis
        for r in &one {
            match d.fold_of(r.0, r.1) {
                Some(f) => {
                    assert!(d.holds_out(r.0, r.1));
                    assert!(one
                        .iter()
                        .any(|t| d.fold_of(t.0, t.1) != Some(f) && axis_of(t.0) == axis_of(r.0)));
                }
                None => assert!(!d.holds_out(r.0, r.1)),
            }
        }
        // the two flexion/extension rows, each in its own fold, no empty fold
        assert_eq!(d.folds, 2);
        assert!(d.rule.contains("stay in training"), "{}", d.rule);
        // the same cases at five levels: every row predictable
        let mut d = Design::new(&cs);
        d.note_measurement(&primary);
        d.assign_folds(&rows(cs.len(), &[0, 1, 2, 3, 4], |c| vec![axis_of(c)]));
        assert!(d.kept.is_empty());
    }

    #[test]
    fn single_magnitude_and_single_sign_name_the_missing_cases() {
        let cs = vec![
            case("FE_neg_5", [0.0, 0.0, -5.0], 0.0),
            case("FE_pos_5", [0.0, 0.0, 5.0], 0.0),
            case("LB_pos_5", [5.0, 0.0, 0.0], 0.0),
        ];
        let d = Design::new(&cs);
        assert!(!d.is_untestable("nonlinear_stiffness"));
        assert!(d
            .weakly_tested
            .iter()
            .any(|(e, _)| e == "nonlinear_stiffness"));
        // both directions about FE, one about LB: the asymmetry is tested
        // about FE only, the other LB direction named
        assert!(!d.is_untestable("asymmetric_stiffness"));
        assert!(d
            .weakly_tested
            .iter()
            .any(|(e, why)| e == "asymmetric_stiffness" && why.contains("LB")));
        assert!(d.is_untestable("preload_stiffening"));
        let names: Vec<&str> = d.missing.iter().map(|m| m.case.as_str()).collect();
        assert!(
            names.contains(&"FE_pos_2.5") && names.contains(&"FE_neg_10"),
            "{names:?}"
        );
        assert!(names.contains(&"LB_neg_5"), "{names:?}");
        assert!(!d.heldout.is_empty() && !d.train.is_empty());
    }
}
