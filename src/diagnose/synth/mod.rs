//! Synthetic labelled experiments for testing the diagnosis on data it has
//! never seen: a nominal specimen (optionally perturbed into another
//! specimen), a truth model made of the nominal one plus exactly one effect
//! of random form, size and levels, solved by the crate's own solver, and
//! measurement noise; written in the layout of `experiment.md`
//! (`experiment.toml`, `kinematics.csv`, `specimen.osim`) so that the
//! diagnosis reads it exactly as it reads a real experiment.
//!
//! The truth forms deliberately differ from the candidate families where
//! the format allows it (threshold facet contact instead of a bilinear law,
//! a few levels instead of all, a single coupled pair, stiffness varying
//! per level and DoF), and the truth's global stiffness always differs
//! from the nominal values, as in the development set. Everything is drawn
//! from one seeded `ChaCha8Rng`: same spec, same files.

mod means;
mod oov;
mod sets;
mod truth;

pub use means::{means_kinds, means_set, write_means, MeansSpec};
pub use oov::Oov;
pub use sets::{
    effect_pairs, means_summary, oov_set, oov_summary, pair_set, pair_summary, score_summary,
    standard_set, Scored,
};

use super::family::Effect;
use super::sim::Sim;
use crate::calibrate::experiment::Experiment;
use crate::error::{Error, Result};
use crate::osim::document::Document;
use crate::osim::xml::Element;
use crate::solver::System;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use std::fmt::Write as _;
use std::path::Path;

/// What to generate.
#[derive(Debug, Clone)]
pub struct SynthSpec {
    /// The effect in the truth model (`Effect::None` for none); the
    /// primary one of a two-effect truth.
    pub effect: Effect,
    /// A second effect in the truth model (two-effect experiments).
    pub second: Option<Effect>,
    /// An effect outside the vocabulary added to the truth.
    pub oov: Option<Oov>,
    /// Body that carries the loads (sets the levels: fixed body .. this one).
    pub loaded_body: String,
    /// Body welded to ground.
    pub fixed_body: String,
    /// Effect size in [0, 1]: 0 modest, 1 obvious.
    pub size: f64,
    /// Rotation noise SD (deg) and translation noise SD (mm).
    pub noise_deg: f64,
    /// Translation noise SD (mm).
    pub noise_mm: f64,
    /// Translations measured.
    pub translations: bool,
    /// Follower-load series present.
    pub follower: bool,
    /// Perturb the joint frames (another specimen) and the nominal stiffness.
    pub perturb_specimen: bool,
    /// The forms a published table of means shows (see
    /// `truth::TableDraws`): a level-dependent stiffness as a trend along
    /// the spine in some DoFs, an asymmetry shared by every level in some
    /// DoFs; the other effects as in the standard set.
    pub table_forms: bool,
    /// Seed of every random choice.
    pub seed: u64,
}

/// What was generated (the label and a description of the truth).
#[derive(Debug, Clone)]
pub struct Truth {
    /// The (primary) effect.
    pub effect: Effect,
    /// The second effect of a two-effect truth.
    pub second: Option<Effect>,
    /// The out-of-vocabulary effect, when there is one.
    pub oov: Option<Oov>,
    /// Levels where the effect acts.
    pub levels: Vec<String>,
    /// Free-text description of what was built in.
    pub notes: String,
}

const MAGS: [f64; 4] = [1.0, 2.5, 5.0, 7.5];
pub(super) const AXES: [&str; 3] = ["LB", "AR", "FE"];

/// The load cases: pure moments +-1, 2.5, 5, 7.5 N m about X, Y, Z; with
/// `follower`, moments +-2.5 .. 7.5 under 250 N and 500 N and the two
/// follower loads alone (the development set's design).
fn cases_toml(body: &str, follower: bool) -> String {
    let mut t = String::new();
    let push = |t: &mut String, id: String, m: [f64; 3], fl: f64| {
        let _ = write!(
            t,
            "[[case]]\nid = \"{id}\"\nbody = \"{body}\"\nmoment = [{:?}, {:?}, {:?}]\nmoment_frame = \"ground\"\n",
            m[0], m[1], m[2]
        );
        if fl > 0.0 {
            let _ = writeln!(t, "follower_load = {fl:?}");
        }
        t.push('\n');
    };
    let mag_id = |m: f64| {
        if m.fract() == 0.0 {
            format!("{}", m as i64)
        } else {
            format!("{m}")
        }
    };
    for (a, name) in AXES.iter().enumerate() {
        for (sg, s) in [("neg", -1.0), ("pos", 1.0)] {
            for m in MAGS {
                let mut v = [0.0; 3];
                v[a] = s * m;
                push(&mut t, format!("{name}_{sg}_{}", mag_id(m)), v, 0.0);
            }
        }
    }
    if follower {
        for fl in [250.0, 500.0] {
            for (a, name) in AXES.iter().enumerate() {
                for (sg, s) in [("neg", -1.0), ("pos", 1.0)] {
                    for m in &MAGS[1..] {
                        let mut v = [0.0; 3];
                        v[a] = s * m;
                        push(
                            &mut t,
                            format!("{name}_{sg}_{}_FL{}", mag_id(*m), fl as i64),
                            v,
                            fl,
                        );
                    }
                }
            }
            push(&mut t, format!("FL_{}", fl as i64), [0.0; 3], fl);
        }
    }
    t
}

/// Recursively visit every element mutably.
fn walk_mut(e: &mut Element, f: &mut dyn FnMut(&mut Element)) {
    f(e);
    for c in e.elements_mut() {
        walk_mut(c, f);
    }
}

fn parse3(s: &str) -> Option<[f64; 3]> {
    let v: Vec<f64> = s
        .split_whitespace()
        .map(|x| x.parse::<f64>())
        .collect::<std::result::Result<_, _>>()
        .ok()?;
    <[f64; 3]>::try_from(v).ok()
}

fn fmt3(v: [f64; 3]) -> String {
    format!("{:?} {:?} {:?}", v[0], v[1], v[2])
}

/// One specimen's deviation from the nominal one: a stiffness factor per
/// DoF (every bushing) and, per 6-DoF IVD joint in document order, an
/// offset (m) and a rotation (rad) of both its frames.
#[derive(Debug, Clone)]
pub(super) struct Perturbation {
    ks: [f64; 6],
    joints: Vec<([f64; 3], [f64; 3])>,
}

/// True for the 6-DoF intervertebral joints.
fn is_ivd_joint(e: &Element) -> bool {
    e.name == "CustomJoint" && e.name_attr().ends_with("_IVDjnt")
}

/// Number of IVD joints under `e`.
fn count_ivd(e: &Element) -> usize {
    is_ivd_joint(e) as usize + e.elements().map(count_ivd).sum::<usize>()
}

impl Perturbation {
    /// Draw: the stiffness factors (lognormal, SD 0.25), then per joint
    /// the offset (SD 1.5 mm) and rotation (SD 1.5 deg) components.
    pub(super) fn draw(doc: &Document, rng: &mut ChaCha8Rng) -> Result<Perturbation> {
        let n = Normal::new(0.0, 1.0).map_err(|e| Error::invalid("synth", e.to_string()))?;
        let ks: [f64; 6] = std::array::from_fn(|_| (0.25f64 * n.sample(rng)).exp());
        let joints = (0..count_ivd(doc.model_element()))
            .map(|_| {
                let dp: [f64; 3] = std::array::from_fn(|_| 1.5e-3 * n.sample(rng));
                let dr: [f64; 3] = std::array::from_fn(|_| 1.5f64.to_radians() * n.sample(rng));
                (dp, dr)
            })
            .collect();
        Ok(Perturbation { ks, joints })
    }

    /// Specimens whose deviations average out: the mean offset and
    /// rotation of each joint subtracted, the stiffness factors divided by
    /// their geometric mean (the nominal model is the sample's mean one).
    pub(super) fn centre(ps: &mut [Perturbation]) {
        let n = ps.len().max(1) as f64;
        for d in 0..6 {
            let g = ps.iter().map(|p| p.ks[d].ln()).sum::<f64>() / n;
            ps.iter_mut().for_each(|p| p.ks[d] /= g.exp());
        }
        let nj = ps.first().map(|p| p.joints.len()).unwrap_or(0);
        for j in 0..nj {
            for k in 0..3 {
                let mp = ps.iter().map(|p| p.joints[j].0[k]).sum::<f64>() / n;
                let mr = ps.iter().map(|p| p.joints[j].1[k]).sum::<f64>() / n;
                for p in ps.iter_mut() {
                    p.joints[j].0[k] -= mp;
                    p.joints[j].1[k] -= mr;
                }
            }
        }
    }

    /// Move both offset frames of every IVD joint and scale the stiffness
    /// of every bushing.
    pub(super) fn apply(&self, doc: &mut Document) -> Result<()> {
        let mut err = None;
        let mut joint = 0;
        walk_mut(doc.model_element_mut(), &mut |e| {
            if is_ivd_joint(e) {
                let (dp, dr) = self.joints.get(joint).copied().unwrap_or_default();
                joint += 1;
                if let Some(frames) = e.child_mut("frames") {
                    for f in frames.elements_mut() {
                        for (prop, d) in [("translation", dp), ("orientation", dr)] {
                            match f.child_text(prop).as_deref().and_then(parse3) {
                                Some(v) => f.set_child_text(
                                    prop,
                                    fmt3(std::array::from_fn(|i| v[i] + d[i])),
                                ),
                                None => err = Some(format!("{}: no {prop}", f.name_attr())),
                            }
                        }
                    }
                }
            }
            if e.name == "BushingForce" {
                for (prop, o) in [("rotational_stiffness", 0), ("translational_stiffness", 3)] {
                    if let Some(v) = e.child_text(prop).as_deref().and_then(parse3) {
                        e.set_child_text(
                            prop,
                            fmt3(std::array::from_fn(|i| v[i] * self.ks[o + i])),
                        );
                    }
                }
            }
        });
        match err {
            Some(m) => Err(Error::invalid("synth: perturbing the specimen", m)),
            None => Ok(()),
        }
    }
}

/// Another specimen: the nominal one with a random [`Perturbation`].
pub(super) fn perturb(doc: &mut Document, rng: &mut ChaCha8Rng) -> Result<()> {
    Perturbation::draw(doc, rng)?.apply(doc)
}

/// The `kinematics.csv` of `exp`'s rows with `values` (report units, 4
/// decimals; translations blank unless `translations`).
fn rows_csv(exp: &Experiment, values: &[[f64; 6]], translations: bool) -> String {
    let mut t = String::from("case,upper,lower,rx,ry,rz,tx,ty,tz\n");
    for (r, v) in exp.rows.iter().zip(values) {
        let id = &exp.cases[r.case].id;
        let _ = write!(
            t,
            "{id},{},{},{:.4},{:.4},{:.4}",
            r.upper, r.lower, v[0], v[1], v[2]
        );
        if translations {
            let _ = writeln!(t, ",{:.4},{:.4},{:.4}", v[3], v[4], v[5]);
        } else {
            t.push_str(",,,\n");
        }
    }
    t
}

/// `pred` plus measurement noise of SD `noise_deg` (rotations) and
/// `noise_mm` (translations), drawn row by row, DoF by DoF.
fn add_noise(pred: &[[f64; 6]], spec: &SynthSpec, rng: &mut ChaCha8Rng) -> Result<Vec<[f64; 6]>> {
    let nr = Normal::new(0.0, spec.noise_deg.max(1e-12))
        .map_err(|e| Error::invalid("synth", e.to_string()))?;
    let nt = Normal::new(0.0, spec.noise_mm.max(1e-12))
        .map_err(|e| Error::invalid("synth", e.to_string()))?;
    Ok(pred
        .iter()
        .map(|p| {
            std::array::from_fn(|d| {
                p[d] + if d < 3 {
                    nr.sample(&mut *rng)
                } else {
                    nt.sample(&mut *rng)
                }
            })
        })
        .collect())
}

/// The spec as generated: the follower-load series whenever a preload
/// stiffening or a follower-guide truth needs them.
fn completed(spec: &SynthSpec) -> SynthSpec {
    let mut spec = spec.clone();
    let preload =
        spec.effect == Effect::PreloadStiffening || spec.second == Some(Effect::PreloadStiffening);
    if preload || spec.oov == Some(Oov::FollowerAnterior) {
        spec.follower = true;
    }
    spec
}

/// Write a synthetic experiment into `dir` from the nominal `specimen`
/// (.osim): the (perturbed) specimen, the load cases, and the truth's
/// predictions plus noise. Preload stiffening and follower-guide truths
/// always get the follower-load series.
pub fn write(specimen: &Path, spec: &SynthSpec, dir: &Path) -> Result<Truth> {
    let mut rng = ChaCha8Rng::seed_from_u64(spec.seed);
    let spec = completed(spec);
    // the specimen and the load cases
    let mut doc = Document::read(specimen)?;
    if spec.perturb_specimen {
        perturb(&mut doc, &mut rng)?;
    }
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    crate::util::write_atomic(&dir.join("specimen.osim"), doc.to_xml_string().as_bytes())?;
    let cases = cases_toml(&spec.loaded_body, spec.follower);
    let toml = format!(
        "[specimen]\nmodel = \"specimen.osim\"\nfixed_body = \"{}\"\ngravity = false\n\n[units]\nangle = \"deg\"\nlength = \"mm\"\n\n{cases}",
        spec.fixed_body
    );
    crate::util::write_atomic(&dir.join("experiment.toml"), toml.as_bytes())?;
    write_placeholder_rows(&doc, &spec.fixed_body, &spec.loaded_body, dir)?;
    // the truth's predictions (with the out-of-vocabulary effect) plus noise
    let exp = Experiment::read(dir)?;
    let sim = Sim::new(&exp)?;
    let (sys, mut truth) = truth::truth_system(&sim, &spec, &mut rng)?;
    let pred = match spec.oov {
        Some(o) => {
            let (pred, note) = oov::predict(&sim, &sys, o, spec.size.clamp(0.0, 1.0), &mut rng)?;
            let _ = write!(truth.notes, "; {note}");
            pred
        }
        None => {
            let all: Vec<usize> = (0..exp.cases.len()).collect();
            sim.predict(&sys, &all, &mut sim.warm())?
        }
    };
    let noisy = add_noise(&pred, &spec, &mut rng)?;
    let csv = rows_csv(&exp, &noisy, spec.translations);
    crate::util::write_atomic(&dir.join("kinematics.csv"), csv.as_bytes())?;
    Ok(truth)
}

/// A `kinematics.csv` of zeros with one row per case and level (so that the
/// experiment can be read before its values exist).
pub(super) fn write_placeholder_rows(
    doc: &Document,
    fixed: &str,
    loaded: &str,
    dir: &Path,
) -> Result<()> {
    let s = crate::solver::SystemSpec::from_model(&doc.model()?)?;
    let s = System::with_body_fixed(&s, fixed)?;
    let sys = System::new(&s)?;
    let f = sys
        .body_index(fixed)
        .ok_or_else(|| Error::invalid("synth", "fixed body not in the model"))?;
    let l = sys
        .body_index(loaded)
        .ok_or_else(|| Error::invalid("synth", "loaded body not in the model"))?;
    let levels = crate::calibrate::family::find_levels(&sys, f, &[l]);
    let text =
        std::fs::read_to_string(dir.join("experiment.toml")).map_err(|e| Error::io(dir, e))?;
    let cases =
        crate::calibrate::experiment::parse_experiment_toml(&text, &dir.join("experiment.toml"))?
            .cases;
    let mut t = String::from("case,upper,lower,rx,ry,rz,tx,ty,tz\n");
    for c in &cases {
        for lv in &levels {
            let _ = writeln!(
                t,
                "{},{},{},0,0,0,,,",
                c.id, lv.level.upper_body, lv.level.lower_body
            );
        }
    }
    crate::util::write_atomic(&dir.join("kinematics.csv"), t.as_bytes())
}
