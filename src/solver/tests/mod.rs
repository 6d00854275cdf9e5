//! Unit tests of the solver core against analytic solutions and invariants,
//! one file per algorithm.

use super::examples::*;
use super::spec::*;
use super::*;
use nalgebra::{Isometry3, Matrix3, Vector3};

mod dynamics;
mod forces;
mod statics;
mod system;

fn one_level(gravity: bool, bushing: BushingModel) -> SystemSpec {
    let mut spec = SystemSpec {
        bodies: vec![],
        joints: vec![],
        coordinates: vec![],
        bushings: vec![],
        gravity: if gravity {
            Vector3::new(0.0, -9.80665, 0.0)
        } else {
            Vector3::zeros()
        },
    };
    spec.bodies.push(BodySpec {
        name: "top".into(),
        mass: 1.0,
        com: Vector3::new(-0.01, 0.0, 0.0),
        inertia: ellipsoid_inertia(1.0, 0.04, 0.0175, 0.05),
    });
    add_level(
        &mut spec,
        "j",
        None,
        0,
        Isometry3::identity(),
        Isometry3::identity(),
        bushing,
    );
    spec
}
