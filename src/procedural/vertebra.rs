//! One procedural vertebra (T1..L5) in its OpenSim body frame: origin at the
//! centre of the disc below, X anterior, Y cranial, Z right.
//!
//! Shells (each closed, outward, disjoint from the others by `gap_m`):
//! * the vertebral body: a generalised cylinder whose cross-section is a
//!   half ellipse anteriorly and a flatter superellipse posteriorly, of the
//!   tabulated endplate width (Z extent) and mid-sagittal depth (X extent),
//!   interpolated from the inferior to the superior endplate, narrowed at
//!   mid-height by the waist rule; the inferior endplate is the plane
//!   `y = disc_below / 2`, the superior endplate is tilted by the wedge
//!   angle `atan((h_ant - h_post) / depth)` so that the anterior and
//!   posterior heights are the tabulated ones;
//! * two pedicles (elliptic tubes of the tabulated height and width) from
//!   behind the posterior wall, beside a canal of the tabulated width;
//! * the lamina arch (a tube along a half-ellipse behind the canal of the
//!   tabulated depth);
//! * the spinous process (tapered tube of the tabulated length, inclined
//!   by region);
//! * two transverse processes (tip-to-tip width as tabulated);
//! * superior and inferior articular processes on both sides.

use super::shapes::{straight, sweep, tube, Station};
use super::tables::BodyShape;
use super::tables::PosteriorShape;
use crate::anatomy::LevelDimensions;
use crate::error::Result;
use crate::landmarks::Level;
use crate::mesh::TriMesh;
use nalgebra::{Point3, Vector3};
use std::collections::BTreeMap;

/// Dimensions of one level after stature scaling (metres, radians).
#[derive(Debug, Clone, PartialEq)]
pub struct LevelShape {
    /// The level these dimensions are of.
    pub level: Level,
    /// Superior endplate width, left-right (m).
    pub sup_width: f64,
    /// Superior endplate depth, anterior-posterior (m).
    pub sup_depth: f64,
    /// Inferior endplate width, left-right (m).
    pub inf_width: f64,
    /// Inferior endplate depth, anterior-posterior (m).
    pub inf_depth: f64,
    /// Anterior vertebral body height (m).
    pub ant_height: f64,
    /// Posterior vertebral body height (m).
    pub post_height: f64,
    /// Pedicle height (m).
    pub pedicle_height: f64,
    /// Pedicle width (m).
    pub pedicle_width: f64,
    /// Spinal canal width, left-right (m).
    pub canal_width: f64,
    /// Spinal canal depth, anterior-posterior (m).
    pub canal_depth: f64,
    /// Spinous process length (m).
    pub spinous_length: f64,
    /// Tip-to-tip width of the transverse processes (m).
    pub transverse_width: f64,
    /// Disc below this level (mean height).
    pub disc_below: f64,
}

impl LevelShape {
    /// Scale a table row by `k` (stature rule).
    pub fn from_table(d: &LevelDimensions, k: f64) -> LevelShape {
        LevelShape {
            level: d.level,
            sup_width: k * d.sup_ep_width.mean,
            sup_depth: k * d.sup_ep_depth.mean,
            inf_width: k * d.inf_ep_width.mean,
            inf_depth: k * d.inf_ep_depth.mean,
            ant_height: k * d.ant_height.mean,
            post_height: k * d.post_height.mean,
            pedicle_height: k * d.pedicle_height.mean,
            pedicle_width: k * d.pedicle_width.mean,
            canal_width: k * d.canal_width.mean,
            canal_depth: k * d.canal_depth.mean,
            spinous_length: k * d.spinous_length.mean,
            transverse_width: k * d.transverse_width.mean,
            disc_below: k * d.disc_height.mean,
        }
    }
    /// Mean body height.
    pub fn height(&self) -> f64 {
        0.5 * (self.ant_height + self.post_height)
    }
    /// Mean mid-sagittal depth.
    pub fn depth(&self) -> f64 {
        0.5 * (self.sup_depth + self.inf_depth)
    }
    /// Lordotic wedge of the body (rad; positive = anterior taller).
    pub fn wedge(&self) -> f64 {
        ((self.ant_height - self.post_height) / self.depth()).atan()
    }
}

/// A generated vertebra in its body frame.
#[derive(Debug, Clone)]
pub struct VertebraGeometry {
    /// The level of the vertebra.
    pub level: Level,
    /// The vertebral body shell alone.
    pub body: TriMesh,
    /// Posterior element shells (pedicles, lamina, processes, facets).
    pub posterior: Vec<TriMesh>,
    /// Named landmarks (muscle attachments, endplate centres), body frame;
    /// sided ones end in `_r` / `_l`.
    pub landmarks: BTreeMap<String, Point3<f64>>,
    /// Superior endplate centre (body frame).
    pub superior_centre: Point3<f64>,
    /// Superior endplate outward unit normal (body frame).
    pub superior_normal: Vector3<f64>,
    /// Inferior endplate centre (normal is -Y).
    pub inferior_centre: Point3<f64>,
}

impl VertebraGeometry {
    /// All shells merged into one mesh (body first).
    pub fn mesh(&self) -> Result<TriMesh> {
        let mut all: Vec<&TriMesh> = vec![&self.body];
        all.extend(self.posterior.iter());
        TriMesh::merge(&all)
    }
}

/// Cross-section point of the body at angle `phi` (0 = anterior, pi/2 =
/// right), for half-depth `a`, half-width `b`: half ellipse anteriorly, a
/// superellipse of exponent `n` posteriorly. Returns (x, z).
fn section(phi: f64, a: f64, b: f64, n: f64) -> (f64, f64) {
    let (s, c) = phi.sin_cos();
    if c >= 0.0 {
        (a * c, b * s)
    } else {
        let e = 2.0 / n;
        (-a * (-c).powf(e), b * s.signum() * s.abs().powf(e))
    }
}

/// X of the posterior body wall at lateral position `z` (the least
/// posterior point of the inferior and superior outlines there, before the
/// waist), for the clearance of the pedicles.
fn posterior_wall_x(z: f64, a: f64, b: f64, n: f64) -> f64 {
    // superellipse |x/a|^n + |z/b|^n = 1 on the posterior side
    let r = (z.abs() / b).min(1.0);
    -a * (1.0 - r.powf(n)).max(0.0).powf(1.0 / n)
}

/// Generate the vertebra of `s` (scaled dimensions). `level_index` picks the
/// per-level angles of the shape rules (0 = T1 .. 16 = L5).
pub(crate) fn generate(
    s: &LevelShape,
    body_rules: &BodyShape,
    post: &PosteriorShape,
) -> Result<VertebraGeometry> {
    let what = format!("procedural vertebra {}", s.level);
    // The vertebral body and its endplates.
    let y0 = 0.5 * s.disc_below;
    let h = s.height();
    let tan_w = (s.ant_height - s.post_height) / s.depth();
    let body = body_shell(s, body_rules, &what)?;
    let inferior_centre = Point3::new(0.0, y0, 0.0);
    let superior_centre = Point3::new(0.0, y0 + h, 0.0);
    let superior_normal = Vector3::new(-tan_w, 1.0, 0.0).normalize();
    // The posterior elements, each clear of the body and of the others.
    let mut arch = Arch::new(s, body_rules, post, what);
    arch.pedicles()?;
    arch.lamina()?;
    arch.spinous_process()?;
    let (tp_top, tp_bottom) = arch.transverse_processes()?;
    arch.articular_processes(tp_top, tp_bottom)?;
    let Arch {
        shells: posterior,
        landmarks: mut lm,
        ..
    } = arch;
    lm.insert("superior_centre".into(), superior_centre);
    lm.insert("inferior_centre".into(), inferior_centre);
    Ok(VertebraGeometry {
        level: s.level,
        body,
        posterior,
        landmarks: lm,
        superior_centre,
        superior_normal,
        inferior_centre,
    })
}

/// The vertebral body: rings from the inferior endplate (`y = disc/2`) to
/// the superior one (tilted by the wedge), narrowed by the waist rule.
fn body_shell(s: &LevelShape, body_rules: &BodyShape, what: &str) -> Result<TriMesh> {
    let y0 = 0.5 * s.disc_below;
    let h = s.height();
    let tan_w = (s.ant_height - s.post_height) / s.depth();
    let n_exp = body_rules.posterior_exponent;
    let nr = body_rules.rings;
    let na = body_rules.around;
    let mut rings = Vec::with_capacity(nr);
    for r in 0..nr {
        let t = r as f64 / (nr - 1) as f64;
        let waist = 1.0 - body_rules.waist * (std::f64::consts::PI * t).sin();
        let a = 0.5 * waist * (s.inf_depth + (s.sup_depth - s.inf_depth) * t);
        let b = 0.5 * waist * (s.inf_width + (s.sup_width - s.inf_width) * t);
        let ring: Vec<Point3<f64>> = (0..na)
            .map(|k| {
                let phi = std::f64::consts::TAU * k as f64 / na as f64;
                let (x, z) = section(phi, a, b, n_exp);
                // height at this x: posterior height at x=-d/2, anterior at +d/2
                let y = y0 + t * (h + x * tan_w);
                Point3::new(x, y, z)
            })
            .collect();
        rings.push(ring);
    }
    tube(&rings, what)
}

/// The posterior elements being built: their placement (from the scaled
/// dimensions and the shape rules), shells and landmarks.
struct Arch<'a> {
    s: &'a LevelShape,
    body_rules: &'a BodyShape,
    post: &'a PosteriorShape,
    what: String,
    /// Per-level index of the shape rules' angles (0 = T1 .. 16 = L5).
    li: usize,
    /// Inferior endplate height, body height.
    y0: f64,
    h: f64,
    gap: f64,
    /// Lateral position of the pedicle axes.
    zp: f64,
    /// Pedicle width and height; pedicle axis height.
    pw: f64,
    ph: f64,
    y_p: f64,
    /// X of the posterior body wall behind the pedicles (less the gap).
    x_wall: f64,
    /// X of the back of the canal; of the pedicles' posterior end.
    x_canal_back: f64,
    x_pe: f64,
    /// Lamina thickness, height, centre height and centre X.
    t_l: f64,
    h_l: f64,
    y_l: f64,
    x_c: f64,
    /// Spinous process thickness.
    t_s: f64,
    shells: Vec<TriMesh>,
    landmarks: BTreeMap<String, Point3<f64>>,
}

impl<'a> Arch<'a> {
    fn new(
        s: &'a LevelShape,
        body_rules: &'a BodyShape,
        post: &'a PosteriorShape,
        what: String,
    ) -> Self {
        let y0 = 0.5 * s.disc_below;
        let h = s.height();
        let gap = post.gap_m;
        let a_body = 0.5 * s.depth().max(s.inf_depth).max(s.sup_depth);
        let b_body = 0.5 * s.inf_width.min(s.sup_width);
        let zp = 0.5 * (s.canal_width + s.pedicle_width);
        let pw = s.pedicle_width;
        // the pedicle starts behind the most posterior wall point over its z range
        let z_inner = (zp - 0.5 * pw).max(0.0);
        let x_wall = posterior_wall_x(z_inner, a_body, b_body, body_rules.posterior_exponent) - gap;
        let x_canal_front = -a_body;
        let x_canal_back = x_canal_front - s.canal_depth;
        let x_pe = x_canal_front - post.pedicle_length_frac_canal_depth * s.canal_depth;
        let t_l = post.lamina_thickness_frac_canal_depth * s.canal_depth;
        Arch {
            s,
            body_rules,
            post,
            what,
            li: s.level.index().min(16),
            y0,
            h,
            gap,
            zp,
            pw,
            ph: s.pedicle_height,
            y_p: y0 + post.pedicle_centre_frac_body * h,
            x_wall,
            x_canal_back,
            x_pe,
            t_l,
            h_l: post.lamina_height_frac_body * h,
            y_l: y0 + post.lamina_centre_frac_body * h,
            x_c: x_canal_back - 0.5 * t_l,
            t_s: post.spinous_thickness_frac_canal_depth * s.canal_depth,
            shells: Vec::new(),
            landmarks: BTreeMap::new(),
        }
    }

    /// A shell swept through `stations`.
    fn push(&mut self, stations: &[Station]) -> Result<()> {
        let m = sweep(stations, self.post.around, &self.what)?;
        self.shells.push(m);
        Ok(())
    }

    /// Two pedicles: elliptic tubes from behind the posterior wall beside
    /// the canal.
    fn pedicles(&mut self) -> Result<()> {
        let (zp, pw, ph, y_p) = (self.zp, self.pw, self.ph, self.y_p);
        for (side, sz) in [("r", 1.0), ("l", -1.0)] {
            let a = Point3::new(self.x_wall.max(self.x_pe + 1e-3), y_p, sz * zp);
            let b = Point3::new(self.x_pe, y_p, sz * zp);
            self.push(&straight(
                a,
                b,
                Vector3::y(),
                (0.5 * pw, 0.5 * ph),
                (0.5 * pw, 0.5 * ph),
                2,
            ))?;
            self.landmarks.insert(
                format!("pedicle_{side}"),
                Point3::new(0.5 * (a.x + b.x), y_p, sz * zp),
            );
        }
        Ok(())
    }

    /// The lamina: a half-ellipse from the right pedicle end, behind the
    /// canal, to the left one.
    fn lamina(&mut self) -> Result<()> {
        let (t_l, h_l, y_l, x_c, zp) = (self.t_l, self.h_l, self.y_l, self.x_c, self.zp);
        let x_start = self.x_pe - self.gap;
        let n_lam = 13;
        let lam: Vec<Station> = (0..n_lam)
            .map(|i| {
                let u = i as f64 / (n_lam - 1) as f64;
                let ang = std::f64::consts::PI * u;
                Station {
                    centre: Point3::new(x_start - (x_start - x_c) * ang.sin(), y_l, zp * ang.cos()),
                    up: Vector3::y(),
                    half_w: 0.5 * t_l,
                    half_h: 0.5 * h_l,
                    tangent: Some(Vector3::new(
                        -(x_start - x_c) * ang.cos(),
                        0.0,
                        -zp * ang.sin(),
                    )),
                }
            })
            .collect();
        self.push(&lam)?;
        self.landmarks.insert(
            "lamina".into(),
            Point3::new(x_c - 0.5 * t_l, y_l + 0.25 * h_l, 0.0),
        );
        Ok(())
    }

    /// The spinous process: a tapered tube of the tabulated length,
    /// inclined by region.
    fn spinous_process(&mut self) -> Result<()> {
        let (s, post, h) = (self.s, self.post, self.h);
        let alpha = post.spinous_inclination_deg[self.li].to_radians();
        let dir = Vector3::new(-alpha.cos(), -alpha.sin(), 0.0);
        let hs0 = post.spinous_root_height_frac_body * h;
        let hs1 = post.spinous_tip_height_frac_body * h;
        let root = Point3::new(
            self.x_canal_back - self.t_l - self.gap - 0.5 * hs0 * alpha.sin(),
            self.y_l,
            0.0,
        );
        let len = (s.spinous_length - (self.x_canal_back - root.x)).max(0.3 * s.spinous_length);
        let tip = root + dir * len;
        let up = Vector3::new(-alpha.sin(), alpha.cos(), 0.0);
        self.push(&straight(
            root,
            tip,
            up,
            (0.5 * self.t_s, 0.5 * hs0),
            (0.5 * self.t_s, 0.5 * hs1),
            3,
        ))?;
        self.landmarks
            .insert("spinous_tip".into(), tip + dir * 0.002);
        Ok(())
    }

    /// Two transverse processes (tip-to-tip width as tabulated) with their
    /// landmarks and the body's lateral ones; returns the top and bottom Y
    /// of the processes.
    fn transverse_processes(&mut self) -> Result<(f64, f64)> {
        let (s, post, h, y0) = (self.s, self.post, self.h, self.y0);
        let (x_pe, y_p) = (self.x_pe, self.y_p);
        let beta = post.transverse_dorsal_deg[self.li].to_radians();
        let gam = post.transverse_cranial_deg[self.li].to_radians();
        let r_y = 0.5 * post.transverse_height_frac_pedicle * self.ph;
        let r_x = 0.5 * post.transverse_depth_frac_pedicle * self.ph;
        let z_root =
            self.zp + 0.5 * self.pw.max(self.t_l) + self.gap + r_x * beta.sin() + r_y * gam.sin();
        let mut tp_top = f64::MIN;
        let mut tp_bottom = f64::MAX;
        for (side, sz) in [("r", 1.0), ("l", -1.0)] {
            let dir_t = Vector3::new(
                -beta.sin() * gam.cos(),
                gam.sin(),
                sz * beta.cos() * gam.cos(),
            );
            let root_t = Point3::new(x_pe, y_p, sz * z_root);
            let reach = (0.5 * s.transverse_width - z_root - r_x * beta.sin()).max(0.005);
            let len_t = reach / (beta.cos() * gam.cos());
            let tip_t = root_t + dir_t * len_t;
            let up_t = Vector3::y();
            let m = sweep(
                &straight(root_t, tip_t, up_t, (r_x, r_y), (0.8 * r_x, 0.8 * r_y), 3),
                post.around,
                &self.what,
            )?;
            if let Some((lo, hi)) = m.bounds() {
                tp_top = tp_top.max(hi.y);
                tp_bottom = tp_bottom.min(lo.y);
            }
            self.shells.push(m);
            let lm = &mut self.landmarks;
            lm.insert(format!("transverse_tip_{side}"), tip_t + dir_t * 0.002);
            lm.insert(
                format!("transverse_root_{side}"),
                Point3::new(x_pe - r_x - 0.002, y_p, sz * (z_root + 0.004)),
            );
            lm.insert(
                format!("erector_lane_{side}"),
                Point3::new(x_pe - r_x - 0.008, y_p, sz * (z_root + 0.004)),
            );
            if s.level < Level::L1 {
                lm.insert(
                    format!("rib_angle_{side}"),
                    tip_t + Vector3::new(-0.01, 0.0, sz * 0.025),
                );
            }
            // lateral side of the body at mid-height, 3 mm off the surface
            let b_mid = 0.5 * (1.0 - self.body_rules.waist) * 0.5 * (s.inf_width + s.sup_width);
            lm.insert(
                format!("body_lateral_{side}"),
                Point3::new(0.1 * s.depth(), y0 + 0.5 * h, sz * (b_mid + 0.003)),
            );
        }
        Ok((tp_top, tp_bottom))
    }

    /// Superior and inferior articular processes on both sides, above and
    /// below the pedicles, lamina and transverse processes (`tp_top`,
    /// `tp_bottom`): thoracic facets face backwards, lumbar ones medially.
    fn articular_processes(&mut self, tp_top: f64, tp_bottom: f64) -> Result<()> {
        let (s, post, h, y0, gap) = (self.s, self.post, self.h, self.y0, self.gap);
        let (x_pe, x_c, zp) = (self.x_pe, self.x_c, self.zp);
        let f_h = post.facet_height_frac_body * h;
        let f_w = 0.5 * post.facet_size_frac_canal_depth * s.canal_depth;
        let f_t = 0.5 * post.facet_thickness_frac_canal_depth * s.canal_depth;
        let lumbar = s.level >= Level::L1;
        // thoracic facets face backwards (thin in X), lumbar facets face medially (thin in Z)
        let (hx, hz) = if lumbar { (f_w, f_t) } else { (f_t, f_w) };
        let x_f = x_pe - 0.3 * (x_pe - x_c);
        let ped_top = self.y_p + 0.5 * self.ph;
        let lam_top = self.y_l + 0.5 * self.h_l;
        let y_s0 = ped_top.max(lam_top).max(tp_top) + gap;
        let y_s1 = (y0 + h + 0.3 * h).max(y_s0 + 0.3 * f_h);
        let lam_bottom = self.y_l - 0.5 * self.h_l;
        let ped_bottom = self.y_p - 0.5 * self.ph;
        let y_i0 = lam_bottom.min(ped_bottom).min(tp_bottom) - gap;
        let y_i1 = y_i0 - f_h;
        // keep the inferior processes clear of the spinous process at the midline
        let hz_i = hz.min(0.75 * zp - 0.5 * self.t_s - gap).max(0.5e-3);
        let x_i = x_pe - 0.6 * (x_pe - x_c);
        for (side, sz) in [("r", 1.0), ("l", -1.0)] {
            self.push(&straight(
                Point3::new(x_f, y_s0, sz * zp),
                Point3::new(x_f, y_s1, sz * zp),
                Vector3::x(),
                (hz, hx),
                (hz, hx),
                2,
            ))?;
            self.landmarks.insert(
                format!("mammillary_{side}"),
                Point3::new(x_f - hx - 0.002, y_s1 - 0.002, sz * zp),
            );
            self.push(&straight(
                Point3::new(x_i, y_i0, sz * 0.75 * zp),
                Point3::new(x_i, y_i1, sz * 0.75 * zp),
                Vector3::x(),
                (hz_i, hx),
                (hz_i, hx),
                2,
            ))?;
        }
        Ok(())
    }
}
