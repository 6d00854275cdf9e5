//! Published-means experiments: tables of mean intervertebral rotations
//! over several specimens that all carry the same effect, one moment
//! magnitude per direction, as published ranges of motion are reported
//! (rotations only, optionally only the primary one; optionally the SD
//! across specimens in `sd_*` columns).

use super::{truth::truth_system, write_placeholder_rows, Perturbation, SynthSpec, Truth, AXES};
use crate::calibrate::experiment::Experiment;
use crate::diagnose::family::Effect;
use crate::diagnose::sim::Sim;
use crate::error::{Error, Result};
use crate::osim::document::Document;
use crate::solver::System;
use nalgebra::Vector3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use std::fmt::Write as _;
use std::path::Path;

/// A published-means experiment: the mean of `n_specimens` perturbed
/// specimens that all carry the same effect(s) (the forms a published
/// table shows: a stiffness trend along the spine, an asymmetry shared by
/// the levels; same form, size and levels;
/// each specimen its own joint frames and stiffness, the deviations
/// centred so that the nominal model is the sample's mean one), one moment magnitude
/// per direction, rotations only, rig noise per specimen; with `with_sd`
/// the SD across the specimens in `sd_rx .. sd_rz`.
#[derive(Debug, Clone)]
pub struct MeansSpec {
    /// The effect built into the specimens.
    pub effect: Effect,
    /// A second effect (a trend with an asymmetry).
    pub second: Option<Effect>,
    /// Body the moments are applied to.
    pub loaded_body: String,
    /// Body held fixed.
    pub fixed_body: String,
    /// Effect size in [0, 1].
    pub size: f64,
    /// Number of specimens averaged.
    pub n_specimens: usize,
    /// Moment magnitude (N m) of every case.
    pub magnitude: f64,
    /// Write the `sd_*` columns.
    pub with_sd: bool,
    /// Only the rotation about the load axis is measured (other cells blank).
    pub primary_only: bool,
    /// Rig noise of each specimen's measurement (deg).
    pub rig_noise_deg: f64,
    /// Seed of every random choice.
    pub seed: u64,
}

/// Cases of a published table: +-`mag` about X, Y, Z; with `follower`,
/// the same under 500 N and the follower load alone.
fn means_cases_toml(body: &str, mag: f64, follower: bool) -> String {
    let mut t = String::new();
    let fls: &[f64] = if follower { &[0.0, 500.0] } else { &[0.0] };
    for &fl in fls {
        for (a, name) in AXES.iter().enumerate() {
            for (sg, s) in [("neg", -1.0), ("pos", 1.0)] {
                let mut v = [0.0; 3];
                v[a] = s * mag;
                let tag = if fl > 0.0 {
                    format!("_FL{}", fl as i64)
                } else {
                    String::new()
                };
                let _ = writeln!(
                    t,
                    "[[case]]\nid = \"{name}_{sg}_{mag}{tag}\"\nbody = \"{body}\"\nmoment = [{:?}, {:?}, {:?}]\nmoment_frame = \"ground\"\nfollower_load = {fl:?}\n",
                    v[0], v[1], v[2]
                );
            }
        }
        if fl > 0.0 {
            let _ = writeln!(
                t,
                "[[case]]\nid = \"FL_{}\"\nbody = \"{body}\"\nfollower_load = {fl:?}\n",
                fl as i64
            );
        }
    }
    t
}

/// The experiment `exp` with another nominal model document.
fn with_document(exp: &Experiment, doc: Document) -> Result<Experiment> {
    let mut spec = crate::solver::SystemSpec::from_model(&doc.model()?)?;
    if !exp.gravity {
        spec.gravity = Vector3::zeros();
    }
    let spec = System::with_body_fixed(&spec, &exp.fixed_body)?;
    Ok(Experiment {
        doc,
        spec,
        ..exp.clone()
    })
}

/// Predicted rotations (deg) of every row of every case for one specimen:
/// the nominal document with the specimen's perturbation, the effect drawn
/// from `effect_seed` (the same for every specimen), plus rig noise drawn
/// from `specimen_rng`.
fn specimen_rotations(
    exp: &Experiment,
    nominal: &Document,
    spec: &SynthSpec,
    (perturbation, specimen_rng): (&Perturbation, &mut ChaCha8Rng),
    effect_seed: u64,
) -> Result<(Vec<[f64; 3]>, Truth)> {
    let mut doc = nominal.clone();
    perturbation.apply(&mut doc)?;
    let exp_k = with_document(exp, doc)?;
    let sim = Sim::new(&exp_k)?;
    let mut effect_rng = ChaCha8Rng::seed_from_u64(effect_seed);
    let (sys, truth) = truth_system(&sim, spec, &mut effect_rng)?;
    let all: Vec<usize> = (0..exp.cases.len()).collect();
    let pred = sim.predict(&sys, &all, &mut sim.warm())?;
    let nr = Normal::new(0.0, spec.noise_deg.max(1e-12))
        .map_err(|e| Error::invalid("synth", e.to_string()))?;
    let rows = pred
        .iter()
        .map(|p| std::array::from_fn(|d| p[d] + nr.sample(specimen_rng)))
        .collect();
    Ok((rows, truth))
}

/// Mean and sample SD of each cell over the specimens.
fn mean_sd(per: &[Vec<[f64; 3]>]) -> Vec<([f64; 3], [f64; 3])> {
    let n = per.len().max(1) as f64;
    let rows = per.first().map(Vec::len).unwrap_or(0);
    (0..rows)
        .map(|r| {
            let m: [f64; 3] = std::array::from_fn(|d| per.iter().map(|p| p[r][d]).sum::<f64>() / n);
            let sd: [f64; 3] = std::array::from_fn(|d| {
                let ss: f64 = per.iter().map(|p| (p[r][d] - m[d]).powi(2)).sum();
                (ss / (n - 1.0).max(1.0)).sqrt()
            });
            (m, sd)
        })
        .collect()
}

/// The `kinematics.csv` of a published table (rotations only; `primary`
/// keeps only the rotation about each case's load axis).
fn means_csv(exp: &Experiment, cells: &[([f64; 3], [f64; 3])], spec: &MeansSpec) -> String {
    let mut t = String::from("case,upper,lower,rx,ry,rz,tx,ty,tz");
    if spec.with_sd {
        t.push_str(",sd_rx,sd_ry,sd_rz,sd_tx,sd_ty,sd_tz");
    }
    t.push('\n');
    for (r, (m, sd)) in exp.rows.iter().zip(cells) {
        let c = &exp.cases[r.case];
        let axis = crate::diagnose::design::CaseInfo::of(c).axis;
        let keep = |d: usize| !spec.primary_only || axis.is_none_or(|a| a == d);
        let cell = |v: f64, d: usize| {
            if keep(d) {
                format!("{v:.4}")
            } else {
                String::new()
            }
        };
        let _ = write!(t, "{},{},{}", c.id, r.upper, r.lower);
        for (d, v) in m.iter().enumerate() {
            let _ = write!(t, ",{}", cell(*v, d));
        }
        t.push_str(",,,");
        if spec.with_sd {
            for (d, v) in sd.iter().enumerate() {
                let _ = write!(t, ",{}", cell(v.max(1e-4), d));
            }
            t.push_str(",,,");
        }
        t.push('\n');
    }
    t
}

/// Write a published-means experiment into `dir` from the nominal
/// `specimen` (.osim). Preload stiffening gets the follower-load cases.
pub fn write_means(specimen: &Path, spec: &MeansSpec, dir: &Path) -> Result<Truth> {
    let nominal = Document::read(specimen)?;
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    crate::util::write_atomic(
        &dir.join("specimen.osim"),
        nominal.to_xml_string().as_bytes(),
    )?;
    let follower =
        spec.effect == Effect::PreloadStiffening || spec.second == Some(Effect::PreloadStiffening);
    let source = format!(
        "synthetic: mean of {} perturbed specimens",
        spec.n_specimens
    );
    let toml = format!(
        "[specimen]\nmodel = \"specimen.osim\"\nfixed_body = \"{}\"\ngravity = false\n\n[units]\nangle = \"deg\"\nlength = \"mm\"\n\n[measurement]\nsource = \"{source}\"\nn_specimens = {}\n\n{}",
        spec.fixed_body,
        spec.n_specimens,
        means_cases_toml(&spec.loaded_body, spec.magnitude, follower)
    );
    crate::util::write_atomic(&dir.join("experiment.toml"), toml.as_bytes())?;
    // a placeholder table naming every row (the levels of the load path)
    write_placeholder_rows(&nominal, &spec.fixed_body, &spec.loaded_body, dir)?;
    let exp = Experiment::read(dir)?;
    let one = SynthSpec {
        effect: spec.effect,
        loaded_body: spec.loaded_body.clone(),
        fixed_body: spec.fixed_body.clone(),
        size: spec.size,
        noise_deg: spec.rig_noise_deg,
        noise_mm: 0.0,
        translations: false,
        follower,
        perturb_specimen: true,
        table_forms: true,
        second: spec.second,
        oov: None,
        seed: spec.seed,
    };
    let mut rng = ChaCha8Rng::seed_from_u64(spec.seed);
    let effect_seed: u64 = rng.random();
    // the specimens, centred on the nominal one, then each solved
    let mut specimens: Vec<Perturbation> = (0..spec.n_specimens.max(2))
        .map(|_| Perturbation::draw(&nominal, &mut rng))
        .collect::<Result<_>>()?;
    Perturbation::centre(&mut specimens);
    let mut per = Vec::new();
    let mut truth = None;
    for p in &specimens {
        let (rows, t) = specimen_rotations(&exp, &nominal, &one, (p, &mut rng), effect_seed)?;
        per.push(rows);
        truth.get_or_insert(t);
    }
    let csv = means_csv(&exp, &mean_sd(&per), spec);
    crate::util::write_atomic(&dir.join("kinematics.csv"), csv.as_bytes())?;
    truth.ok_or_else(|| Error::invalid("synth", "no specimen"))
}

/// The kinds of the published-means set: `none`, each effect, and a
/// level trend with a shared asymmetry.
pub fn means_kinds() -> Vec<(Effect, Option<Effect>)> {
    let mut v: Vec<(Effect, Option<Effect>)> = std::iter::once(Effect::None)
        .chain(Effect::CANDIDATES)
        .map(|e| (e, None))
        .collect();
    v.insert(
        3,
        (
            Effect::LevelDependentStiffness,
            Some(Effect::AsymmetricStiffness),
        ),
    );
    v
}

/// The published-means set: `per_label` experiments for each kind of
/// [`means_kinds`], half with `sd_*` columns, random size, level range
/// and specimen seed, all from `seed`.
pub fn means_set(
    per_label: usize,
    seed: u64,
    specimens: &[(String, Vec<String>)],
    primary_only: bool,
) -> Vec<(usize, MeansSpec)> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut out = Vec::new();
    for (e, second) in means_kinds() {
        for k in 0..per_label {
            let (si, body) = super::sets::random_specimen(&mut rng, specimens);
            out.push((
                si,
                MeansSpec {
                    effect: e,
                    second,
                    loaded_body: body,
                    fixed_body: "sacrum".into(),
                    size: rng.random_range(0.3..1.0),
                    n_specimens: 10,
                    magnitude: 7.5,
                    with_sd: k % 2 == 0,
                    primary_only,
                    rig_noise_deg: 0.02,
                    seed: rng.random(),
                },
            ));
        }
    }
    out
}
