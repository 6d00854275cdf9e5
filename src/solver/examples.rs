//! Programmatic example systems: serial spine-like chains with 6-DoF
//! CustomJoints (X-Y-Z rotations, then translations) and a linear bushing on
//! each joint's own frames, with the thesis stiffness values used by the
//! oracle models. Used by tests and benchmarks.

use super::spec::*;
use nalgebra::{Isometry3, Matrix3, Translation3, UnitQuaternion, Vector3};

/// Thesis bushing parameters (see `../shared/oracle/spine_oracle_lib.py`).
pub fn thesis_bushing() -> BushingModel {
    BushingModel::Linear {
        rot_stiffness: Vector3::new(68.8, 291.0, 51.0),
        trans_stiffness: Vector3::new(149000.0, 1890000.0, 135000.0),
        rot_damping: Vector3::new(2.3, 2.3, 2.3),
        trans_damping: Vector3::new(1000.0, 1000.0, 1000.0),
    }
}

/// Solid ellipsoid inertia, semi-axes a (x), b (y), c (z).
pub fn ellipsoid_inertia(m: f64, a: f64, b: f64, c: f64) -> Matrix3<f64> {
    Matrix3::from_diagonal(&Vector3::new(
        m * (b * b + c * c) / 5.0,
        m * (a * a + c * c) / 5.0,
        m * (a * a + b * b) / 5.0,
    ))
}

/// Body-fixed X-Y-Z orientation + location as an isometry.
pub fn iso(loc: [f64; 3], xyz: [f64; 3]) -> Isometry3<f64> {
    let r = crate::osim::model::body_fixed_xyz(&Vector3::new(xyz[0], xyz[1], xyz[2]));
    Isometry3::from_parts(
        Translation3::new(loc[0], loc[1], loc[2]),
        UnitQuaternion::from_rotation_matrix(&r),
    )
}

/// Add a 6-DoF XYZ CustomJoint `parent -> child` with coordinates named
/// `<name>_rx.._tz` and a bushing on the joint's frames.
pub fn add_level(
    spec: &mut SystemSpec,
    name: &str,
    parent: Option<usize>,
    child: usize,
    x_pf: Isometry3<f64>,
    x_bm: Isometry3<f64>,
    bushing: BushingModel,
) {
    let c0 = spec.coordinates.len();
    for (i, s) in ["rx", "ry", "rz", "tx", "ty", "tz"].iter().enumerate() {
        let rot = i < 3;
        spec.coordinates.push(CoordinateSpec {
            name: format!("{name}_{s}"),
            default: 0.0,
            range: if rot {
                [-std::f64::consts::FRAC_PI_2, std::f64::consts::FRAC_PI_2]
            } else {
                [-0.05, 0.05]
            },
            clamped: false,
            locked: false,
        });
    }
    let e = [Vector3::x(), Vector3::y(), Vector3::z()];
    let axes = Box::new([
        TransformAxis::identity(e[0], c0),
        TransformAxis::identity(e[1], c0 + 1),
        TransformAxis::identity(e[2], c0 + 2),
        TransformAxis::identity(e[0], c0 + 3),
        TransformAxis::identity(e[1], c0 + 4),
        TransformAxis::identity(e[2], c0 + 5),
    ]);
    spec.joints.push(JointSpec {
        name: name.to_string(),
        parent,
        child,
        x_pf,
        x_bm,
        kind: JointKind::Custom { axes },
    });
    spec.bushings.push(BushingSpec {
        name: format!("{name}_bushing"),
        frame1: FrameSpec {
            body: parent,
            transform: x_pf,
        },
        frame2: FrameSpec {
            body: Some(child),
            transform: x_bm,
        },
        model: bushing,
    });
}

/// A chain like `../shared/oracle/chain17.osim` with `n` moving vertebrae on
/// a sacrum welded to ground (25 mm apart, gently curved), gravity off.
pub fn spine_chain(n: usize) -> SystemSpec {
    let mut spec = SystemSpec {
        bodies: vec![],
        joints: vec![],
        coordinates: vec![],
        bushings: vec![],
        gravity: Vector3::zeros(),
    };
    spec.bodies.push(BodySpec {
        name: "sacrum".into(),
        mass: 2.0,
        com: Vector3::new(-0.02, -0.02, 0.0),
        inertia: ellipsoid_inertia(2.0, 0.05, 0.04, 0.06),
    });
    spec.joints.push(JointSpec {
        name: "sacrum_ground".into(),
        parent: None,
        child: 0,
        x_pf: Isometry3::identity(),
        x_bm: Isometry3::identity(),
        kind: JointKind::Weld,
    });
    let half = 0.0125;
    for i in 0..n {
        let f = if n > 1 {
            i as f64 / (n - 1) as f64
        } else {
            0.0
        };
        let m = 1.2 - 0.8 * f;
        let s = 1.0 - 0.4 * f;
        let tilt = if i < 5 { 0.06 } else { -0.045 };
        let name = format!("v{}", i + 1);
        spec.bodies.push(BodySpec {
            name: name.clone(),
            mass: m,
            com: Vector3::new(-0.008 * s, 0.0, 0.0),
            inertia: ellipsoid_inertia(m, 0.040 * s, 0.0125, 0.050 * s),
        });
        let parent = i;
        let pname = spec.bodies[parent].name.clone();
        let ploc = [0.0, if i == 0 { 0.020 } else { half }, 0.0];
        add_level(
            &mut spec,
            &format!("{pname}_{name}"),
            Some(parent),
            i + 1,
            iso(ploc, [0.0, 0.0, tilt]),
            iso([0.0, -half, 0.0], [0.0; 3]),
            thesis_bushing(),
        );
    }
    spec
}
