//! Seeded sets of synthetic experiments (specs only; `write` makes them)
//! and their scoring: the standard withheld set (one effect of the
//! vocabulary or none), two-effect experiments and out-of-vocabulary
//! experiments.

use super::{Oov, SynthSpec, Truth};
use crate::diagnose::family::Effect;
use crate::diagnose::select::{Outcome, Verdict};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::fmt::Write as _;
use std::ops::Range;

/// A specimen (its index) and one of its loaded bodies, drawn in this
/// order from `rng`.
pub(super) fn random_specimen(
    rng: &mut ChaCha8Rng,
    specimens: &[(String, Vec<String>)],
) -> (usize, String) {
    let si = rng.random_range(0..specimens.len().max(1));
    let bodies = specimens.get(si).map(|s| s.1.as_slice()).unwrap_or(&[]);
    let body = bodies
        .get(rng.random_range(0..bodies.len().max(1)))
        .cloned()
        .unwrap_or_default();
    (si, body)
}

/// A spec of `effect` on a random specimen of `specimens` (and loaded
/// body), with random size in `size`, noise, translations, follower series
/// and perturbation, drawn in this order from `rng`.
fn random_spec(
    rng: &mut ChaCha8Rng,
    specimens: &[(String, Vec<String>)],
    effect: Effect,
    size: Range<f64>,
) -> (usize, SynthSpec) {
    let (si, body) = random_specimen(rng, specimens);
    let spec = SynthSpec {
        effect,
        second: None,
        oov: None,
        loaded_body: body,
        fixed_body: "sacrum".into(),
        size: rng.random_range(size),
        noise_deg: rng.random_range(0.01..0.05),
        noise_mm: rng.random_range(0.01..0.05),
        translations: rng.random_bool(0.7),
        follower: rng.random_bool(0.4),
        perturb_specimen: rng.random_bool(0.6),
        table_forms: false,
        seed: rng.random(),
    };
    (si, spec)
}

/// The standard synthetic withheld set: `n` cases cycling through the seven
/// labels, with random loaded body (level range), size, noise,
/// translations, follower series and specimen perturbation, all from
/// `seed`. Each entry is the spec; `specimens` are the nominal models to
/// draw from, with the bodies that can be loaded.
pub fn standard_set(
    n: usize,
    seed: u64,
    specimens: &[(String, Vec<String>)],
) -> Vec<(usize, SynthSpec)> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let labels: Vec<Effect> = std::iter::once(Effect::None)
        .chain(Effect::CANDIDATES)
        .collect();
    (0..n)
        .filter(|_| !specimens.is_empty())
        .map(|i| random_spec(&mut rng, specimens, labels[i % labels.len()], 0.0..1.0))
        .collect()
}

/// The fifteen unordered pairs of the six effects.
pub fn effect_pairs() -> Vec<(Effect, Effect)> {
    let c = Effect::CANDIDATES;
    let mut out = Vec::new();
    for i in 0..c.len() {
        for j in i + 1..c.len() {
            out.push((c[i], c[j]));
        }
    }
    out
}

/// Two-effect experiments: `n` cases cycling through the fifteen pairs of
/// the six effects, each effect at a size (0.5 .. 1) that matters alone
/// (the standard set names every effect at such sizes), the rest drawn as
/// in [`standard_set`], all from `seed`.
pub fn pair_set(
    n: usize,
    seed: u64,
    specimens: &[(String, Vec<String>)],
) -> Vec<(usize, SynthSpec)> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let pairs = effect_pairs();
    (0..n)
        .filter(|_| !specimens.is_empty())
        .map(|i| {
            let (a, b) = pairs[i % pairs.len()];
            let (si, mut spec) = random_spec(&mut rng, specimens, a, 0.5..1.0);
            spec.second = Some(b);
            (si, spec)
        })
        .collect()
}

/// Out-of-vocabulary experiments: `n` cases cycling through the four
/// effects of [`Oov`] on a nominal-form truth, sizes 0.3 .. 1, the rest
/// drawn as in [`standard_set`], all from `seed`.
pub fn oov_set(
    n: usize,
    seed: u64,
    specimens: &[(String, Vec<String>)],
) -> Vec<(usize, SynthSpec)> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..n)
        .filter(|_| !specimens.is_empty())
        .map(|i| {
            let (si, mut spec) = random_spec(&mut rng, specimens, Effect::None, 0.3..1.0);
            spec.oov = Some(Oov::ALL[i % Oov::ALL.len()]);
            (si, spec)
        })
        .collect()
}

/// One scored experiment.
#[derive(Debug, Clone, PartialEq)]
pub struct Scored {
    /// The label: `none`, the (primary) effect, or `other`.
    pub truth: Verdict,
    /// The second effect of a two-effect truth.
    pub second: Option<Effect>,
    /// The verdict (`None` when the diagnosis failed).
    pub verdict: Option<Verdict>,
    /// The effects of `verdict.effects`.
    pub effects: Vec<Effect>,
    /// The diagnosis's confidence (0 when it failed).
    pub confidence: f64,
    /// Held-out shrink of the augmented model.
    pub shrink: f64,
}

impl Scored {
    /// The score of the diagnosis `o` of a synthetic experiment of truth
    /// `truth` (`None`: the diagnosis failed).
    pub fn of(truth: &Truth, o: Option<&Outcome>) -> Scored {
        let shrink = o
            .map(|o| {
                let (b, a) = o.heldout_rmse();
                if b > 0.0 {
                    1.0 - a / b
                } else {
                    0.0
                }
            })
            .unwrap_or(0.0);
        Scored {
            truth: if truth.oov.is_some() {
                Verdict::Other
            } else {
                Verdict::of(truth.effect)
            },
            second: truth.second,
            verdict: o.map(|o| o.verdict),
            effects: o
                .map(|o| o.effects.iter().map(|e| e.effect).collect())
                .unwrap_or_default(),
            confidence: o.map(|o| o.confidence).unwrap_or(0.0),
            shrink,
        }
    }

    /// True when the verdict is the label.
    pub fn hit(&self) -> bool {
        self.verdict == Some(self.truth)
    }

    /// The truth's effects (none for `none` and `other`).
    fn truth_effects(&self) -> Vec<Effect> {
        let mut v: Vec<Effect> = match self.truth {
            Verdict::Effect(e) => vec![e],
            _ => Vec::new(),
        };
        v.extend(self.second);
        v
    }

    /// An effect named (verdict or `verdict.effects`) that the truth does
    /// not carry.
    pub fn names_wrong(&self) -> bool {
        let t = self.truth_effects();
        let named = match self.verdict {
            Some(Verdict::Effect(e)) => vec![e],
            _ => Vec::new(),
        };
        let listed = if matches!(self.verdict, Some(Verdict::Effect(_))) {
            self.effects.clone()
        } else {
            Vec::new()
        };
        named.iter().chain(&listed).any(|e| !t.contains(e))
    }

    /// The published-means reading is right (see [`means_summary`]).
    pub fn means_right(&self) -> bool {
        let t = self.truth_effects();
        match (self.truth, self.second) {
            (Verdict::None, _) => !matches!(self.verdict, Some(Verdict::Effect(_))),
            (
                Verdict::Effect(
                    Effect::NonlinearStiffness | Effect::CoupledStiffness | Effect::JointPoseError,
                ),
                None,
            ) => matches!(self.verdict, Some(Verdict::Unidentifiable | Verdict::None)),
            (Verdict::Effect(e), None) => {
                self.verdict == Some(Verdict::Effect(e)) && !self.names_wrong()
            }
            (Verdict::Effect(_), Some(_)) => {
                matches!(self.verdict, Some(Verdict::Effect(_)))
                    && !self.names_wrong()
                    && t.iter().all(|e| self.effects.contains(e))
            }
            _ => self.hit(),
        }
    }
}

/// The labels of the confusion matrix (rows and columns).
fn labels() -> Vec<Verdict> {
    let mut v = vec![Verdict::None];
    v.extend(Effect::CANDIDATES.map(Verdict::Effect));
    v.extend([Verdict::Other, Verdict::Unidentifiable]);
    v
}

/// The scoring summary of labelled experiments (the acceptance figures of
/// the diagnose issue): the confusion matrix (rows truth, columns verdict:
/// the format's vocabulary, `other`, `unidentifiable` and failed runs),
/// then top-1 accuracy, effects claimed on `none` cases and the median
/// held-out shrink of the effect cases.
pub fn score_summary(rows: &[Scored]) -> String {
    let names = labels();
    let mut out = String::from("confusion (rows truth, columns verdict):\n");
    let _ = write!(out, "{:<28}", "");
    for n in &names {
        let _ = write!(out, "{:>6}", &n.name()[..4]);
    }
    let _ = writeln!(out, "{:>6}", "err");
    for t in names.iter().filter(|t| rows.iter().any(|r| r.truth == **t)) {
        let _ = write!(out, "{:<28}", t.name());
        for v in &names {
            let n = rows
                .iter()
                .filter(|r| r.truth == *t && r.verdict == Some(*v))
                .count();
            let _ = write!(out, "{n:>6}");
        }
        let failed = rows
            .iter()
            .filter(|r| r.truth == *t && r.verdict.is_none())
            .count();
        let _ = writeln!(out, "{failed:>6}");
    }
    let correct = rows.iter().filter(|r| r.hit()).count();
    // an effect name on a `none` case (`unidentifiable` names none)
    let false_claims = rows
        .iter()
        .filter(|r| r.truth == Verdict::None && matches!(r.verdict, Some(Verdict::Effect(_))))
        .count();
    let shrinks: Vec<f64> = rows
        .iter()
        .filter(|r| r.truth != Verdict::None)
        .map(|r| r.shrink)
        .collect();
    let med = crate::landmarks::stats::median(&shrinks).unwrap_or(f64::NAN);
    let _ = writeln!(
        out,
        "top-1 accuracy {correct}/{} = {:.3}; false claims on none: {false_claims}; median shrink (effect cases) {med:.3}",
        rows.len(),
        correct as f64 / rows.len().max(1) as f64
    );
    out
}

/// The two-effect figures: both effects in `verdict.effects`, the primary
/// (`verdict.effect`) one of the two, and the rows by pair.
pub fn pair_summary(rows: &[Scored]) -> String {
    let truth = |r: &Scored| -> Vec<Effect> {
        let mut v: Vec<Effect> = match r.truth {
            Verdict::Effect(e) => vec![e],
            _ => vec![],
        };
        v.extend(r.second);
        v
    };
    let both = rows
        .iter()
        .filter(|r| truth(r).iter().all(|e| r.effects.contains(e)))
        .count();
    let primary = rows
        .iter()
        .filter(|r| matches!(r.verdict, Some(Verdict::Effect(e)) if truth(r).contains(&e)))
        .count();
    let n = rows.len().max(1) as f64;
    format!(
        "both effects in verdict.effects: {both}/{} = {:.3}; primary (verdict.effect) one of the two: {primary}/{} = {:.3}\n",
        rows.len(),
        both as f64 / n,
        rows.len(),
        primary as f64 / n
    )
}

/// The published-means figures, per kind of truth (see
/// [`super::means_kinds`]): how often the reading is right, and how often
/// a wrong effect is named with confidence 0.9 or more. Right is:
/// - `none`: no effect named;
/// - a level trend, a shared asymmetry: that effect is `verdict.effect`
///   and `verdict.effects` names no other;
/// - both: `verdict.effects` names exactly the two;
/// - nonlinear, coupled, joint pose (no signature in a table of primary
///   rotations at one magnitude): `unidentifiable` or `none`;
/// - preload stiffening: named.
pub fn means_summary(rows: &[Scored]) -> String {
    let mut out = String::new();
    let kind = |r: &Scored| match (r.truth, r.second) {
        (t, Some(e)) => format!("{}+{}", t.name(), e.name()),
        (t, None) => t.name().to_string(),
    };
    let mut kinds: Vec<String> = Vec::new();
    for r in rows {
        if !kinds.contains(&kind(r)) {
            kinds.push(kind(r));
        }
    }
    for k in kinds {
        let sub: Vec<&Scored> = rows.iter().filter(|r| kind(r) == k).collect();
        let right = sub.iter().filter(|r| r.means_right()).count();
        let wrong_sure = sub
            .iter()
            .filter(|r| r.names_wrong() && r.confidence >= 0.9)
            .count();
        let mut verdicts: Vec<String> = Vec::new();
        for r in &sub {
            let v = r.verdict.map(|v| v.name()).unwrap_or("error");
            let mut e: Vec<&str> = r.effects.iter().map(|e| e.name()).collect();
            e.sort_unstable();
            let e = if e.len() > 1 {
                format!("{v}[{}]", e.join("+"))
            } else {
                v.to_string()
            };
            verdicts.push(e);
        }
        verdicts.sort();
        let mut hist: Vec<String> = Vec::new();
        for v in verdicts.iter() {
            if !hist.iter().any(|h| h.starts_with(&format!("{v} x"))) {
                let n = verdicts.iter().filter(|w| *w == v).count();
                hist.push(format!("{v} x{n}"));
            }
        }
        let _ = writeln!(
            out,
            "{k:<48} right {right}/{} = {:.2}; wrong effect named at confidence >= 0.9: {wrong_sure}; verdicts: {}",
            sub.len(),
            right as f64 / sub.len().max(1) as f64,
            hist.join(", ")
        );
    }
    out
}

/// The out-of-vocabulary figures: `other` verdicts, and effect names given
/// with confidence 0.9 or more (all wrong: the truth is outside the
/// vocabulary).
pub fn oov_summary(rows: &[Scored]) -> String {
    let other = rows
        .iter()
        .filter(|r| r.verdict == Some(Verdict::Other))
        .count();
    let confident_names = rows
        .iter()
        .filter(|r| matches!(r.verdict, Some(Verdict::Effect(_))) && r.confidence >= 0.9)
        .count();
    format!(
        "other: {other}/{} = {:.3}; effect names with confidence >= 0.9: {confident_names}\n",
        rows.len(),
        other as f64 / rows.len().max(1) as f64
    )
}
