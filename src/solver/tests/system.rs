//! System: the spec and system index spaces.

use super::*;

/// Spec order and system order are two index spaces: a spec listing the
/// child before its parent gets the parent first in the system, and every
/// body index the system hands out (body by name, parent, bushing bodies,
/// body of a dof, coordinate -> dof) is in system order.
#[test]
fn spec_indices_are_mapped_to_system_order() {
    let body = |name: &str| BodySpec {
        name: name.into(),
        mass: 1.0,
        com: Vector3::zeros(),
        inertia: Matrix3::identity() * 1e-3,
    };
    let mut spec = SystemSpec {
        bodies: vec![body("child"), body("parent")],
        joints: vec![],
        coordinates: vec![],
        bushings: vec![],
        gravity: Vector3::zeros(),
    };
    let x = iso([0.0, 0.02, 0.0], [0.0; 3]);
    // spec indices: parent = 1 (on ground), child = 0 (on parent)
    add_level(&mut spec, "upper", Some(1), 0, x, x, thesis_bushing());
    add_level(&mut spec, "lower", None, 1, x, x, thesis_bushing());
    let sys = System::new(&spec).unwrap();
    let (parent, child) = (BodyIndex(0), BodyIndex(1));
    assert_eq!(sys.body_index("parent"), Some(parent));
    assert_eq!(sys.body_index("child"), Some(child));
    assert_eq!(sys.parent_of(child), Some(parent));
    assert_eq!(sys.parent_of(parent), None);
    // bushing 0 ("upper") joins the parent (frame 1) to the child (frame 2)
    assert_eq!(
        sys.bushing_bodies(BushingIndex(0)),
        Some((Some(parent), Some(child)))
    );
    assert_eq!(
        sys.bushing_bodies(BushingIndex(1)),
        Some((None, Some(parent)))
    );
    // dofs are numbered joint by joint in system order: the parent's first
    assert_eq!(sys.dof_of("lower_rx"), Some(DofIndex(0)));
    assert_eq!(sys.dof_of("upper_rx"), Some(DofIndex(6)));
    assert_eq!(sys.dof_body(DofIndex(0)), Some(parent));
    assert_eq!(sys.dof_body(DofIndex(6)), Some(child));
    assert_eq!(sys.dof_name(DofIndex(6)), "upper_rx");
}
