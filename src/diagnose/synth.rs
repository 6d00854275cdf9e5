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

use super::family::{preload_expressions, Effect};
use super::sim::Sim;
use crate::calibrate::experiment::Experiment;
use crate::error::{Error, Result};
use crate::osim::document::Document;
use crate::osim::xml::Element;
use crate::solver::{BushingModel, Curve, Expr, System};
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use std::fmt::Write as _;
use std::path::Path;

/// What to generate.
#[derive(Debug, Clone)]
pub struct SynthSpec {
    /// The effect in the truth model (`Effect::None` for none).
    pub effect: Effect,
    /// Body that carries the loads (sets the levels: fixed body .. this one).
    pub loaded_body: String,
    /// Body welded to ground.
    pub fixed_body: String,
    /// Effect size in [0, 1]: 0 modest, 1 obvious.
    pub size: f64,
    /// Rotation noise SD (deg) and translation noise SD (mm).
    pub noise_deg: f64,
    pub noise_mm: f64,
    /// Translations measured.
    pub translations: bool,
    /// Follower-load series present.
    pub follower: bool,
    /// Perturb the joint frames (another specimen) and the nominal stiffness.
    pub perturb_specimen: bool,
    /// Seed of every random choice.
    pub seed: u64,
}

/// What was generated (the label and a description of the truth).
#[derive(Debug, Clone)]
pub struct Truth {
    pub effect: Effect,
    /// Levels where the effect acts.
    pub levels: Vec<String>,
    pub notes: String,
}

const MAGS: [f64; 4] = [1.0, 2.5, 5.0, 7.5];
const AXES: [&str; 3] = ["LB", "AR", "FE"];

/// The load cases: pure moments +-1, 2.5, 5, 7.5 N m about X, Y, Z; with
/// `follower`, moments +-2.5 .. 7.5 under 250 N and 500 N and the two
/// follower loads alone (the development set's design).
fn cases_toml(body: &str, follower: bool) -> (String, Vec<String>) {
    let mut t = String::new();
    let mut ids = Vec::new();
    let mut push = |t: &mut String, id: String, m: [f64; 3], fl: f64| {
        let _ = write!(
            t,
            "[[case]]\nid = \"{id}\"\nbody = \"{body}\"\nmoment = [{:?}, {:?}, {:?}]\nmoment_frame = \"ground\"\n",
            m[0], m[1], m[2]
        );
        if fl > 0.0 {
            let _ = writeln!(t, "follower_load = {fl:?}");
        }
        t.push('\n');
        ids.push(id);
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
    (t, ids)
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

/// Another specimen: both offset frames of every 6-DoF IVD joint moved by
/// the same random offset (SD 1.5 mm) and rotation (SD 1.5 deg), and the
/// nominal stiffness of every bushing scaled by one random factor per DoF.
fn perturb(doc: &mut Document, rng: &mut ChaCha8Rng) -> Result<()> {
    let n = Normal::new(0.0, 1.0).map_err(|e| Error::invalid("synth", e.to_string()))?;
    let ks: [f64; 6] = std::array::from_fn(|_| (0.25f64 * n.sample(rng)).exp());
    let root = doc.model_element_mut();
    let mut err = None;
    walk_mut(root, &mut |e| {
        if e.name == "CustomJoint" && e.name_attr().ends_with("_IVDjnt") {
            let dp: [f64; 3] = std::array::from_fn(|_| 1.5e-3 * n.sample(rng));
            let dr: [f64; 3] = std::array::from_fn(|_| 1.5f64.to_radians() * n.sample(rng));
            if let Some(frames) = e.child_mut("frames") {
                for f in frames.elements_mut() {
                    for (prop, d) in [("translation", dp), ("orientation", dr)] {
                        match f.child_text(prop).as_deref().and_then(parse3) {
                            Some(v) => {
                                f.set_child_text(prop, fmt3(std::array::from_fn(|i| v[i] + d[i])))
                            }
                            None => err = Some(format!("{}: no {prop}", f.name_attr())),
                        }
                    }
                }
            }
        }
        if e.name == "BushingForce" {
            for (prop, o) in [("rotational_stiffness", 0), ("translational_stiffness", 3)] {
                if let Some(v) = e.child_text(prop).as_deref().and_then(parse3) {
                    e.set_child_text(prop, fmt3(std::array::from_fn(|i| v[i] * ks[o + i])));
                }
            }
        }
    });
    match err {
        Some(m) => Err(Error::invalid("synth: perturbing the specimen", m)),
        None => Ok(()),
    }
}

fn parsed(ex: &[String; 6]) -> Result<[Expr; 6]> {
    let v: Vec<Expr> = ex
        .iter()
        .map(|s| Expr::parse(s).map_err(|e| Error::invalid("synth expression", e.to_string())))
        .collect::<Result<_>>()?;
    v.try_into()
        .map_err(|_| Error::invalid("synth expression", "six expressions"))
}

/// A random subset of levels: all of them, one, or a contiguous run.
fn pick_levels(rng: &mut ChaCha8Rng, nl: usize) -> Vec<bool> {
    let mut m = vec![false; nl];
    match rng.random_range(0..3) {
        0 => m.iter_mut().for_each(|v| *v = true),
        1 => m[rng.random_range(0..nl)] = true,
        _ => {
            let len = rng.random_range(2..=nl.max(2)).min(nl);
            let start = rng.random_range(0..=nl - len);
            m[start..start + len].iter_mut().for_each(|v| *v = true);
        }
    }
    m
}

/// The truth system: global stiffness away from nominal plus the effect.
fn truth_system(sim: &Sim, spec: &SynthSpec, rng: &mut ChaCha8Rng) -> Result<(System, Truth)> {
    let n = Normal::new(0.0, 1.0).map_err(|e| Error::invalid("synth", e.to_string()))?;
    let nl = sim.levels.len();
    let s = spec.size.clamp(0.0, 1.0);
    let g: [f64; 3] = std::array::from_fn(|_| rng.random_range(-0.45f64..0.45).exp());
    let mut sys = sim.base.clone();
    let mut notes = format!(
        "global rotational stiffness x{:.3}/{:.3}/{:.3}",
        g[0], g[1], g[2]
    );
    let mut mask = vec![false; nl];
    // largest rotation of each DoF at 7.5 N m under the truth's linear part
    let theta_max = |k: &[f64; 6], d: usize| 7.5 / k[d];
    let sign = |rng: &mut ChaCha8Rng| if rng.random_bool(0.5) { 1.0 } else { -1.0 };
    let effect = spec.effect;
    // per-effect draws shared by all levels
    let lvl_mode = rng.random_range(0..2);
    let nl_form = rng.random_range(0..2);
    let ratio = 1.4 + 1.6 * s; // tangent stiffness ratio at the largest moment
    let asym_dof = rng.random_range(0..3);
    let asym_threshold = rng.random_bool(0.5);
    let asym_up = rng.random_bool(0.5);
    let pair = rng.random_range(0..3);
    let preload_factor = 1.3 + 0.7 * s;
    match effect {
        Effect::LevelDependentStiffness if lvl_mode == 0 => {
            let l = rng.random_range(0..nl);
            mask[l] = true;
        }
        Effect::LevelDependentStiffness
        | Effect::NonlinearStiffness
        | Effect::CoupledStiffness
        | Effect::PreloadStiffening => mask = vec![true; nl],
        Effect::AsymmetricStiffness | Effect::JointPoseError => mask = pick_levels(rng, nl),
        Effect::None => {}
    }
    if effect == Effect::CoupledStiffness && rng.random_bool(0.4) {
        mask = pick_levels(rng, nl);
    }
    for li in 0..nl {
        let kn = sim.k_nominal[li];
        let damping = sim.nominal[li].damping();
        let mut k = kn;
        for d in 0..3 {
            k[d] = kn[d] * g[d];
        }
        let on = mask[li];
        let bushing = sim.levels[li].bushing;
        let linear = |k: [f64; 6]| BushingModel::Linear {
            rot_stiffness: Vector3::new(k[0], k[1], k[2]),
            trans_stiffness: Vector3::new(k[3], k[4], k[5]),
            rot_damping: Vector3::new(damping[0], damping[1], damping[2]),
            trans_damping: Vector3::new(damping[3], damping[4], damping[5]),
        };
        let trans = |k: &[f64; 6]| {
            [
                Curve::Linear { k: k[3] },
                Curve::Linear { k: k[4] },
                Curve::Linear { k: k[5] },
            ]
        };
        let law = match effect {
            Effect::None => linear(k),
            Effect::LevelDependentStiffness => {
                if on {
                    let m = if lvl_mode == 0 {
                        (sign(rng) * (0.5 + 0.6 * s)).exp()
                    } else {
                        ((0.15 + 0.3 * s) * n.sample(rng)).exp()
                    };
                    for d in 0..3 {
                        k[d] *= m * (0.05 * n.sample(rng)).exp();
                    }
                    let _ = write!(notes, "; {} x{m:.3}", sim.levels[li].name);
                }
                linear(k)
            }
            Effect::NonlinearStiffness => {
                let rot: [Curve; 3] = std::array::from_fn(|d| {
                    let th = theta_max(&k, d);
                    if nl_form == 0 {
                        Curve::Sinh {
                            k: k[d],
                            a: th / ratio.acosh(),
                        }
                    } else {
                        Curve::Cubic {
                            k: k[d],
                            c: (ratio - 1.0) * k[d] / (3.0 * th * th),
                        }
                    }
                });
                let [r0, r1, r2] = rot;
                let [t0, t1, t2] = trans(&k);
                BushingModel::PerDof {
                    curves: Box::new([r0, r1, r2, t0, t1, t2]),
                    damping,
                }
            }
            Effect::AsymmetricStiffness if on => {
                let d = asym_dof;
                let r = 1.0 + (ratio - 1.0) * 1.2;
                if asym_threshold {
                    // facet contact on one side beyond a threshold
                    let th0 = 0.15 * theta_max(&k, d);
                    let kc = (r - 1.0) * k[d];
                    let v = ["theta_x", "theta_y", "theta_z"][d];
                    let contact = if asym_up {
                        format!("+{kc:?}*max(0,{v}-{th0:?})")
                    } else {
                        format!("-{kc:?}*max(0,-{v}-{th0:?})")
                    };
                    let ex: [String; 6] = std::array::from_fn(|i| match i {
                        0..=2 if i == d => format!("{:?}*{v}{contact}", k[i]),
                        0 => format!("{:?}*theta_x", k[0]),
                        1 => format!("{:?}*theta_y", k[1]),
                        2 => format!("{:?}*theta_z", k[2]),
                        3 => format!("{:?}*delta_x", k[3]),
                        4 => format!("{:?}*delta_y", k[4]),
                        _ => format!("{:?}*delta_z", k[5]),
                    });
                    BushingModel::Expression {
                        exprs: Box::new(parsed(&ex)?),
                        damping,
                    }
                } else {
                    let rot: [Curve; 3] = std::array::from_fn(|i| {
                        if i == d {
                            let (kn_, kp) = if asym_up {
                                (k[i], k[i] * r)
                            } else {
                                (k[i] * r, k[i])
                            };
                            Curve::Bilinear {
                                k_neg: kn_,
                                k_pos: kp,
                            }
                        } else {
                            Curve::Linear { k: k[i] }
                        }
                    });
                    let [r0, r1, r2] = rot;
                    let [t0, t1, t2] = trans(&k);
                    BushingModel::PerDof {
                        curves: Box::new([r0, r1, r2, t0, t1, t2]),
                        damping,
                    }
                }
            }
            Effect::AsymmetricStiffness => linear(k),
            Effect::CoupledStiffness if on => {
                let mut rho = [0.0; 3];
                rho[pair] = sign(rng) * (0.15 + 0.35 * s);
                BushingModel::Coupled {
                    stiffness: crate::calibrate::forms::coupled_matrix(&k, rho),
                    damping,
                }
            }
            Effect::CoupledStiffness => linear(k),
            Effect::JointPoseError => {
                if on {
                    let ang = (1.0 + 5.0 * s).to_radians();
                    let off = (1.0 + 4.0 * s) * 1e-3;
                    let u = Vector3::new(n.sample(rng), n.sample(rng), n.sample(rng));
                    let v = Vector3::new(n.sample(rng), n.sample(rng), n.sample(rng));
                    let w = u.try_normalize(1e-12).unwrap_or(Vector3::x()) * ang;
                    let t = v.try_normalize(1e-12).unwrap_or(Vector3::y()) * off;
                    let tr = Isometry3::from_parts(
                        Translation3::from(t),
                        UnitQuaternion::from_scaled_axis(w),
                    );
                    let (x1, x2) = sim.frames[li];
                    sys = sys.with_bushing_joint_frames(bushing, &(x1 * tr), &(x2 * tr))?;
                }
                linear(k)
            }
            Effect::PreloadStiffening => {
                let fmax = if spec.follower { 500.0 } else { 1.0 };
                let beta = (preload_factor - 1.0) * k[4] / fmax;
                BushingModel::Expression {
                    exprs: Box::new(parsed(&preload_expressions(&k, beta))?),
                    damping,
                }
            }
        };
        sys = sys.with_bushing_model(bushing, law)?;
    }
    let _ = write!(notes, "; size {s:.2}");
    match effect {
        Effect::NonlinearStiffness => {
            let _ = write!(
                notes,
                "; {} tangent ratio {ratio:.2}",
                ["sinh", "cubic"][nl_form]
            );
        }
        Effect::AsymmetricStiffness => {
            let _ = write!(
                notes,
                "; {} {} {}",
                ["rx", "ry", "rz"][asym_dof],
                if asym_threshold {
                    "threshold contact"
                } else {
                    "bilinear"
                },
                if asym_up {
                    "positive side"
                } else {
                    "negative side"
                }
            );
        }
        Effect::CoupledStiffness => {
            let _ = write!(notes, "; pair {}", ["xy", "xz", "yz"][pair]);
        }
        Effect::PreloadStiffening => {
            let _ = write!(notes, "; x{preload_factor:.2} at 500 N");
        }
        _ => {}
    }
    let levels = sim
        .levels
        .iter()
        .zip(&mask)
        .filter(|p| *p.1)
        .map(|p| p.0.name.clone())
        .collect();
    Ok((
        sys,
        Truth {
            effect,
            levels,
            notes,
        },
    ))
}

/// Write a synthetic experiment into `dir` from the nominal `specimen`
/// (.osim). Preload stiffening always gets the follower-load series.
pub fn write(specimen: &Path, spec: &SynthSpec, dir: &Path) -> Result<Truth> {
    let mut rng = ChaCha8Rng::seed_from_u64(spec.seed);
    let mut spec = spec.clone();
    if spec.effect == Effect::PreloadStiffening {
        spec.follower = true;
    }
    let mut doc = Document::read(specimen)?;
    if spec.perturb_specimen {
        perturb(&mut doc, &mut rng)?;
    }
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    crate::util::write_atomic(&dir.join("specimen.osim"), doc.to_xml_string().as_bytes())?;
    let (cases, ids) = cases_toml(&spec.loaded_body, spec.follower);
    let toml = format!(
        "[specimen]\nmodel = \"specimen.osim\"\nfixed_body = \"{}\"\ngravity = false\n\n[units]\nangle = \"deg\"\nlength = \"mm\"\n\n{cases}",
        spec.fixed_body
    );
    crate::util::write_atomic(&dir.join("experiment.toml"), toml.as_bytes())?;
    // the levels on the load path, from the nominal system
    let levels = {
        let model = doc.model()?;
        let s = crate::solver::SystemSpec::from_model(&model)?;
        let s = System::with_body_fixed(&s, &spec.fixed_body)?;
        let sys = System::new(&s)?;
        let fixed = sys
            .body_index(&spec.fixed_body)
            .ok_or_else(|| Error::invalid("synth", "fixed body not in the model"))?;
        let loaded = sys
            .body_index(&spec.loaded_body)
            .ok_or_else(|| Error::invalid("synth", "loaded body not in the model"))?;
        crate::calibrate::family::find_levels(&sys, fixed, &[loaded])
    };
    let csv = |vals: &dyn Fn(usize, usize) -> [f64; 6]| {
        let mut t = String::from("case,upper,lower,rx,ry,rz,tx,ty,tz\n");
        let mut row = 0;
        for (ci, id) in ids.iter().enumerate() {
            for l in &levels {
                let v = vals(ci, row);
                let _ = write!(
                    t,
                    "{id},{},{},{:.4},{:.4},{:.4}",
                    l.upper_name, l.lower_name, v[0], v[1], v[2]
                );
                if spec.translations {
                    let _ = writeln!(t, ",{:.4},{:.4},{:.4}", v[3], v[4], v[5]);
                } else {
                    t.push_str(",,,\n");
                }
                row += 1;
            }
        }
        t
    };
    crate::util::write_atomic(
        &dir.join("kinematics.csv"),
        csv(&|_, _| [0.0; 6]).as_bytes(),
    )?;
    let exp = Experiment::read(dir)?;
    let sim = Sim::new(&exp)?;
    let (sys, truth) = truth_system(&sim, &spec, &mut rng)?;
    let all: Vec<usize> = (0..exp.cases.len()).collect();
    let pred = sim.predict(&sys, &all, &mut sim.warm())?;
    let nr = Normal::new(0.0, spec.noise_deg.max(1e-12))
        .map_err(|e| Error::invalid("synth", e.to_string()))?;
    let nt = Normal::new(0.0, spec.noise_mm.max(1e-12))
        .map_err(|e| Error::invalid("synth", e.to_string()))?;
    let noisy: Vec<[f64; 6]> = pred
        .iter()
        .map(|p| {
            std::array::from_fn(|d| {
                p[d] + if d < 3 {
                    nr.sample(&mut rng)
                } else {
                    nt.sample(&mut rng)
                }
            })
        })
        .collect();
    crate::util::write_atomic(
        &dir.join("kinematics.csv"),
        csv(&|_, r| noisy.get(r).copied().unwrap_or([0.0; 6])).as_bytes(),
    )?;
    Ok(truth)
}

/// A published-means experiment: the mean of `n_specimens` perturbed
/// specimens that all carry the same effect (same form, size and levels;
/// each specimen its own joint frames and stiffness), one moment magnitude
/// per direction, rotations only, rig noise per specimen; with `with_sd`
/// the SD across the specimens in `sd_rx .. sd_rz`.
#[derive(Debug, Clone)]
pub struct MeansSpec {
    pub effect: Effect,
    pub loaded_body: String,
    pub fixed_body: String,
    /// Effect size in [0, 1].
    pub size: f64,
    pub n_specimens: usize,
    /// Moment magnitude (N m) of every case.
    pub magnitude: f64,
    /// Write the `sd_*` columns.
    pub with_sd: bool,
    /// Only the rotation about the load axis is measured (other cells blank).
    pub primary_only: bool,
    /// Rig noise of each specimen's measurement (deg).
    pub rig_noise_deg: f64,
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
/// the nominal document perturbed by `specimen_rng`, the effect drawn by
/// `effect_rng` (the same seed for every specimen), plus rig noise.
fn specimen_rotations(
    exp: &Experiment,
    nominal: &Document,
    spec: &SynthSpec,
    specimen_rng: &mut ChaCha8Rng,
    effect_seed: u64,
) -> Result<(Vec<[f64; 3]>, Truth)> {
    let mut doc = nominal.clone();
    perturb(&mut doc, specimen_rng)?;
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
        let axis = super::design::CaseInfo::of(c).axis;
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
    let follower = spec.effect == Effect::PreloadStiffening;
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
        seed: spec.seed,
    };
    let mut rng = ChaCha8Rng::seed_from_u64(spec.seed);
    let effect_seed: u64 = rng.random();
    let mut per = Vec::new();
    let mut truth = None;
    for _ in 0..spec.n_specimens.max(2) {
        let (rows, t) = specimen_rotations(&exp, &nominal, &one, &mut rng, effect_seed)?;
        per.push(rows);
        truth.get_or_insert(t);
    }
    let csv = means_csv(&exp, &mean_sd(&per), spec);
    crate::util::write_atomic(&dir.join("kinematics.csv"), csv.as_bytes())?;
    truth.ok_or_else(|| Error::invalid("synth", "no specimen"))
}

/// A `kinematics.csv` of zeros with one row per case and level (so that the
/// experiment can be read before its values exist).
fn write_placeholder_rows(doc: &Document, fixed: &str, loaded: &str, dir: &Path) -> Result<()> {
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
            let _ = writeln!(t, "{},{},{},0,0,0,,,", c.id, lv.upper_name, lv.lower_name);
        }
    }
    crate::util::write_atomic(&dir.join("kinematics.csv"), t.as_bytes())
}

/// The published-means set: `per_label` experiments for each of the seven
/// labels, half with `sd_*` columns, random size, level range and
/// specimen seed, all from `seed`.
pub fn means_set(
    per_label: usize,
    seed: u64,
    specimens: &[(String, Vec<String>)],
    primary_only: bool,
) -> Vec<(usize, MeansSpec)> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let labels = std::iter::once(Effect::None).chain(Effect::CANDIDATES);
    let mut out = Vec::new();
    for e in labels {
        for k in 0..per_label {
            let si = rng.random_range(0..specimens.len().max(1));
            let bodies = specimens.get(si).map(|s| s.1.as_slice()).unwrap_or(&[]);
            let body = bodies
                .get(rng.random_range(0..bodies.len().max(1)))
                .cloned()
                .unwrap_or_default();
            out.push((
                si,
                MeansSpec {
                    effect: e,
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

/// The standard synthetic withheld set: `n` cases cycling through the seven
/// labels, with random loaded body (level range), size, noise,
/// translations, follower series and specimen perturbation, all from
/// `seed`. Each entry is the spec; `specimens` are the nominal models to
/// draw from, with their fixed body and the bodies that can be loaded.
pub fn standard_set(
    n: usize,
    seed: u64,
    specimens: &[(String, Vec<String>)],
) -> Vec<(usize, SynthSpec)> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let labels = [
        Effect::None,
        Effect::LevelDependentStiffness,
        Effect::NonlinearStiffness,
        Effect::AsymmetricStiffness,
        Effect::CoupledStiffness,
        Effect::JointPoseError,
        Effect::PreloadStiffening,
    ];
    (0..n)
        .filter(|_| !specimens.is_empty())
        .map(|i| {
            let si = rng.random_range(0..specimens.len());
            let bodies = specimens.get(si).map(|s| s.1.as_slice()).unwrap_or(&[]);
            let body = bodies
                .get(rng.random_range(0..bodies.len().max(1)))
                .cloned()
                .unwrap_or_default();
            (
                si,
                SynthSpec {
                    effect: labels[i % labels.len()],
                    loaded_body: body,
                    fixed_body: "sacrum".into(),
                    size: rng.random_range(0.0..1.0),
                    noise_deg: rng.random_range(0.01..0.05),
                    noise_mm: rng.random_range(0.01..0.05),
                    translations: rng.random_bool(0.7),
                    follower: rng.random_bool(0.4),
                    perturb_specimen: rng.random_bool(0.6),
                    seed: rng.random(),
                },
            )
        })
        .collect()
}

/// One scored experiment: truth label, verdict, held-out shrink.
#[derive(Debug, Clone, PartialEq)]
pub struct Scored {
    pub truth: String,
    pub verdict: String,
    pub shrink: f64,
}

/// The scoring summary of labelled experiments (the acceptance figures of
/// the diagnose issue): the confusion matrix (rows truth, columns verdict,
/// the format's vocabulary plus `unidentifiable`), then top-1 accuracy,
/// effects claimed on `none` cases and the median held-out shrink of the
/// effect cases.
pub fn score_summary(rows: &[Scored]) -> String {
    use std::fmt::Write;
    let mut names: Vec<&str> = std::iter::once(Effect::None)
        .chain(Effect::CANDIDATES)
        .map(|e| e.name())
        .collect();
    let truths = names.len();
    names.push("unidentifiable");
    let mut out = String::from("confusion (rows truth, columns verdict):\n");
    let _ = write!(out, "{:<28}", "");
    for n in &names {
        let _ = write!(out, "{:>6}", &n[..4]);
    }
    out.push('\n');
    for t in &names[..truths] {
        let _ = write!(out, "{t:<28}");
        for v in &names {
            let n = rows
                .iter()
                .filter(|r| r.truth == *t && r.verdict == *v)
                .count();
            let _ = write!(out, "{n:>6}");
        }
        out.push('\n');
    }
    let correct = rows.iter().filter(|r| r.truth == r.verdict).count();
    // an effect name on a `none` case (`unidentifiable` names none)
    let false_claims = rows
        .iter()
        .filter(|r| r.truth == "none" && r.verdict != "none" && r.verdict != "unidentifiable")
        .count();
    let shrinks: Vec<f64> = rows
        .iter()
        .filter(|r| r.truth != "none")
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
