//! Procedural sacrum and pelvis.
//!
//! Pelvis frame (as the OpenSim gait models): origin at the midpoint of the
//! anterior superior iliac spines (ASIS), X anterior, Y superior, Z right;
//! at the default pose it is the standing pelvis (aligned with ground). All
//! pelvis landmarks are fractions of the inter-ASIS distance `W`
//! (`procedural_shape.toml`), the hip joint centres by Bell et al. 1990.
//!
//! The S1 superior endplate centre is placed from the hip axis by the
//! pelvic tilt and the pelvic radius (`alignment.toml`); the sacrum frame
//! has its origin there and the pelvis' axes (welded, no rotation), and its
//! S1 endplate is tilted by the sacral slope: normal
//! `(sin SS, cos SS, 0)` in the sacrum frame.
//!
//! Meshes: the sacrum is one swept shell (flat S1 endplate of the tabulated
//! width/depth, alae, tapering curved body to the apex); each hemipelvis is
//! an iliac blade swept along the crest (PSIS to ASIS) and two separate
//! straight shells (a pillar from below the ASIS to the acetabular region,
//! the superior pubic ramus to the symphysis).

use super::shapes::{straight, sweep, Station};
use super::tables::{PelvisShape, SacrumShape};
use crate::error::Result;
use crate::mesh::TriMesh;
use nalgebra::{Point3, Rotation3, Vector3};
use std::collections::BTreeMap;

/// Generated sacrum (sacrum frame) and pelvis (pelvis frame).
#[derive(Debug, Clone)]
pub struct PelvisGeometry {
    /// Sacrum mesh in the sacrum frame.
    pub sacrum: TriMesh,
    /// Pelvis mesh in the pelvis frame.
    pub pelvis: TriMesh,
    /// Sacrum landmarks in the sacrum frame.
    pub sacrum_landmarks: BTreeMap<String, Point3<f64>>,
    /// Pelvis landmarks in the pelvis frame (sided names end in `_r`/`_l`).
    pub pelvis_landmarks: BTreeMap<String, Point3<f64>>,
    /// Sacrum origin (S1 endplate centre) in the pelvis frame.
    pub sacrum_origin: Point3<f64>,
    /// S1 superior endplate unit normal in the sacrum frame.
    pub s1_normal: Vector3<f64>,
}

/// Inputs besides the shape rules.
pub struct PelvisInputs {
    /// Stature scale factor.
    pub k: f64,
    /// Inter-ASIS distance (m, already scaled).
    pub w: f64,
    /// S1 endplate width (m, scaled).
    pub s1_width: f64,
    /// S1 endplate depth (m, scaled).
    pub s1_depth: f64,
    /// Sacral slope (rad).
    pub sacral_slope: f64,
    /// Pelvic tilt (rad).
    pub pelvic_tilt: f64,
    /// Pelvic radius (m, scaled).
    pub pelvic_radius: f64,
}

fn lerp_profile(knots: &[(f64, f64, f64)], s: f64) -> (f64, f64) {
    for w in knots.windows(2) {
        let (s0, a0, b0) = w[0];
        let (s1, a1, b1) = w[1];
        if s <= s1 {
            let u = if s1 > s0 { (s - s0) / (s1 - s0) } else { 0.0 };
            return (a0 + (a1 - a0) * u, b0 + (b1 - b0) * u);
        }
    }
    knots.last().map(|k| (k.1, k.2)).unwrap_or((0.0, 0.0))
}

/// Generate sacrum and pelvis.
pub(crate) fn generate(
    sac: &SacrumShape,
    pel: &PelvisShape,
    inp: &PelvisInputs,
) -> Result<PelvisGeometry> {
    let w = inp.w;
    let ss = inp.sacral_slope;
    // The S1 endplate centre from the hip axis (pelvic tilt and radius),
    // its normal tilted by the sacral slope.
    let hip_mid = Point3::new(-pel.hjc_posterior * w, -pel.hjc_inferior * w, 0.0);
    let pt = inp.pelvic_tilt;
    let sacrum_origin = hip_mid + Vector3::new(-pt.sin(), pt.cos(), 0.0) * inp.pelvic_radius;
    let s1_normal = Vector3::new(ss.sin(), ss.cos(), 0.0);
    // The sacrum: swept from the S1 endplate along a curve bending
    // anteriorly; its dorsal and lateral landmarks.
    let curve = SacrumCurve::new(sac, inp, s1_normal);
    let sacrum = curve.mesh(sac)?;
    let sacrum_landmarks = curve.landmarks(inp.k);
    // The pelvis: each hemipelvis's shells and landmarks.
    let mut pelvis_landmarks = BTreeMap::new();
    let mut shells = Vec::new();
    for (side, sz) in [("r", 1.0), ("l", -1.0)] {
        hemipelvis(pel, inp, side, sz, &mut shells, &mut pelvis_landmarks)?;
    }
    let refs: Vec<&TriMesh> = shells.iter().collect();
    let pelvis = TriMesh::merge(&refs)?;
    Ok(PelvisGeometry {
        sacrum,
        pelvis,
        sacrum_landmarks,
        pelvis_landmarks,
        sacrum_origin,
        s1_normal,
    })
}

/// The sacrum's centre line (from the S1 endplate centre, bending
/// anteriorly at a constant rate) and its width/thickness profile.
struct SacrumCurve {
    length: f64,
    kappa: f64,
    /// Direction at the S1 endplate (into the sacrum).
    dir0: Vector3<f64>,
    /// (s, width, thickness) knots of the profile along the curve.
    knots: [(f64, f64, f64); 5],
}

impl SacrumCurve {
    fn new(sac: &SacrumShape, inp: &PelvisInputs, s1_normal: Vector3<f64>) -> Self {
        let k = inp.k;
        let alar = sac.alar_width_m * k;
        let thick = sac.thickness_m * k;
        SacrumCurve {
            length: sac.length_m * k,
            kappa: sac.curvature_deg.to_radians(),
            dir0: -s1_normal,
            knots: [
                (0.0, inp.s1_width, inp.s1_depth),
                (0.06, 1.05 * inp.s1_width, inp.s1_depth),
                (0.18, alar, 1.1 * thick.max(0.8 * inp.s1_depth)),
                (0.45, 0.7 * alar, thick),
                (1.0, sac.tip_width_m * k, sac.tip_thickness_m * k),
            ],
        }
    }

    /// Tangent at fraction `s` of the length.
    fn dir_at(&self, s: f64) -> Vector3<f64> {
        Rotation3::from_axis_angle(&Vector3::z_axis(), self.kappa * s) * self.dir0
    }

    /// Centre at fraction `s` (the tangent integrated by the midpoint rule,
    /// fine steps).
    fn centre_at(&self, s: f64) -> Point3<f64> {
        let steps = 200;
        let mut p = Point3::origin();
        for i in 0..steps {
            let u = s * (i as f64 + 0.5) / steps as f64;
            p += self.dir_at(u) * (self.length * s / steps as f64);
        }
        p
    }

    /// Dorsal direction at `s`: perpendicular to the tangent in the
    /// sagittal plane, posterior.
    fn dorsal(&self, s: f64) -> Vector3<f64> {
        let t = self.dir_at(s);
        let b = Vector3::new(-t.y, t.x, 0.0);
        if b.x < 0.0 {
            b
        } else {
            -b
        }
    }

    /// The swept shell: four stations over the alae, then `rings` to the apex.
    fn mesh(&self, sac: &SacrumShape) -> Result<TriMesh> {
        let n = sac.rings.max(6);
        let mut s_values: Vec<f64> = vec![0.0, 0.06, 0.12, 0.18];
        for i in 1..n {
            let s = 0.18 + 0.82 * i as f64 / (n - 1) as f64;
            s_values.push(s);
        }
        let stations: Vec<Station> = s_values
            .iter()
            .map(|&s| {
                let (wd, th) = lerp_profile(&self.knots, s);
                Station {
                    centre: self.centre_at(s),
                    up: Vector3::z(),
                    half_w: 0.5 * th,
                    half_h: 0.5 * wd,
                    tangent: Some(self.dir_at(s)),
                }
            })
            .collect();
        sweep(&stations, sac.around.max(8), "procedural sacrum")
    }

    /// Dorsal landmarks at four heights and a lateral pair, on the dorsal
    /// surface (2 mm out), and the S1 endplate centre.
    fn landmarks(&self, k: f64) -> BTreeMap<String, Point3<f64>> {
        let mut sl = BTreeMap::new();
        let on_back = |s: f64| {
            let (_, th) = lerp_profile(&self.knots, s);
            self.centre_at(s) + self.dorsal(s) * (0.5 * th + 0.002)
        };
        for (i, s) in [0.1, 0.3, 0.5, 0.7].iter().enumerate() {
            let c = on_back(*s);
            for (side, sz) in [("r", 1.0), ("l", -1.0)] {
                sl.insert(
                    format!("sacrum_dorsal_{}_{side}", i + 1),
                    c + Vector3::z() * (sz * 0.012 * k),
                );
            }
        }
        let c = on_back(0.5);
        for (side, sz) in [("r", 1.0), ("l", -1.0)] {
            sl.insert(
                format!("sacrum_lateral_{side}"),
                c + Vector3::z() * (sz * 0.028 * k),
            );
        }
        sl.insert("superior_centre".into(), Point3::origin());
        sl
    }
}

/// One hemipelvis (`side` `r`/`l`, `sz` its sign on Z): the iliac blade
/// swept along the crest, the pillar to the acetabulum and the superior
/// pubic ramus, as shells; its landmarks into `pl`.
fn hemipelvis(
    pel: &PelvisShape,
    inp: &PelvisInputs,
    side: &str,
    sz: f64,
    shells: &mut Vec<TriMesh>,
    pl: &mut BTreeMap<String, Point3<f64>>,
) -> Result<()> {
    let (w, k) = (inp.w, inp.k);
    let p3 = |a: &[f64; 3], side: f64| Point3::new(a[0] * w, a[1] * w, side * a[2] * w);
    let blade = pel.ilium_blade_height * w;
    let t_il = pel.ilium_thickness_m * k;
    let r_ram = 0.5 * pel.ramus_diameter_m * k;
    let asis = Point3::new(0.0, 0.0, sz * 0.5 * w);
    let crest = [
        (p3(&pel.psis, sz), 0.6),
        (p3(&pel.iliac_crest_posterior, sz), 1.0),
        (p3(&pel.iliac_crest_mid, sz), 1.0),
        (p3(&pel.iliac_crest_anterior, sz), 0.8),
        (asis, 0.3),
    ];
    let st: Vec<Station> = crest
        .iter()
        .map(|(p, f)| Station {
            centre: p - Vector3::y() * (0.5 * f * blade),
            up: Vector3::y(),
            half_w: 0.5 * t_il,
            half_h: 0.5 * f * blade,
            tangent: None,
        })
        .collect();
    shells.push(sweep(&st, pel.around.max(8), "procedural pelvis (ilium)")?);
    // the hip joint centre (Bell et al. 1990)
    let h = Point3::new(
        -pel.hjc_posterior * w,
        -pel.hjc_inferior * w,
        sz * pel.hjc_lateral * w,
    );
    let blade_bottom_asis = -0.3 * blade;
    let a0 = Point3::new(0.0, blade_bottom_asis - r_ram - 0.004 * k, sz * 0.47 * w);
    let acet = Point3::new(h.x + 0.01 * k, h.y + 0.01 * k, sz * (h.z.abs() - 0.02 * k));
    // pillar from below the ASIS to the acetabulum, then a straight
    // superior pubic ramus to the symphysis, starting beyond the
    // pillar's end cap (straight tubes, apart: no intersections)
    let r_acet = 1.4 * r_ram;
    shells.push(sweep(
        &straight(a0, acet, Vector3::x(), (r_ram, r_ram), (r_acet, r_acet), 3),
        pel.around.max(8),
        "procedural pelvis (pillar)",
    )?);
    // stop short of the midline so the two rami stay apart
    let mut sym = p3(&pel.pubic_symphysis, sz);
    sym.z = sz * sym.z.abs().max(r_ram + 0.002 * k);
    let dir = (sym - acet)
        .try_normalize(1e-9)
        .unwrap_or_else(|| Vector3::z() * -sz);
    let r0 = acet + dir * (r_acet + r_ram + 0.002 * k);
    shells.push(sweep(
        &straight(r0, sym, Vector3::x(), (r_ram, r_ram), (r_ram, r_ram), 3),
        pel.around.max(8),
        "procedural pelvis (ramus)",
    )?);
    pl.insert(format!("hip_{side}"), h);
    pl.insert(format!("asis_{side}"), asis);
    pl.insert(format!("psis_{side}"), p3(&pel.psis, sz));
    pl.insert(
        format!("iliac_crest_posterior_{side}"),
        p3(&pel.iliac_crest_posterior, sz),
    );
    pl.insert(
        format!("iliac_crest_mid_{side}"),
        p3(&pel.iliac_crest_mid, sz),
    );
    pl.insert(
        format!("pelvic_brim_{side}"),
        p3(&pel.pelvic_brim, sz) + Vector3::y() * (r_ram + 0.002 * k),
    );
    pl.insert(
        format!("lesser_trochanter_proxy_{side}"),
        p3(&pel.lesser_trochanter_proxy, sz),
    );
    Ok(())
}
