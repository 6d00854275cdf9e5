//! Outputs of a solve: body poses, bushing deflections and OpenSim-style
//! record values, an OpenSim storage (.sto, version 1) of coordinates, and a
//! JSON document with poses and bushing records.

use super::forces;
use super::kinematics;
use super::scalar::body_xyz;
use super::system::System;
use super::workspace::Workspace;
use crate::error::Result;
use crate::util::fmt_f64;
use nalgebra::{Matrix3, Vector3};
use num_dual::Dual64;
use serde::Serialize;
use std::collections::BTreeMap;

/// Pose of a body in ground.
#[derive(Debug, Clone, Serialize)]
pub struct BodyPose {
    /// Origin of the body frame in ground (m, ground axes).
    pub origin_in_ground: [f64; 3],
    /// Rotation from body to ground axes (`R_GB`), row by row.
    pub r_ground_body_rowmajor: [[f64; 3]; 3],
    /// Body-fixed X-Y-Z angles of the body frame in ground (rad).
    pub body_fixed_xyz_rad: [f64; 3],
    /// Centre of mass in ground (m, ground axes).
    pub com_in_ground: [f64; 3],
}

/// A bushing's state.
#[derive(Debug, Clone, Serialize)]
pub struct BushingRecord {
    /// rx, ry, rz (body-fixed X-Y-Z angles of frame 2 in frame 1), tx, ty, tz.
    pub deflection_rx_ry_rz_tx_ty_tz: [f64; 6],
    /// OpenSim `getRecordValues`: force and torque on frame 1's body (about
    /// its origin, ground axes), then on frame 2's body.
    pub record_values: [f64; 12],
    /// Stored energy (1/2 sum K q^2 for linear bushings).
    pub potential_energy: f64,
}

fn arr(v: &Vector3<f64>) -> [f64; 3] {
    [v.x, v.y, v.z]
}

fn rows(m: &Matrix3<f64>) -> [[f64; 3]; 3] {
    [
        [m[(0, 0)], m[(0, 1)], m[(0, 2)]],
        [m[(1, 0)], m[(1, 1)], m[(1, 2)]],
        [m[(2, 0)], m[(2, 1)], m[(2, 2)]],
    ]
}

impl System {
    /// Body poses at q (by body name, sorted).
    pub fn body_poses(&self, q: &[f64], ws: &mut Workspace) -> Result<BTreeMap<String, BodyPose>> {
        self.check_workspace(ws)?;
        self.check_q(q)?;
        ws.k64.q.copy_from_slice(q);
        kinematics::forward(self, &mut ws.k64);
        Ok(self
            .bodies
            .iter()
            .enumerate()
            .map(|(bi, b)| {
                let x = ws.k64.x_gb[bi];
                (
                    b.name.clone(),
                    BodyPose {
                        origin_in_ground: arr(&x.p),
                        r_ground_body_rowmajor: rows(&x.r),
                        body_fixed_xyz_rad: arr(&body_xyz(&x.r)),
                        com_in_ground: arr(&x.point(&b.com)),
                    },
                )
            })
            .collect())
    }

    /// Bushing deflections and record values at (q, u) (u = None: at rest).
    pub fn bushing_records(
        &self,
        q: &[f64],
        u: Option<&[f64]>,
        ws: &mut Workspace,
    ) -> Result<BTreeMap<String, BushingRecord>> {
        self.check_workspace(ws)?;
        self.check_q(q)?;
        // deflection rates from the coordinate rates of the speeds
        let mut qdot = vec![0.0; q.len()];
        if let Some(u) = u {
            self.qdot(q, u, &mut qdot)?;
        }
        for i in 0..q.len() {
            ws.kd1.q[i] = Dual64::new(q[i], qdot[i]);
        }
        kinematics::forward(self, &mut ws.kd1);
        let mut out = BTreeMap::new();
        for (i, b) in self.bushings.iter().enumerate() {
            let (x1d, x2d, qrd, qtd) = forces::bushing_deflection(b, &ws.kd1);
            if qrd.y.re.abs() >= forces::GIMBAL_LIMIT {
                return Err(forces::GimbalLock {
                    bushing: i,
                    angle: qrd.y.re,
                }
                .to_error(self));
            }
            let (x1, x2) = (x1d.re(), x2d.re());
            let qr = qrd.map(|v| v.re);
            let qt = qtd.map(|v| v.re);
            let q6 = [qr.x, qr.y, qr.z, qt.x, qt.y, qt.z];
            let g = b.law.g(&q6);
            let fr = Vector3::new(
                -(g[0] + b.c[0] * qrd.x.eps),
                -(g[1] + b.c[1] * qrd.y.eps),
                -(g[2] + b.c[2] * qrd.z.eps),
            );
            let ft = Vector3::new(
                -(g[3] + b.c[3] * qtd.x.eps),
                -(g[4] + b.c[4] * qtd.y.eps),
                -(g[5] + b.c[5] * qtd.z.eps),
            );
            let m2 = x2.r * forces::n_transpose_mul(&qr, &fr);
            let f2 = x1.r * ft;
            let origin = |body: Option<super::BodyIndex>| {
                body.map(|bi| ws.kd1.x_gb[bi.0].p.map(|v| v.re))
                    .unwrap_or_else(Vector3::zeros)
            };
            let o1 = origin(b.body1);
            let o2 = origin(b.body2);
            let t2 = m2 + (x2.p - o2).cross(&f2);
            let t1 = -m2 + (x2.p - o1).cross(&(-f2));
            let mut rec = [0.0; 12];
            rec[0..3].copy_from_slice(&arr(&(-f2)));
            rec[3..6].copy_from_slice(&arr(&t1));
            rec[6..9].copy_from_slice(&arr(&f2));
            rec[9..12].copy_from_slice(&arr(&t2));
            let pe = b.law.potential(&q6);
            out.insert(
                b.name.clone(),
                BushingRecord {
                    deflection_rx_ry_rz_tx_ty_tz: [qr.x, qr.y, qr.z, qt.x, qt.y, qt.z],
                    record_values: rec,
                    potential_energy: pe,
                },
            );
        }
        Ok(out)
    }
}

/// OpenSim storage file (version 1, radians) with a time column and one
/// column per coordinate (all coordinates of the model, locked ones too).
pub fn sto_string(name: &str, columns: &[String], rows: &[(f64, Vec<f64>)]) -> String {
    let mut s = String::new();
    s.push_str(name);
    s.push('\n');
    s.push_str("version=1\n");
    s.push_str(&format!("nRows={}\n", rows.len()));
    s.push_str(&format!("nColumns={}\n", columns.len() + 1));
    s.push_str("inDegrees=no\n");
    s.push_str("endheader\n");
    s.push_str("time");
    for c in columns {
        s.push('\t');
        s.push_str(c);
    }
    s.push('\n');
    for (t, vals) in rows {
        s.push_str(&fmt_f64(*t));
        for v in vals {
            s.push('\t');
            s.push_str(&fmt_f64(*v));
        }
        s.push('\n');
    }
    s
}
