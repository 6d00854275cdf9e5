//! Segment masses, centres of mass and inertias of the procedural bodies
//! from de Leva (1996) trunk segments (`templates/segments.toml`, rules in
//! its header): body mass from the reference BMI of the chosen sex, UPT
//! over T1..T8, MPT over T9..L3 (shares proportional to slice height), LPT
//! over L4, L5 (by slice height over the LPT length) and the pelvis (the
//! rest); each slice an elliptic cylinder of the region's torso breadth and
//! depth.

use super::skeleton::Skeleton;
use super::tables::Templates;
use super::Sex;
use crate::error::{Error, Result};
use nalgebra::Point3;

/// Mass properties of one body (OpenSim conventions: inertia
/// `[Ixx Iyy Izz Ixy Ixz Iyz]` about the centre of mass, body axes).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct MassProps {
    /// Body name.
    pub body: String,
    /// Mass (kg).
    pub mass: f64,
    /// Centre of mass in the body frame (m).
    pub mass_center: [f64; 3],
    /// Inertia about the centre of mass `[Ixx Iyy Izz Ixy Ixz Iyz]` (kg m^2, body axes).
    pub inertia: [f64; 6],
}

fn slice_inertia(m: f64, breadth: f64, depth: f64, h: f64) -> [f64; 6] {
    let a = 0.5 * depth; // x semi-axis
    let c = 0.5 * breadth; // z semi-axis
    [
        m * (c * c / 4.0 + h * h / 12.0),
        m * (a * a + c * c) / 4.0,
        m * (a * a / 4.0 + h * h / 12.0),
        0.0,
        0.0,
        0.0,
    ]
}

/// Body mass (kg) for the skeleton's stature and sex.
pub fn body_mass(sk: &Skeleton, t: &Templates) -> f64 {
    let s = match sk.sex {
        Sex::Male => &t.segments.male,
        Sex::Female => &t.segments.female,
    };
    s.bmi_ref * sk.stature * sk.stature
}

/// Mass properties of every body: T1..L5, sacrum, pelvis.
pub fn mass_properties(sk: &Skeleton, t: &Templates) -> Result<Vec<MassProps>> {
    let sx = match sk.sex {
        Sex::Male => &t.segments.male,
        Sex::Female => &t.segments.female,
    };
    let tor = &t.segments.torso;
    let k = sk.scale;
    let bm = body_mass(sk, t);
    // slice height of each level: body height + disc below
    let hs: Vec<f64> = sk
        .levels
        .iter()
        .map(|l| l.height() + l.disc_below)
        .collect();
    let upt: f64 = hs[0..8].iter().sum();
    let mpt: f64 = hs[8..15].iter().sum();
    let lpt_len = sx.lpt_length_m * sk.stature / sx.ref_stature_m;
    let mut out = Vec::new();
    let mut lpt_used = 0.0;
    for (i, l) in sk.levels.iter().enumerate() {
        let h = hs[i];
        let m = if i < 8 {
            sx.upt_mass_frac * bm * h / upt
        } else if i < 15 {
            sx.mpt_mass_frac * bm * h / mpt
        } else {
            let m = sx.lpt_mass_frac * bm * h / lpt_len;
            lpt_used += m;
            m
        };
        let thoracic = i < 12;
        let (br, dp, ant) = if thoracic {
            (
                tor.thoracic_breadth_m,
                tor.thoracic_depth_m,
                tor.thoracic_com_anterior_m,
            )
        } else {
            (
                tor.lumbar_breadth_m,
                tor.lumbar_depth_m,
                tor.lumbar_com_anterior_m,
            )
        };
        let y = 0.5 * l.disc_below + 0.5 * l.height();
        out.push(MassProps {
            body: l.level.body_name(),
            mass: m,
            mass_center: [ant * k, y, 0.0],
            inertia: slice_inertia(m, br * k, dp * k, h),
        });
    }
    let pelvis_mass = sx.lpt_mass_frac * bm - lpt_used;
    if pelvis_mass <= 0.0 {
        return Err(Error::invalid(
            "templates/segments.toml",
            "the L4/L5 slices take all of the LPT mass (check lpt_length_m)",
        ));
    }
    out.push(MassProps {
        body: "sacrum".into(),
        mass: tor.sacrum_nominal_mass_kg,
        mass_center: [0.0, 0.0, 0.0],
        inertia: [1e-6, 1e-6, 1e-6, 0.0, 0.0, 0.0],
    });
    let pc = Point3::new(
        tor.pelvis_com_anterior_m * k,
        -tor.pelvis_com_below_m * k,
        0.0,
    );
    out.push(MassProps {
        body: "pelvis".into(),
        mass: pelvis_mass,
        mass_center: pc.coords.into(),
        inertia: slice_inertia(
            pelvis_mass,
            tor.pelvis_breadth_m * k,
            tor.pelvis_depth_m * k,
            lpt_len,
        ),
    });
    Ok(out)
}
