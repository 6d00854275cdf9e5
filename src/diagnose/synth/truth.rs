//! The truth system of a synthetic experiment: the nominal specimen with
//! its global rotational stiffness moved away from the nominal values, plus
//! one or two effects of random form, size and levels. The effects build
//! each level's law through [`LawParts`] (a native law for one effect, an
//! expression law for two) and move joint frames for a pose error.
//!
//! Every random number is drawn in a fixed order from one `ChaCha8Rng`:
//! the global factors, the draws shared by all levels, the levels of each
//! effect, then level by level each effect's own draws. A single-effect
//! truth draws exactly what it always drew (same seed, same experiment).

use super::{SynthSpec, Truth};
use crate::diagnose::family::Effect;
use crate::diagnose::law::{LawParts, OneSided};
use crate::diagnose::sim::Sim;
use crate::error::{Error, Result};
use crate::solver::{Curve, System};
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use std::fmt::Write as _;

/// The draws every level of a truth shares.
struct Draws {
    /// Level-dependent stiffness: 0 one level much stiffer or softer, 1
    /// every level its own factor.
    lvl_mode: u32,
    /// Nonlinear form: 0 sinh, 1 cubic.
    nl_form: usize,
    /// Tangent stiffness ratio at the largest moment.
    ratio: f64,
    asym_dof: usize,
    asym_threshold: bool,
    asym_up: bool,
    /// Coupled pair: 0 xy, 1 xz, 2 yz.
    pair: usize,
    /// Stiffness factor under the 500 N follower load.
    preload_factor: f64,
}

impl Draws {
    /// Draw them (size `s` in [0, 1]).
    fn new(rng: &mut ChaCha8Rng, s: f64) -> Draws {
        let lvl_mode = rng.random_range(0..2);
        let nl_form = rng.random_range(0..2);
        let asym_dof = rng.random_range(0..3);
        let asym_threshold = rng.random_bool(0.5);
        let asym_up = rng.random_bool(0.5);
        let pair = rng.random_range(0..3);
        Draws {
            lvl_mode,
            nl_form,
            ratio: 1.4 + 1.6 * s,
            asym_dof,
            asym_threshold,
            asym_up,
            pair,
            preload_factor: 1.3 + 0.7 * s,
        }
    }
}

/// The draws of a published table's forms (`SynthSpec::table_forms`),
/// drawn after the standard ones: a stiffness trend along the spine in
/// some rotational DoFs (the first level against the last one x 1.4 ..
/// 2.5, either way, as published ranges of motion differ along the lumbar
/// spine) and a one-sided stiffening shared by every level in some DoFs
/// (x 1.7 .. 2.5, as flexion and extension ranges differ).
struct TableDraws {
    /// Log-stiffness slope per unit of level position, per DoF (0: none).
    trend: [f64; 3],
    /// One-sided factor per DoF (`None`: symmetric) and the stiffer side.
    asym: [Option<(f64, bool)>; 3],
}

impl TableDraws {
    /// Draw them (size `s` in [0, 1]) for levels spanning `span` positions.
    fn new(rng: &mut ChaCha8Rng, s: f64, span: f64) -> TableDraws {
        let some = |rng: &mut ChaCha8Rng, p: f64| -> [bool; 3] {
            let mut on: [bool; 3] = std::array::from_fn(|_| rng.random_bool(p));
            if !on.iter().any(|x| *x) {
                on[rng.random_range(0..3)] = true;
            }
            on
        };
        let on = some(rng, 0.7);
        let trend = std::array::from_fn(|d| {
            let ratio: f64 = 1.4 + 1.1 * s * rng.random_range(0.8..1.0);
            if on[d] {
                sign(rng) * ratio.ln() / span.max(1.0)
            } else {
                0.0
            }
        });
        let on = some(rng, 0.5);
        let asym = std::array::from_fn(|d| {
            let r = 1.7 + 0.8 * s * rng.random_range(0.8..1.0);
            let up = rng.random_bool(0.5);
            on[d].then_some((r, up))
        });
        TableDraws { trend, asym }
    }
}

/// A random subset of levels: all of them, one, or a contiguous run.
pub(super) fn pick_levels(rng: &mut ChaCha8Rng, nl: usize) -> Vec<bool> {
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

/// The levels where `effect` acts (a table's trend and shared asymmetry:
/// all).
fn effect_mask(
    effect: Effect,
    d: &Draws,
    table: bool,
    rng: &mut ChaCha8Rng,
    nl: usize,
) -> Vec<bool> {
    let mut mask = vec![false; nl];
    let shared = matches!(
        effect,
        Effect::LevelDependentStiffness | Effect::AsymmetricStiffness
    );
    if table && shared {
        return vec![true; nl];
    }
    match effect {
        Effect::LevelDependentStiffness if d.lvl_mode == 0 => {
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
    mask
}

/// What one level's effects need besides the parts.
struct LevelCtx<'a> {
    sim: &'a Sim,
    spec: &'a SynthSpec,
    d: &'a Draws,
    table: Option<&'a TableDraws>,
    n: Normal<f64>,
    li: usize,
}

/// Largest rotation (rad) of DoF `d` at 7.5 N m under linear stiffness `k`.
fn theta_max(k: &[f64; 6], d: usize) -> f64 {
    7.5 / k[d]
}

/// A random sign.
fn sign(rng: &mut ChaCha8Rng) -> f64 {
    if rng.random_bool(0.5) {
        1.0
    } else {
        -1.0
    }
}

/// Add `effect` at a level where it acts: the law's parts, or (pose) the
/// frame change returned.
fn add_effect(
    effect: Effect,
    c: &LevelCtx,
    p: &mut LawParts,
    rng: &mut ChaCha8Rng,
    notes: &mut String,
) -> Option<Isometry3<f64>> {
    let s = c.spec.size.clamp(0.0, 1.0);
    let d = c.d;
    match (effect, c.table) {
        (Effect::LevelDependentStiffness, Some(t)) => {
            // the trend at this level's position, 5% jitter per level
            let z = c.sim.position[c.li] - crate::diagnose::family::mean_position(c.sim);
            let mut f = [1.0; 3];
            for (dof, fd) in f.iter_mut().enumerate() {
                *fd = (t.trend[dof] * z + 0.05 * c.n.sample(rng)).exp();
                p.k[dof] *= *fd;
            }
            let _ = write!(
                notes,
                "; {} x{:.3}/{:.3}/{:.3}",
                c.sim.levels[c.li].level.name, f[0], f[1], f[2]
            );
            return None;
        }
        (Effect::AsymmetricStiffness, Some(t)) => {
            for (dof, a) in t.asym.iter().enumerate() {
                if let Some((r, up)) = a {
                    one_sided_factor(p, dof, *up, *r);
                }
            }
            return None;
        }
        _ => {}
    }
    match effect {
        Effect::None => {}
        Effect::LevelDependentStiffness => {
            let m = if d.lvl_mode == 0 {
                (sign(rng) * (0.5 + 0.6 * s)).exp()
            } else {
                ((0.15 + 0.3 * s) * c.n.sample(rng)).exp()
            };
            for k in p.k.iter_mut().take(3) {
                *k *= m * (0.05 * c.n.sample(rng)).exp();
            }
            let _ = write!(notes, "; {} x{m:.3}", c.sim.levels[c.li].level.name);
        }
        Effect::NonlinearStiffness => add_nonlinear(d, p),
        Effect::AsymmetricStiffness => add_asymmetry(d, p),
        Effect::CoupledStiffness => {
            let mut rho = [0.0; 3];
            rho[d.pair] = sign(rng) * (0.15 + 0.35 * s);
            p.rho = Some(rho);
        }
        Effect::JointPoseError => return Some(pose_change(c, s, rng)),
        Effect::PreloadStiffening => {
            let fmax = if c.spec.follower { 500.0 } else { 1.0 };
            p.beta = Some((d.preload_factor - 1.0) * p.k[4] / fmax);
        }
    }
    None
}

/// Neutral-zone (sinh) or stiffening (cubic) curves on every rotational
/// DoF, reaching the tangent ratio at the largest moment.
fn add_nonlinear(d: &Draws, p: &mut LawParts) {
    let k = p.k;
    for (i, r) in p.rot.iter_mut().enumerate() {
        let th = theta_max(&k, i);
        *r = Some(if d.nl_form == 0 {
            Curve::Sinh {
                k: k[i],
                a: th / d.ratio.acosh(),
            }
        } else {
            Curve::Cubic {
                k: k[i],
                c: (d.ratio - 1.0) * k[i] / (3.0 * th * th),
            }
        });
    }
}

/// One side of rotational DoF `i` stiffer by `r` (bilinear, or an added
/// one-sided term on a curved law).
fn one_sided_factor(p: &mut LawParts, i: usize, up: bool, r: f64) {
    let k = p.k[i];
    if p.rot[i].is_some() {
        p.one_sided[i] = Some(OneSided {
            positive: up,
            threshold: 0.0,
            factor: r,
        });
    } else {
        let (k_neg, k_pos) = if up { (k, k * r) } else { (k * r, k) };
        p.rot[i] = Some(Curve::Bilinear { k_neg, k_pos });
    }
}

/// One side of one rotational DoF stiffer: facet contact beyond a
/// threshold, or a bilinear law.
fn add_asymmetry(d: &Draws, p: &mut LawParts) {
    let i = d.asym_dof;
    let r = 1.0 + (d.ratio - 1.0) * 1.2;
    let k = p.k[i];
    if d.asym_threshold || p.rot[i].is_some() {
        let threshold = if d.asym_threshold {
            0.15 * theta_max(&p.k, i)
        } else {
            0.0
        };
        p.one_sided[i] = Some(OneSided {
            positive: d.asym_up,
            threshold,
            factor: r,
        });
    } else {
        let (k_neg, k_pos) = if d.asym_up { (k, k * r) } else { (k * r, k) };
        p.rot[i] = Some(Curve::Bilinear { k_neg, k_pos });
    }
}

/// A joint pose error: both joint frames rotated (1-6 deg) and moved
/// (1-5 mm) in random directions.
fn pose_change(c: &LevelCtx, s: f64, rng: &mut ChaCha8Rng) -> Isometry3<f64> {
    let ang = (1.0 + 5.0 * s).to_radians();
    let off = (1.0 + 4.0 * s) * 1e-3;
    let n = c.n;
    let u = Vector3::new(n.sample(rng), n.sample(rng), n.sample(rng));
    let v = Vector3::new(n.sample(rng), n.sample(rng), n.sample(rng));
    let w = u.try_normalize(1e-12).unwrap_or(Vector3::x()) * ang;
    let t = v.try_normalize(1e-12).unwrap_or(Vector3::y()) * off;
    Isometry3::from_parts(Translation3::from(t), UnitQuaternion::from_scaled_axis(w))
}

/// The effects of a spec in the order their laws are built (level
/// factors first, see [`Effect::order`]).
fn effects_of(spec: &SynthSpec) -> Vec<Effect> {
    let mut v = vec![spec.effect];
    v.extend(
        spec.second
            .filter(|e| *e != spec.effect && *e != Effect::None),
    );
    v.sort_by_key(Effect::order);
    v
}

/// The notes of an effect's shared draws.
fn effect_notes(effect: Effect, d: &Draws, notes: &mut String) {
    match effect {
        Effect::NonlinearStiffness => {
            let form = ["sinh", "cubic"][d.nl_form];
            let _ = write!(notes, "; {form} tangent ratio {:.2}", d.ratio);
        }
        Effect::AsymmetricStiffness => {
            let _ = write!(
                notes,
                "; {} {} {}",
                ["rx", "ry", "rz"][d.asym_dof],
                if d.asym_threshold {
                    "threshold contact"
                } else {
                    "bilinear"
                },
                if d.asym_up {
                    "positive side"
                } else {
                    "negative side"
                }
            );
        }
        Effect::CoupledStiffness => {
            let _ = write!(notes, "; pair {}", ["xy", "xz", "yz"][d.pair]);
        }
        Effect::PreloadStiffening => {
            let _ = write!(notes, "; x{:.2} at 500 N", d.preload_factor);
        }
        _ => {}
    }
}

/// The notes of a table form's shared draws.
fn table_notes(effect: Effect, t: &TableDraws, notes: &mut String) {
    match effect {
        Effect::LevelDependentStiffness => {
            let _ = write!(
                notes,
                "; trend log-slope per level {:.3}/{:.3}/{:.3}",
                t.trend[0], t.trend[1], t.trend[2]
            );
        }
        Effect::AsymmetricStiffness => {
            for (d, a) in t.asym.iter().enumerate() {
                if let Some((r, up)) = a {
                    let side = if *up { "positive" } else { "negative" };
                    let _ = write!(
                        notes,
                        "; {} {side} side x{r:.2} at every level",
                        ["rx", "ry", "rz"][d]
                    );
                }
            }
        }
        _ => {}
    }
}

/// The truth system: global stiffness away from nominal plus the effects.
pub(super) fn truth_system(
    sim: &Sim,
    spec: &SynthSpec,
    rng: &mut ChaCha8Rng,
) -> Result<(System, Truth)> {
    let n = Normal::new(0.0, 1.0).map_err(|e| Error::invalid("synth", e.to_string()))?;
    let nl = sim.levels.len();
    // global factors, the shared draws, then where each effect acts
    let g: [f64; 3] = std::array::from_fn(|_| rng.random_range(-0.45f64..0.45).exp());
    let mut notes = format!(
        "global rotational stiffness x{:.3}/{:.3}/{:.3}",
        g[0], g[1], g[2]
    );
    let d = Draws::new(rng, spec.size.clamp(0.0, 1.0));
    let span = sim.position.iter().fold(0.0f64, |m, v| m.max(*v))
        - sim.position.iter().fold(f64::INFINITY, |m, v| m.min(*v));
    let table = spec
        .table_forms
        .then(|| TableDraws::new(rng, spec.size.clamp(0.0, 1.0), span));
    let effects = effects_of(spec);
    let masks: Vec<Vec<bool>> = effects
        .iter()
        .map(|&e| effect_mask(e, &d, spec.table_forms, rng, nl))
        .collect();
    // level by level: the global factors, then each effect where it acts
    let mut sys = sim.base.clone();
    for li in 0..nl {
        let mut k = sim.k_nominal[li];
        for (kd, gd) in k.iter_mut().zip(g) {
            *kd *= gd;
        }
        let mut parts = LawParts::new(k, sim.nominal[li].damping());
        let c = LevelCtx {
            sim,
            spec,
            d: &d,
            table: table.as_ref(),
            n,
            li,
        };
        for (e, mask) in effects.iter().zip(&masks) {
            if !mask[li] {
                continue;
            }
            if let Some(t) = add_effect(*e, &c, &mut parts, rng, &mut notes) {
                let (x1, x2) = sim.frames[li];
                let b = sim.levels[li].bushing;
                sys = sys.with_bushing_joint_frames(b, &(x1 * t), &(x2 * t))?;
            }
        }
        sys = sys.with_bushing_model(sim.levels[li].bushing, parts.model()?.0)?;
    }
    let _ = write!(notes, "; size {:.2}", spec.size.clamp(0.0, 1.0));
    for &e in &effects {
        match &table {
            Some(t)
                if matches!(
                    e,
                    Effect::LevelDependentStiffness | Effect::AsymmetricStiffness
                ) =>
            {
                table_notes(e, t, &mut notes)
            }
            _ => effect_notes(e, &d, &mut notes),
        }
    }
    let levels = (0..nl)
        .filter(|&li| masks.iter().any(|m| m[li]))
        .map(|li| sim.levels[li].level.name.clone())
        .collect();
    let truth = Truth {
        effect: spec.effect,
        second: spec
            .second
            .filter(|e| effects.contains(e) && *e != spec.effect),
        oov: spec.oov,
        levels,
        notes,
    };
    Ok((sys, truth))
}
