//! The palpation engine: the 14 landmarks of `../shared/formats/landmarks.md`
//! ("How each landmark is placed") and the thesis's vertebral centre,
//! found on one vertebra mesh in any pose, given a rough anatomical hint.
//!
//! Steps of [`palpate_vertebra`] (each a named function):
//! 1. [`local::prepare`]: weld and orient the mesh;
//! 2. [`frame::symmetry_plane`]: the mid-sagittal plane (left-right symmetry);
//! 3. iterate the vertebra frame: [`body::find_walls`] (anterior/posterior
//!    walls by rays along -X, lateral walls), [`body::find_endplate`]
//!    (faces within 40 deg of the endplate normal, within a few mm of its
//!    plane, between the walls), Y = IEC -> SEC in the mid-sagittal plane;
//! 4. [`body::endplate_points`]: SEC/IEC area centroids on the surface,
//!    SA/SP/IA/IP ends of the mid-sagittal section, SR/SL/IR/IL the
//!    middles of the lateral rims (the furthest points, made well-posed on
//!    flat rims, so that a mesh, its decimation and its label map agree);
//! 5. [`pedicle::pedicle_section`]: the frontal cut a fifth of the body
//!    depth behind the posterior wall, PT/PB its highest/lowest points;
//! 6. [`pedicle::vertebral_centre`]: the least-squares sphere through the
//!    body's anterior-surface nodes (points spread evenly over that
//!    surface, so the centre does not depend on the mesh's resolution);
//! 7. [`checks`]: protocol invariants and anatomy (upside-down, not a
//!    vertebra) as findings; confidence per landmark;
//! 8. `spread::region_spread`: how far each landmark moves when the
//!    endplate regions' 40 deg bound moves by 8 deg either way.
//!
//! The sacrum ([`palpate_sacrum`]) uses the same plane and endplate steps
//! on the S1 plateau, with the coarse-mesh fallback of the protocol.

mod body;
mod checks;
mod frame;
mod local;
mod pedicle;
mod sacrum;
mod spread;

use crate::error::{Error, Result};
use crate::landmarks::{Code, Level};
use crate::mesh::{MeshQuery, TriMesh};
use nalgebra::{Isometry3, Point3, Rotation3, Translation3, Vector3};
use std::collections::BTreeMap;

pub use checks::protocol_findings;
pub(crate) use pedicle::cut_x as pedicle_cut_x;
pub use sacrum::palpate_sacrum;

/// Rough anatomical directions in the mesh's coordinates (may be off by up
/// to ~45 deg); the engine refines them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameHint {
    /// Roughly anterior, unit vector in mesh coordinates.
    pub anterior: Vector3<f64>,
    /// Roughly cranial, unit vector in mesh coordinates.
    pub cranial: Vector3<f64>,
}

impl FrameHint {
    /// The hint of a mesh already in an OpenSim body frame (X anterior, Y cranial).
    pub fn body_frame() -> FrameHint {
        FrameHint {
            anterior: Vector3::x(),
            cranial: Vector3::y(),
        }
    }

    /// The hint's right direction (anterior x cranial).
    pub fn right(&self) -> Vector3<f64> {
        self.anterior.cross(&self.cranial)
    }
}

/// One palpated landmark.
#[derive(Debug, Clone, PartialEq)]
pub struct PalpatedLandmark {
    /// Position in mesh coordinates.
    pub point: Point3<f64>,
    /// 0..1: 1 = placed by the protocol's rule on a well-resolved region.
    pub confidence: f64,
    /// Why the confidence is reduced, if it is.
    pub note: Option<String>,
    /// How far (m) the landmark moves when the endplate regions' 40 deg
    /// bound is moved by 8 deg either way: large where it hangs on a face
    /// near the bound (see `spread.rs`); 0 where not measured.
    pub spread: f64,
}

/// How serious a finding is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Severity {
    /// The landmark is placed but less trustworthy.
    Warning,
    /// The landmark or mesh is unusable as palpated.
    Error,
}

/// Something the engine noticed about a landmark or the mesh.
#[derive(Debug, Clone, PartialEq)]
pub struct Finding {
    /// The vertebra (or sacrum) concerned.
    pub level: Level,
    /// The landmark concerned (None: the mesh as a whole).
    pub code: Option<Code>,
    /// How serious it is.
    pub severity: Severity,
    /// What was noticed, for a reader.
    pub message: String,
}

impl std::fmt::Display for Finding {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let sev = match self.severity {
            Severity::Warning => "warning",
            Severity::Error => "error",
        };
        match self.code {
            Some(c) => write!(f, "{sev}: {}_{c}: {}", self.level, self.message),
            None => write!(f, "{sev}: {}: {}", self.level, self.message),
        }
    }
}

/// The palpation of one vertebra (or the sacrum).
#[derive(Debug, Clone, PartialEq)]
pub struct VertebraPalpation {
    /// The vertebra (or the sacrum) palpated.
    pub level: Level,
    /// The vertebra's own frame (X anterior, Y cranial, Z right) in mesh
    /// coordinates; origin midway between SEC and IEC, on the mid-sagittal plane.
    pub frame: Isometry3<f64>,
    /// Landmarks in mesh coordinates (same units as the mesh, metres).
    pub landmarks: BTreeMap<Code, PalpatedLandmark>,
    /// Vertebral centre (thesis sphere rule), mesh coordinates.
    pub centre: Point3<f64>,
    /// Radius of that least-squares sphere.
    pub centre_radius: f64,
    /// What the engine noticed while palpating.
    pub findings: Vec<Finding>,
    /// How the centre's sphere was fitted.
    pub centre_fit: CentreFit,
    /// 0..1: 1 = the centre lies inside the body as the rule expects.
    pub centre_confidence: f64,
    /// The literal furthest points of the endplate regions to the right
    /// and left (`SR`, `SL`, `IR`, `IL`; mesh coordinates), where the
    /// landmarks are the middles of the lateral rims (a base model's
    /// coarse sacral plateau copies them from L5).
    pub furthest: BTreeMap<Code, Point3<f64>>,
}

/// The least-squares sphere fit behind the vertebral centre.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct CentreFit {
    /// Anterior-surface nodes used: points spread evenly over the body's
    /// anterior surface, about one per mm^2 (not the mesh's vertices).
    pub nodes: usize,
    /// RMS of the nodes' distances to the sphere (m).
    pub rms: f64,
}

impl VertebraPalpation {
    /// Landmark positions only.
    pub fn points(&self) -> BTreeMap<Code, Point3<f64>> {
        self.landmarks.iter().map(|(c, l)| (*c, l.point)).collect()
    }

    /// The same palpation after a rigid motion of the mesh.
    pub fn transformed(&self, iso: &Isometry3<f64>) -> VertebraPalpation {
        let mut out = self.clone();
        out.frame = iso * self.frame;
        out.centre = iso * self.centre;
        for l in out.landmarks.values_mut() {
            l.point = iso * l.point;
        }
        for p in out.furthest.values_mut() {
            *p = iso * *p;
        }
        out
    }

    /// The same palpation with `SR`, `SL`, `IR`, `IL` at the literal
    /// furthest points of the endplate regions ([`Self::furthest`]).
    pub fn with_furthest_laterals(&self) -> VertebraPalpation {
        let mut out = self.clone();
        for (c, p) in &self.furthest {
            if let Some(l) = out.landmarks.get_mut(c) {
                l.point = *p;
            }
        }
        out
    }

    /// A landmark expressed in the vertebra's own frame.
    pub fn local(&self, code: Code) -> Option<Point3<f64>> {
        self.landmarks
            .get(&code)
            .map(|l| self.frame.inverse() * l.point)
    }
}

/// The state of one frame iteration (local coordinates).
pub(crate) struct BodyState {
    pub lm: local::LocalMesh,
    pub walls: body::Walls,
    pub sup: body::Endplate,
    pub inf: body::Endplate,
    pub sup_pts: body::EndplatePoints,
    pub inf_pts: body::EndplatePoints,
}

/// Walls, endplates and endplate landmarks in the trial frame `rot`
/// (`q`: the query structure of `mesh`, shared by every trial frame).
fn body_in_frame(
    ctx: &str,
    mesh: &TriMesh,
    q: &MeshQuery,
    rot: Rotation3<f64>,
    origin: Point3<f64>,
) -> Result<BodyState> {
    let lm = local::LocalMesh::new(mesh, rot, origin);
    let walls = body::find_walls(&lm, q).ok_or_else(|| {
        Error::invalid(
            ctx,
            "no vertebral body: rays along the anterior axis do not cross two walls",
        )
    })?;
    if !(walls.depth() > 0.0 && walls.half_width() > 0.0) {
        return Err(Error::invalid(
            ctx,
            "no vertebral body: the walls have no depth or width",
        ));
    }
    let ep = |sup: bool, code: Code| {
        body::find_endplate(&lm, &walls, sup).ok_or_else(|| {
            Error::invalid(ctx, format!("{code}: no endplate faces between the walls"))
        })
    };
    let sup = ep(true, Code::SEC)?;
    let inf = ep(false, Code::IEC)?;
    let pts = |e: &body::Endplate, code: Code| {
        body::endplate_points(&lm, e, Some(walls.column_x())).ok_or_else(|| {
            Error::invalid(ctx, format!("{code}: the endplate region is degenerate"))
        })
    };
    let sup_pts = pts(&sup, Code::SEC)?;
    let inf_pts = pts(&inf, Code::IEC)?;
    Ok(BodyState {
        lm,
        walls,
        sup,
        inf,
        sup_pts,
        inf_pts,
    })
}

/// In-plane turns of the hint's anterior axis tried before refining (deg):
/// the hint may be off by up to about 45 deg.
const HINT_TURNS_DEG: [f64; 7] = [-45.0, -30.0, -15.0, 0.0, 15.0, 30.0, 45.0];

/// The mid-sagittal plane, then the in-plane rotation: the trial turn of
/// the hint whose endplate regions are largest (endplates found edge-on
/// when the frame is right), refined until Y is the IEC -> SEC direction.
fn estimate_frame(ctx: &str, mesh: &TriMesh, hint: &FrameHint) -> Result<(BodyState, f64)> {
    // Mid-sagittal plane and an origin on it.
    let q = MeshQuery::new(mesh)?;
    let plane = frame::symmetry_plane(mesh, &q, &hint.right(), &hint.cranial)
        .ok_or_else(|| Error::invalid(ctx, "cannot estimate the mid-sagittal plane"))?;
    let n = plane.normal;
    let c = mesh.area_centroid().unwrap_or(mesh.vertices[0]);
    let origin = c - n * (n.dot(&c.coords) - plane.offset);
    // Coarse search over the in-plane turn of the hint.
    let trial = |deg: f64| {
        let turn = Rotation3::from_axis_angle(&nalgebra::Unit::new_normalize(n), deg.to_radians());
        let rot = local::frame_rotation(&(turn * hint.anterior), &n);
        body_in_frame(ctx, mesh, &q, rot, origin).map(|st| (rot, st))
    };
    let mut best: Option<(Rotation3<f64>, BodyState)> = None;
    let mut first_err = None;
    for deg in HINT_TURNS_DEG {
        match trial(deg) {
            Ok((rot, st)) => {
                let area = st.sup.area + st.inf.area;
                if best
                    .as_ref()
                    .is_none_or(|(_, b)| area > b.sup.area + b.inf.area)
                {
                    best = Some((rot, st));
                }
            }
            Err(e) => first_err = first_err.or(Some(e)),
        }
    }
    let (mut rot, mut state) = match best {
        Some(b) => b,
        None => return Err(first_err.expect("at least one trial ran")),
    };
    // Refine: Y along IEC -> SEC in the mid-sagittal plane.
    for _ in 0..10 {
        let y_local = state.sup_pts.centre - state.inf_pts.centre;
        let y = rot * Vector3::new(y_local.x, y_local.y, 0.0);
        let Some(y) = y.try_normalize(1e-12) else {
            break;
        };
        let anterior = y.cross(&n);
        let new_rot = local::frame_rotation(&anterior, &n);
        let change = (new_rot * rot.inverse()).angle();
        rot = new_rot;
        state = body_in_frame(ctx, mesh, &q, rot, origin)?;
        if change < 0.01f64.to_radians() {
            break;
        }
    }
    Ok((state, plane.relative_cost))
}

/// Palpate one vertebra mesh (T1..L5) by the protocol.
pub fn palpate_vertebra(
    mesh: &TriMesh,
    level: Level,
    hint: &FrameHint,
) -> Result<VertebraPalpation> {
    let ctx = format!("palpation of {level}");
    if level.is_sacrum() {
        return palpate_sacrum(mesh, hint, None);
    }
    let prepared = local::prepare(mesh, &ctx)?;
    let (st, sym_cost) = estimate_frame(&ctx, &prepared, hint)?;
    let mut landmarks = BTreeMap::new();
    let mut findings = Vec::new();
    place_endplate_landmarks(&st, level, &mut landmarks, &mut findings);
    place_pedicles(&ctx, &st, level, &mut landmarks)?;
    // How far each landmark moves with the endplate regions' angle bound.
    for (code, s) in spread::region_spread(&st, &landmarks) {
        if let Some(l) = landmarks.get_mut(&code) {
            l.spread = s;
        }
    }
    let (centre, radius, centre_fit) = centre_of(&ctx, &st)?;
    let lm = &st.lm;
    let sec = landmarks[&Code::SEC].point;
    let iec = landmarks[&Code::IEC].point;
    // Origin: the SEC-IEC midpoint, on the mid-sagittal plane (z = 0).
    let mid = (sec.coords + iec.coords) * 0.5;
    let origin = Point3::new(mid.x, mid.y, 0.0);
    let frame = Isometry3::from_parts(
        Translation3::from(lm.to_mesh.transform_point(&origin).coords),
        lm.to_mesh.rotation,
    );
    let mut out = VertebraPalpation {
        level,
        frame,
        landmarks: landmarks
            .into_iter()
            .map(|(c, mut l)| {
                l.point = lm.to_mesh_point(&l.point);
                (c, l)
            })
            .collect(),
        centre: lm.to_mesh_point(&centre),
        centre_radius: radius,
        findings,
        centre_fit,
        centre_confidence: 1.0,
        furthest: [
            (Code::SR, st.sup_pts.furthest_right),
            (Code::SL, st.sup_pts.furthest_left),
            (Code::IR, st.inf_pts.furthest_right),
            (Code::IL, st.inf_pts.furthest_left),
        ]
        .into_iter()
        .map(|(c, p)| (c, lm.to_mesh_point(&p)))
        .collect(),
    };
    checks::anatomy_findings(&st, sym_cost, &mut out);
    out.findings.extend(protocol_findings(&out));
    Ok(out)
}

fn landmark(point: Point3<f64>, confidence: f64, note: Option<String>) -> PalpatedLandmark {
    PalpatedLandmark {
        point,
        confidence,
        note,
        spread: 0.0,
    }
}

/// SEC..IL from the two endplate regions (local coordinates).
fn place_endplate_landmarks(
    st: &BodyState,
    level: Level,
    out: &mut BTreeMap<Code, PalpatedLandmark>,
    findings: &mut Vec<Finding>,
) {
    use Code::*;
    for (e, p, codes) in [
        (&st.sup, &st.sup_pts, [SEC, SA, SP, SR, SL]),
        (&st.inf, &st.inf_pts, [IEC, IA, IP, IR, IL]),
    ] {
        let coarse = e.faces.len() < 4;
        let base = if coarse { 0.7 } else { 1.0 };
        let note = coarse.then(|| format!("endplate region of only {} faces", e.faces.len()));
        out.insert(codes[0], landmark(p.centre, base, note.clone()));
        let (mid_conf, mid_note) = if p.midline_section {
            (base, note.clone())
        } else {
            findings.push(Finding {
                level,
                code: Some(codes[1]),
                severity: Severity::Warning,
                message: format!(
                    "the endplate region does not cross the mid-sagittal plane (a hole?): {} and {} are its nearest points, not its mid-sagittal section",
                    codes[1], codes[2]
                ),
            });
            (
                0.4,
                Some("no mid-sagittal section of the endplate".to_string()),
            )
        };
        out.insert(codes[1], landmark(p.front, mid_conf, mid_note.clone()));
        out.insert(codes[2], landmark(p.back, mid_conf, mid_note));
        out.insert(codes[3], landmark(p.right, base, note.clone()));
        out.insert(codes[4], landmark(p.left, base, note));
    }
}

/// PTR/PBR/PTL/PBL from the pedicle cuts (local coordinates).
fn place_pedicles(
    ctx: &str,
    st: &BodyState,
    _level: Level,
    out: &mut BTreeMap<Code, PalpatedLandmark>,
) -> Result<()> {
    for (side, top, bot) in [(1.0, Code::PTR, Code::PBR), (-1.0, Code::PTL, Code::PBL)] {
        let x_cut = pedicle::pedicle_cut_x(&st.sup_pts, &st.inf_pts);
        let p = pedicle::pedicle_section(&st.lm, x_cut, side).ok_or_else(|| {
            Error::invalid(
                ctx,
                format!(
                    "{top}/{bot}: the frontal cut a fifth of the body depth behind the posterior wall meets no {} pedicle (not a vertebra, or the hint's anterior points the wrong way?)",
                    if side > 0.0 { "right" } else { "left" }
                ),
            )
        })?;
        let conf = if p.points < 4 { 0.7 } else { 1.0 };
        out.insert(top, landmark(p.top, conf, None));
        out.insert(bot, landmark(p.base, conf, None));
    }
    Ok(())
}

/// The vertebral centre and sphere radius (local coordinates).
fn centre_of(ctx: &str, st: &BodyState) -> Result<(Point3<f64>, f64, CentreFit)> {
    let (sphere, n) =
        pedicle::vertebral_centre(&st.lm, &st.sup_pts, &st.inf_pts).ok_or_else(|| {
            Error::invalid(
                ctx,
                "vertebral centre: too few anterior-surface nodes of the body for a sphere fit",
            )
        })?;
    Ok((
        sphere.centre,
        sphere.radius,
        CentreFit {
            nodes: n,
            rms: sphere.rms,
        },
    ))
}

/// A rotation's columns, for tests and callers wanting the axes.
pub fn frame_axes(frame: &Isometry3<f64>) -> [Vector3<f64>; 3] {
    let r: Rotation3<f64> = frame.rotation.to_rotation_matrix();
    [r * Vector3::x(), r * Vector3::y(), r * Vector3::z()]
}
