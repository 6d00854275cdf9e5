//! The bending model: the patient model's spine as a solver system with its
//! bushings as the only forces (no gravity, no muscles), the pelvis and the
//! sacrum welded, and a level (T1 on a full film) pulled sideways and
//! tilted by a lateral force along ground Z at its vertebral centre and a
//! frontal moment about ground X: the two loads of a planar constraint that
//! holds the level where the film shows it. The levels between are in
//! static equilibrium (the solver's Newton statics with its structured O(n)
//! tangent).
//!
//! Each estimated joint's rotational stiffness (`rx ry rz`) is the model's
//! times a multiplier `m_j`; the derivatives of the equilibrium with respect
//! to `log m_j` and to the two loads are implicit (`dq/dp = -T^-1 dtau/dp`
//! with the tangent the last Newton step factorised, [`System::tangent_solve`]),
//! those of the projected markers by six-direction dual numbers through the
//! kinematics.

use crate::anatomy::{bushing_level_name, MotionSegment};
use crate::error::{Error, Result};
use crate::landmarks::radiograph::FilmPoint;
use crate::landmarks::{Code, LandmarkId, Level};
use crate::osim::model::Model;
use crate::solver::kinematics;
use crate::solver::scalar::{d6_eps, D6};
use crate::solver::workspace::KinBuf;
use crate::solver::{
    BodyIndex, BushingIndex, BushingModel, Load, LoadFrame, LoadSet, StaticOptions, System,
    SystemSpec, Workspace,
};
use nalgebra::{DMatrix, DVector, Point3, Vector2, Vector3};
use std::collections::BTreeMap;

/// Projected film points and, when asked, their derivatives (two rows per
/// point, one column per parameter).
pub type Projected = (Vec<Vector2<f64>>, Option<DMatrix<f64>>);

/// One intervertebral joint whose stiffness can be estimated.
#[derive(Debug, Clone)]
pub struct Joint {
    /// `T7_T8`, `L5_S1`.
    pub name: String,
    /// The upper vertebra.
    pub upper: Level,
    /// The bushing's index in the system.
    pub bushing: BushingIndex,
    /// The model's stiffness `(rx, ry, rz, tx, ty, tz)` (N m/rad, N/m).
    pub k: [f64; 6],
    /// Column of its first stiffness parameter in [`System::dtau_dstiffness`].
    column: usize,
}

/// A marker: its body and its point in the body frame (m).
#[derive(Debug, Clone, Copy)]
struct Marker {
    body: BodyIndex,
    local: Vector3<f64>,
}

/// The patient model as a bending system (immutable).
#[derive(Debug, Clone)]
pub struct BendModel {
    /// Bushings only, gravity off, the model's stiffness.
    pub sys: System,
    /// Intervertebral joints, cranial to caudal.
    pub joints: Vec<Joint>,
    markers: BTreeMap<FilmPoint, Marker>,
    /// Each vertebra's body and the point loads act on (its vertebral
    /// centre: the middle of its endplate centres, else the body origin).
    centres: BTreeMap<Level, Marker>,
    /// The default (unbent) coordinates.
    pub rest: DVector<f64>,
}

/// The joint of a bushing named `<UP>_<LOW>_bushing` between two levels.
fn joint_levels(name: &str) -> Option<MotionSegment> {
    bushing_level_name(name).parse().ok()
}

impl BendModel {
    /// Build from a patient model (its file name for messages).
    pub fn new(model: &Model) -> Result<BendModel> {
        let file = model.file.display().to_string();
        let mut spec = SystemSpec::from_model(model)?;
        spec.gravity = Vector3::zeros();
        let sys = System::new(&spec)?;
        // The intervertebral joints: linear bushings between neighbouring levels.
        let mut joints = Vec::new();
        let mut column = 0;
        for (i, name) in sys.bushing_names().enumerate() {
            let model_i = sys.bushing_model(BushingIndex(i)).cloned();
            let np = model_i
                .as_ref()
                .map(|m| m.n_stiffness_params())
                .unwrap_or(0);
            if let Some(MotionSegment { upper, .. }) = joint_levels(name) {
                let Some(BushingModel::Linear {
                    rot_stiffness: r,
                    trans_stiffness: t,
                    ..
                }) = model_i
                else {
                    return Err(Error::invalid(
                        format!("{file}: bushing '{name}'"),
                        "not a linear BushingForce: flexibility scales each joint's linear rotational stiffness (give the model linear bushings, e.g. `osim-spine stiffness --table templates/stiffness-table5.1-uniform.toml`)",
                    ));
                };
                joints.push(Joint {
                    name: bushing_level_name(name).to_string(),
                    upper,
                    bushing: BushingIndex(i),
                    k: [r.x, r.y, r.z, t.x, t.y, t.z],
                    column,
                });
            }
            column += np;
        }
        joints.sort_by_key(|j| j.upper);
        if joints.is_empty() {
            return Err(Error::invalid(
                file,
                "no intervertebral bushing `<UP>_<LOW>_bushing` between neighbouring levels (T1..L5, S1): not a spine model of osim-spine",
            ));
        }
        // Markers the films can show, on bodies of the system.
        let mut markers = BTreeMap::new();
        for mk in &model.markers {
            let Some(p) = FilmPoint::parse(&mk.name) else {
                continue;
            };
            let (body, x) = model.marker_frame(mk)?;
            let Some(bi) = sys.body_index(&body) else {
                continue;
            };
            let local = (x * Point3::from(mk.location)).coords;
            markers.insert(p, Marker { body: bi, local });
        }
        let centres = vertebral_centres(&sys, &markers);
        let rest = sys.default_q();
        Ok(BendModel {
            sys,
            joints,
            markers,
            centres,
            rest,
        })
    }

    /// Whether the model has a marker for `p`.
    pub fn has(&self, p: FilmPoint) -> bool {
        self.markers.contains_key(&p)
    }

    /// The same model with the frontal positions at rest of some markers
    /// replaced (`(u, v)` in the model's frontal plane, m): each keeps its
    /// body and its depth (ground X) at rest. The load points stay.
    pub fn with_frontal_positions(&self, moved: &BTreeMap<FilmPoint, Vector2<f64>>) -> BendModel {
        let mut k64 = KinBuf::<f64>::new(&self.sys);
        k64.q.copy_from_slice(self.rest.as_slice());
        kinematics::forward(&self.sys, &mut k64);
        let mut out = self.clone();
        for (p, uv) in moved {
            let Some(m) = out.markers.get_mut(p) else {
                continue;
            };
            let x = &k64.x_gb[m.body.0];
            let g = x.point(&m.local);
            let target = Vector3::new(g.x, uv.y, -uv.x);
            m.local = x.r.transpose() * (target - x.p);
        }
        out
    }

    /// The vertebrae the model can load (cranial to caudal).
    pub fn levels(&self) -> Vec<Level> {
        self.centres.keys().copied().collect()
    }

    /// The system with joint `j`'s rotational stiffness times `m[j]`.
    pub fn with_multipliers(&self, m: &[f64]) -> Result<System> {
        let models = self
            .joints
            .iter()
            .zip(m)
            .map(|(j, mj)| {
                let mut k = j.k;
                for v in k.iter_mut().take(3) {
                    *v *= mj;
                }
                Ok((j.bushing, self.sys.linear_with_stiffness(j.bushing, k)?))
            })
            .collect::<Result<Vec<_>>>()?;
        self.sys.with_bushing_models(models)
    }

    /// The loads on `level`: lateral force `f[0]` (N, ground Z, at its
    /// centre) and frontal moment `f[1]` (N m, about ground X).
    pub fn loads(&self, level: Level, f: [f64; 3]) -> Result<LoadSet> {
        let c = self.centre(level)?;
        let body = self
            .sys
            .body_names()
            .nth(c.body.0)
            .unwrap_or("")
            .to_string();
        self.sys.prepare_loads(&[
            Load::Force {
                body: body.clone(),
                point_in_body: c.local,
                vec: Vector3::new(0.0, f[2], f[0]),
                frame: LoadFrame::Ground,
            },
            Load::Moment {
                body,
                vec: Vector3::new(f[1], 0.0, 0.0),
                frame: LoadFrame::Ground,
            },
        ])
    }

    fn centre(&self, level: Level) -> Result<Marker> {
        self.centres.get(&level).copied().ok_or_else(|| {
            Error::invalid(
                "flexibility",
                format!("the model has no vertebra {level} to load"),
            )
        })
    }

    /// Static equilibrium of `sys` (from [`BendModel::with_multipliers`])
    /// under the loads `f` on `level`, from `warm`; the tangent stays
    /// factorised in `ws` for [`BendModel::sensitivities`].
    pub fn solve(
        &self,
        sys: &System,
        level: Level,
        f: [f64; 3],
        warm: &[f64],
        ws: &mut Workspace,
    ) -> Result<DVector<f64>> {
        let loads = self.loads(level, f)?;
        let opts = StaticOptions::default();
        let sol = match sys.solve_static(&loads, warm, ws, &opts) {
            Ok(s) => s,
            Err(_) => sys.solve_static(&loads, self.rest.as_slice(), ws, &opts)?,
        };
        Ok(sol.q)
    }

    /// `dq/d log m_j` (one column per joint) and `dq/df` (force, moment) at
    /// the equilibrium `q` of `sys` just solved in `ws`.
    pub fn sensitivities(
        &self,
        sys: &System,
        level: Level,
        q: &[f64],
        ws: &mut Workspace,
    ) -> Result<(DMatrix<f64>, DMatrix<f64>)> {
        let n = sys.n_dofs();
        // dtau / d log m_j: the rotational stiffness columns times their values.
        let mut dk = DMatrix::zeros(n, sys.n_stiffness_params());
        sys.dtau_dstiffness(q, ws, &mut dk)?;
        let mut dm = DMatrix::zeros(n, self.joints.len());
        for (c, j) in self.joints.iter().enumerate() {
            let k = sys
                .bushing_model(j.bushing)
                .map(|b| b.stiffness_params())
                .unwrap_or_default();
            for d in 0..3 {
                let kd = k.get(d).copied().unwrap_or(0.0);
                for i in 0..n {
                    dm[(i, c)] -= kd * dk[(i, j.column + d)];
                }
            }
        }
        // dtau / df: the generalised force of a unit load.
        let mut df = DMatrix::zeros(n, 3);
        let zero = sys
            .static_residual(q, &self.loads(level, [0.0; 3])?, ws)?
            .to_vec();
        for (c, unit) in [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
            .into_iter()
            .enumerate()
        {
            let r = sys.static_residual(q, &self.loads(level, unit)?, ws)?;
            for i in 0..n {
                df[(i, c)] = -(r[i] - zero[i]);
            }
        }
        // dq/dp = -T^-1 dtau/dp (signs folded in above).
        for mat in [&mut dm, &mut df] {
            let mut col = vec![0.0; n];
            for c in 0..mat.ncols() {
                for i in 0..n {
                    col[i] = mat[(i, c)];
                }
                sys.tangent_solve(ws, &mut col)?;
                for i in 0..n {
                    mat[(i, c)] = col[i];
                }
            }
        }
        Ok((dm, df))
    }

    /// The frontal projections `(u, v) = (-z, y)` (m) of `points` at `q`,
    /// and, with `dq`, their derivatives along its columns (rows `2i, 2i+1`
    /// for point `i`).
    pub fn project(
        &self,
        points: &[FilmPoint],
        q: &[f64],
        dq: Option<&DMatrix<f64>>,
    ) -> Result<Projected> {
        let markers: Vec<Marker> = points
            .iter()
            .map(|p| {
                self.markers.get(p).copied().ok_or_else(|| {
                    Error::invalid("flexibility", format!("the model has no marker {p}"))
                })
            })
            .collect::<Result<_>>()?;
        let mut k64 = KinBuf::<f64>::new(&self.sys);
        k64.q.copy_from_slice(q);
        kinematics::forward(&self.sys, &mut k64);
        let values = markers
            .iter()
            .map(|m| {
                let g = k64.x_gb[m.body.0].point(&m.local);
                Vector2::new(-g.z, g.y)
            })
            .collect();
        let Some(dq) = dq else {
            return Ok((values, None));
        };
        let np = dq.ncols();
        let mut out = DMatrix::zeros(2 * markers.len(), np);
        let mut kd6 = KinBuf::<D6>::new(&self.sys);
        let mut start = 0;
        while start < np {
            let width = (np - start).min(6);
            for (i, qi) in q.iter().enumerate() {
                let mut e = nalgebra::SVector::<f64, 6>::zeros();
                for k in 0..width {
                    e[k] = dq[(i, start + k)];
                }
                kd6.q[i] = D6::new(*qi, num_dual::Derivative::some(e));
            }
            kinematics::forward(&self.sys, &mut kd6);
            for (r, m) in markers.iter().enumerate() {
                let g = kd6.x_gb[m.body.0].point(&m.local);
                let (dz, dy) = (d6_eps(&g.z), d6_eps(&g.y));
                for k in 0..width {
                    out[(2 * r, start + k)] = -dz[k];
                    out[(2 * r + 1, start + k)] = dy[k];
                }
            }
            start += width;
        }
        Ok((values, Some(out)))
    }

    /// The loaded level's frontal tilt (rad, about ground X, positive when
    /// its right end is lower, as [`crate::landmarks::metrics::tilts`]) and
    /// lateral position (m, ground Z) at `q`.
    pub fn level_pose(&self, level: Level, q: &[f64]) -> Result<(f64, f64)> {
        let c = self.centre(level)?;
        let mut k64 = KinBuf::<f64>::new(&self.sys);
        k64.q.copy_from_slice(q);
        kinematics::forward(&self.sys, &mut k64);
        let x = &k64.x_gb[c.body.0];
        let up = x.r * Vector3::y();
        Ok((up.z.atan2(up.y), x.point(&c.local).z))
    }
}

/// Each vertebra's load point: the middle of its `SEC` and `IEC` markers,
/// else its body origin.
fn vertebral_centres(
    sys: &System,
    markers: &BTreeMap<FilmPoint, Marker>,
) -> BTreeMap<Level, Marker> {
    let mut out = BTreeMap::new();
    for level in &Level::ALL[..17] {
        let Some(body) = sys.body_index(&level.body_name()) else {
            continue;
        };
        let get = |c: Code| {
            markers
                .get(&FilmPoint::Landmark(LandmarkId::new(*level, c)))
                .filter(|m| m.body == body)
                .map(|m| m.local)
        };
        let local = match (get(Code::SEC), get(Code::IEC)) {
            (Some(s), Some(i)) => (s + i) * 0.5,
            _ => Vector3::zeros(),
        };
        out.insert(*level, Marker { body, local });
    }
    out
}
