//! The least-squares problem of the films: residuals
//! `(R(phi) m_i(q) + t - f_i) / sigma` of every film point the model has
//! (vertebral landmarks, sacrum, femoral heads), where `q` is the
//! equilibrium of the bending model under the film's two loads, `m_i` the
//! model's frontal projection, `(phi, t)` the film's placement and `sigma`
//! the digitising noise. Parameters, in order:
//! - the stiffness coordinates `x` (when estimating): `log m = B x` with
//!   `B` an orthonormal basis of the vectors summing to zero, so the
//!   estimated joints' multipliers have geometric mean 1 (a prescribed
//!   level fixes only stiffness ratios: scaling every stiffness and both
//!   loads together leaves every film unchanged);
//! - per film: the lateral force and frontal moment on its loaded level
//!   and its placement `(phi, t_u, t_v)`.
//!
//! A Gaussian prior on the log multipliers adds the residuals `A log m`
//! (rows of `A`: a joint's `log m_j / sd`, or a neighbour difference
//! `(log m_{j+1} - log m_j) / sd`). Minimised by
//! the crate's one Levenberg-Marquardt ([`crate::util::lm`]) with the
//! exact Jacobian of [`super::bend`].

use super::bend::BendModel;
use super::place::{procrustes, Placement};
use crate::error::{Error, Result};
use crate::landmarks::radiograph::FilmPoint;
use crate::landmarks::Level;
use crate::solver::Workspace;
use crate::util::lm::{self, LmOptions, LmResult};
use nalgebra::{DMatrix, DVector, Vector2};

/// A film ready for fitting.
#[derive(Debug, Clone)]
pub struct FilmData {
    /// File stem (`film_left`).
    pub stem: String,
    /// The file, for messages.
    pub file: String,
    /// The level the loads act on (the most cranial vertebra on the film).
    pub level: Level,
    /// Points the film and the model both have, in order.
    pub points: Vec<FilmPoint>,
    /// Their film coordinates at the patient's scale (divided by the
    /// magnification), m.
    pub measured: Vec<Vector2<f64>>,
}

impl FilmData {
    /// The pelvic points and their film coordinates.
    fn pelvic(&self) -> (Vec<FilmPoint>, Vec<Vector2<f64>>) {
        self.points
            .iter()
            .zip(&self.measured)
            .filter(|(p, _)| p.is_pelvic())
            .map(|(p, m)| (*p, *m))
            .unzip()
    }
}

/// A film's fitted state: loads, placement, equilibrium.
#[derive(Debug, Clone)]
pub struct FilmState {
    /// Lateral force (N, ground Z) and frontal moment (N m, about ground X).
    pub loads: [f64; 3],
    /// The film's placement on the model's frontal plane.
    pub place: Placement,
    /// Equilibrium coordinates (warm start of the next solve).
    pub q: DVector<f64>,
}

/// Parameters per film.
const PER_FILM: usize = 6;

/// The placement of `film` on the model's pelvis at rest (2-D Procrustes)
/// and its RMS residual (m).
pub fn initial_placement(model: &BendModel, film: &FilmData) -> Result<(Placement, f64)> {
    let (pts, meas) = film.pelvic();
    let (proj, _) = model.project(&pts, model.rest.as_slice(), None)?;
    procrustes(&proj, &meas).ok_or_else(|| {
        Error::invalid(
            film.file.clone(),
            "its pelvic landmarks coincide: the film cannot be placed",
        )
    })
}

/// An orthonormal basis (columns) of the vectors of `n` entries summing
/// to zero (Helmert).
pub fn sum_zero_basis(n: usize) -> DMatrix<f64> {
    let mut b = DMatrix::zeros(n, n.saturating_sub(1));
    for k in 1..n {
        let s = ((k * (k + 1)) as f64).sqrt();
        for i in 0..k {
            b[(i, k - 1)] = 1.0 / s;
        }
        b[(k, k - 1)] = -(k as f64) / s;
    }
    b
}

/// What is estimated.
#[derive(Debug, Clone)]
pub struct Estimated {
    /// Indices (into the model's joints) of the estimated joints.
    pub joints: Vec<usize>,
    /// `log m = B x` for them.
    pub basis: DMatrix<f64>,
    /// The prior's rows `A` (residuals `A log m`; no rows: no prior).
    pub prior: DMatrix<f64>,
}

/// The prior rows on `n` log multipliers, cranial to caudal: each one's
/// `log m_j / sd` and each neighbour difference `/ step_sd`.
pub fn prior_rows(n: usize, sd: Option<f64>, step_sd: Option<f64>) -> DMatrix<f64> {
    let mut rows: Vec<Vec<f64>> = Vec::new();
    if let Some(sd) = sd {
        for j in 0..n {
            let mut r = vec![0.0; n];
            r[j] = 1.0 / sd;
            rows.push(r);
        }
    }
    if let Some(sd) = step_sd {
        for j in 1..n {
            let mut r = vec![0.0; n];
            r[j] = 1.0 / sd;
            r[j - 1] = -1.0 / sd;
            rows.push(r);
        }
    }
    DMatrix::from_fn(rows.len(), n, |i, j| rows[i][j])
}

/// A fit of some films: fixed multipliers, or estimated ones.
pub struct Problem<'a> {
    /// The bending model.
    pub model: &'a BendModel,
    /// The films fitted.
    pub films: Vec<&'a FilmData>,
    /// Multipliers of every joint (the estimated ones are replaced).
    pub fixed: Vec<f64>,
    /// The estimated joints and their parametrisation (`None`: only loads and placements are fitted).
    pub estimated: Option<Estimated>,
    /// Digitising noise (m).
    pub sigma: f64,
    ws: Workspace,
    warm: Vec<DVector<f64>>,
}

impl<'a> Problem<'a> {
    /// A problem on `films` with the joints' `fixed` multipliers, the `estimated` ones and noise `sigma` (m).
    pub fn new(
        model: &'a BendModel,
        films: Vec<&'a FilmData>,
        fixed: Vec<f64>,
        estimated: Option<Estimated>,
        sigma: f64,
    ) -> Problem<'a> {
        let warm = vec![model.rest.clone(); films.len()];
        Problem {
            model,
            films,
            fixed,
            estimated,
            sigma,
            ws: Workspace::new(&model.sys),
            warm,
        }
    }

    /// Number of stiffness coordinates.
    fn n_stiffness(&self) -> usize {
        self.estimated.as_ref().map_or(0, |e| e.basis.ncols())
    }

    /// Number of data residuals (2 per film point).
    pub fn n_data(&self) -> usize {
        self.films.iter().map(|f| 2 * f.points.len()).sum()
    }

    /// Every joint's multiplier at stiffness coordinates `x`.
    pub fn multipliers(&self, x: &[f64]) -> Vec<f64> {
        let mut m = self.fixed.clone();
        if let Some(e) = &self.estimated {
            let lm = &e.basis * DVector::from_column_slice(x);
            for (k, &j) in e.joints.iter().enumerate() {
                m[j] = lm[k].exp();
            }
        }
        m
    }

    /// The parameter vector of stiffness coordinates `x` and film states.
    pub fn pack(&self, x: &[f64], states: &[FilmState]) -> Vec<f64> {
        let mut p = x.to_vec();
        for s in states {
            p.extend_from_slice(&[
                s.loads[0],
                s.loads[1],
                s.loads[2],
                s.place.phi,
                s.place.t.x,
                s.place.t.y,
            ]);
        }
        p
    }

    /// The film states of parameter vector `p` (equilibria from the last evaluation).
    pub fn states(&self, p: &[f64]) -> Vec<FilmState> {
        let ns = self.n_stiffness();
        (0..self.films.len())
            .map(|f| {
                let o = ns + PER_FILM * f;
                FilmState {
                    loads: [p[o], p[o + 1], p[o + 2]],
                    place: Placement {
                        phi: p[o + 3],
                        t: Vector2::new(p[o + 4], p[o + 5]),
                    },
                    q: self.warm[f].clone(),
                }
            })
            .collect()
    }

    /// Set the warm starts (e.g. from an earlier fit of the same films).
    pub fn set_warm(&mut self, q: Vec<DVector<f64>>) {
        self.warm = q;
    }

    /// Residuals and (with `jac`) the Jacobian at `p`.
    pub fn eval(&mut self, p: &[f64], jac: bool) -> Result<(DVector<f64>, Option<DMatrix<f64>>)> {
        let ns = self.n_stiffness();
        let np = p.len();
        let m = self.multipliers(&p[..ns]);
        let sys = self.model.with_multipliers(&m)?;
        let n_prior = self.estimated.as_ref().map_or(0, |e| e.prior.nrows());
        let nd = self.n_data();
        let mut r = DVector::zeros(nd + n_prior);
        let mut jm = jac.then(|| DMatrix::zeros(nd + n_prior, np));
        let mut row = 0;
        for f in 0..self.films.len() {
            let film = self.films[f];
            let o = ns + PER_FILM * f;
            let loads = [p[o], p[o + 1], p[o + 2]];
            let place = Placement {
                phi: p[o + 3],
                t: Vector2::new(p[o + 4], p[o + 5]),
            };
            // The film's equilibrium and its sensitivities.
            let q = self
                .model
                .solve(
                    &sys,
                    film.level,
                    loads,
                    self.warm[f].as_slice(),
                    &mut self.ws,
                )
                .map_err(|e| {
                    Error::numerical(film.file.clone(), format!("no bent equilibrium: {e}"))
                })?;
            let dq = if jac {
                let (dm, df) =
                    self.model
                        .sensitivities(&sys, film.level, q.as_slice(), &mut self.ws)?;
                let mut dq = DMatrix::zeros(q.len(), ns + 3);
                if let Some(e) = &self.estimated {
                    let cols =
                        DMatrix::from_fn(q.len(), e.joints.len(), |i, k| dm[(i, e.joints[k])]);
                    dq.columns_mut(0, ns).copy_from(&(cols * &e.basis));
                }
                dq.columns_mut(ns, 3).copy_from(&df);
                Some(dq)
            } else {
                None
            };
            // Projected points on the film and their derivatives.
            let (proj, dproj) = self
                .model
                .project(&film.points, q.as_slice(), dq.as_ref())?;
            let rot = place.rotation();
            for (i, (mi, fi)) in proj.iter().zip(&film.measured).enumerate() {
                let e = (place.apply(mi) - fi) / self.sigma;
                r[row] = e.x;
                r[row + 1] = e.y;
                if let (Some(j), Some(d)) = (jm.as_mut(), dproj.as_ref()) {
                    for c in 0..ns + 3 {
                        let v = rot * Vector2::new(d[(2 * i, c)], d[(2 * i + 1, c)]) / self.sigma;
                        let col = if c < ns { c } else { o + (c - ns) };
                        j[(row, col)] = v.x;
                        j[(row + 1, col)] = v.y;
                    }
                    let dphi = place.d_phi(mi) / self.sigma;
                    j[(row, o + 3)] = dphi.x;
                    j[(row + 1, o + 3)] = dphi.y;
                    j[(row, o + 4)] = 1.0 / self.sigma;
                    j[(row + 1, o + 5)] = 1.0 / self.sigma;
                }
                row += 2;
            }
            self.warm[f] = q;
        }
        // The prior on the estimated joints' log multipliers.
        if let Some(e) = self.estimated.as_ref().filter(|e| e.prior.nrows() > 0) {
            let a = &e.prior * &e.basis;
            let rp = &a * DVector::from_column_slice(&p[..ns]);
            r.rows_mut(nd, n_prior).copy_from(&rp);
            if let Some(j) = jm.as_mut() {
                j.view_mut((nd, 0), (n_prior, ns)).copy_from(&a);
            }
        }
        Ok((r, jm))
    }

    /// Minimise from `p0` with Levenberg-Marquardt.
    pub fn minimise(&mut self, p0: &[f64]) -> Result<LmResult> {
        let ns = self.n_stiffness();
        let mut lo = vec![f64::NEG_INFINITY; p0.len()];
        let mut hi = vec![f64::INFINITY; p0.len()];
        // stiffness coordinates: every multiplier within exp(+-12)
        for k in 0..ns {
            lo[k] = -12.0;
            hi[k] = 12.0;
        }
        // films may be turned a few degrees, never half a turn
        for f in 0..self.films.len() {
            lo[ns + PER_FILM * f + 3] = -0.5;
            hi[ns + PER_FILM * f + 3] = 0.5;
            // no vertical load: the films show a lateral bend
            lo[ns + PER_FILM * f + 2] = 0.0;
            hi[ns + PER_FILM * f + 2] = 0.0;
        }
        let opts = LmOptions {
            max_iterations: 1000,
            gtol: 1e-10,
            xtol: 1e-10,
            ftol: 1e-12,
            ..LmOptions::default()
        };
        lm::minimize(|p, j| self.eval(p, j), p0, &lo, &hi, &opts)
    }
}

/// Fit each film's loads and placement with the multipliers fixed, from
/// its pelvic placement and no load.
pub fn fit_films(
    model: &BendModel,
    films: &[&FilmData],
    multipliers: &[f64],
    sigma: f64,
) -> Result<Vec<(FilmState, LmResult)>> {
    films
        .iter()
        .map(|film| {
            let (place, _) = initial_placement(model, film)?;
            let mut pb = Problem::new(model, vec![*film], multipliers.to_vec(), None, sigma);
            let start = FilmState {
                loads: [0.0; 3],
                place,
                q: model.rest.clone(),
            };
            let p0 = pb.pack(&[], &[start]);
            let res = pb.minimise(&p0)?;
            // the states at the optimum (the last evaluation was a trial)
            pb.eval(&res.x, false)?;
            let st = pb.states(&res.x).remove(0);
            Ok((st, res))
        })
        .collect()
}
