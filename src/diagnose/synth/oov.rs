//! Out-of-vocabulary truths: effects none of the diagnoser's candidates
//! describes, added to a nominal-form truth (global stiffness away from
//! nominal, no effect of the vocabulary) while the experiment file keeps
//! stating the nominal loads. They test whether `diagnose` says `other`
//! instead of forcing a name from its vocabulary.

use crate::diagnose::sim::Sim;
use crate::error::Result;
use crate::solver::{BushingModel, Load, LoadSet, System};
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use rand::Rng;
use rand_chacha::ChaCha8Rng;

/// An effect outside the vocabulary of `experiment.md`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Oov {
    /// Creep between load steps: a fraction of each step's deformation is
    /// still there when the next step is measured (incomplete recovery).
    Creep,
    /// Every applied moment 15 deg off its nominal axis (a misaligned
    /// fixture), each axis tilted towards its own random direction.
    OffAxisMoment,
    /// Follower-load guide points 10 mm anterior of the joint centres.
    FollowerAnterior,
    /// Rotational stiffness softened by the largest moment applied before
    /// about the same axis (preconditioning by the loading history).
    HistoryStiffness,
}

impl Oov {
    /// All four, in the order the out-of-vocabulary set cycles through.
    pub const ALL: [Oov; 4] = [
        Oov::Creep,
        Oov::OffAxisMoment,
        Oov::FollowerAnterior,
        Oov::HistoryStiffness,
    ];

    /// A short name for tables.
    pub fn name(&self) -> &'static str {
        match self {
            Oov::Creep => "creep",
            Oov::OffAxisMoment => "off_axis_moment",
            Oov::FollowerAnterior => "follower_anterior",
            Oov::HistoryStiffness => "history_stiffness",
        }
    }
}

/// Predicted increments (report units) of every row of every case of the
/// truth `sys` with the out-of-vocabulary effect `oov` of size `s` in
/// [0, 1], and a note describing it.
pub(super) fn predict(
    sim: &Sim,
    sys: &System,
    oov: Oov,
    s: f64,
    rng: &mut ChaCha8Rng,
) -> Result<(Vec<[f64; 6]>, String)> {
    let all: Vec<usize> = (0..sim.loads.len()).collect();
    match oov {
        Oov::Creep => {
            let carry = 0.1 + 0.15 * s;
            let pred = sim.predict(sys, &all, &mut sim.warm())?;
            let note = format!("creep: {carry:.2} of each step carried into the next");
            Ok((creep(sim, &pred, carry), note))
        }
        Oov::OffAxisMoment => {
            let phi: [f64; 3] =
                std::array::from_fn(|_| rng.random_range(0.0..std::f64::consts::TAU));
            let truth = with_prepared(sim, tilted_loads(sim, sys, phi)?);
            let note = "every moment 15 deg off its axis".to_string();
            Ok((truth.predict(sys, &all, &mut truth.warm())?, note))
        }
        Oov::FollowerAnterior => {
            let truth = with_prepared(sim, anterior_guides(sim, sys)?);
            let note = "follower guide points 10 mm anterior".to_string();
            Ok((truth.predict(sys, &all, &mut truth.warm())?, note))
        }
        Oov::HistoryStiffness => {
            let delta = 0.2 + 0.3 * s;
            let note =
                format!("stiffness softened by {delta:.2} x (largest earlier moment / 7.5 N m)");
            Ok((history(sim, sys, delta)?, note))
        }
    }
}

/// The simulated experiment with other resolved loads.
fn with_prepared(sim: &Sim, prepared: Vec<LoadSet>) -> Sim {
    Sim {
        prepared,
        ..sim.clone()
    }
}

/// Each case's rows plus `carry` times the previous case's rows (same level).
fn creep(sim: &Sim, pred: &[[f64; 6]], carry: f64) -> Vec<[f64; 6]> {
    let mut out = pred.to_vec();
    for (ci, rows) in sim.case_rows.iter().enumerate().skip(1) {
        for (k, &r) in rows.iter().enumerate() {
            if let Some(&p) = sim.case_rows[ci - 1].get(k) {
                out[r] = std::array::from_fn(|d| pred[r][d] + carry * pred[p][d]);
            }
        }
    }
    out
}

/// Every case's loads with the moment tilted 15 deg off its dominant axis
/// `a`, towards the direction at angle `phi[a]` in the plane normal to it.
fn tilted_loads(sim: &Sim, sys: &System, phi: [f64; 3]) -> Result<Vec<LoadSet>> {
    let tilt = 15f64.to_radians();
    let tilt_of = |m: &Vector3<f64>| -> Vector3<f64> {
        let a = m.iamax();
        let (b, c) = ((a + 1) % 3, (a + 2) % 3);
        let mut perp = Vector3::zeros();
        perp[b] = phi[a].cos();
        perp[c] = phi[a].sin();
        let axis = Vector3::ith(a, 1.0).cross(&perp);
        UnitQuaternion::from_scaled_axis(axis * tilt) * m
    };
    sim.loads
        .iter()
        .map(|loads| {
            let tilted: Vec<Load> = loads
                .iter()
                .map(|l| match l {
                    Load::Moment { body, vec, frame } => Load::Moment {
                        body: body.clone(),
                        vec: tilt_of(vec),
                        frame: *frame,
                    },
                    other => other.clone(),
                })
                .collect();
            sys.prepare_loads(&tilted)
        })
        .collect()
}

/// Every case's loads resolved on the system with every joint centre 10 mm
/// anterior (frame X), so that the follower guide points sit there; the
/// bodies stay where they are (both joint frames move together).
fn anterior_guides(sim: &Sim, sys: &System) -> Result<Vec<LoadSet>> {
    let t = Isometry3::from_parts(
        Translation3::new(0.010, 0.0, 0.0),
        UnitQuaternion::identity(),
    );
    let mut moved = sys.clone();
    for (li, l) in sim.levels.iter().enumerate() {
        let (x1, x2) = sim.frames[li];
        moved = moved.with_bushing_joint_frames(l.bushing, &(x1 * t), &(x2 * t))?;
    }
    sim.loads.iter().map(|l| moved.prepare_loads(l)).collect()
}

/// Each case solved with every level's rotational stiffness about axis
/// `a` divided by `1 + delta m_a / 7.5`, `m_a` the largest moment (N m)
/// about `a` of the cases before it.
fn history(sim: &Sim, sys: &System, delta: f64) -> Result<Vec<[f64; 6]>> {
    let mut out = vec![[0.0; 6]; sim.row_bodies.len()];
    let mut seen = [0.0f64; 3];
    for (ci, loads) in sim.loads.iter().enumerate() {
        let f: [f64; 3] = std::array::from_fn(|a| 1.0 / (1.0 + delta * seen[a] / 7.5));
        let mut softened = sys.clone();
        for l in &sim.levels {
            if let Some(BushingModel::Linear {
                rot_stiffness: r,
                trans_stiffness: t,
                ..
            }) = sys.bushing_model(l.bushing)
            {
                let k = [r.x * f[0], r.y * f[1], r.z * f[2], t.x, t.y, t.z];
                softened = softened.with_bushing_stiffness(l.bushing, k)?;
            }
        }
        let pred = sim.predict(&softened, &[ci], &mut sim.warm())?;
        for &r in &sim.case_rows[ci] {
            out[r] = pred[r];
        }
        for l in loads {
            if let Load::Moment { vec, .. } = l {
                for a in 0..3 {
                    seen[a] = seen[a].max(vec[a].abs());
                }
            }
        }
    }
    Ok(out)
}
