//! Builders for new 4.x components (elements ready to insert into a
//! [`Document`](super::Document) set or list): Body, PhysicalOffsetFrame,
//! CustomJoint with six TransformAxis, Coordinate, BushingForce, Marker,
//! WrapSphere, PathWrap. Numbers are written with the shortest text that
//! reads back to the same f64.

use super::props::fmt_numbers;
use super::xml::Element;
use crate::util::fmt_f64;
use nalgebra::Vector3;

fn v3(v: &Vector3<f64>) -> String {
    fmt_numbers(v.as_slice())
}

/// `<Body>` with mass properties (inertia [Ixx Iyy Izz Ixy Ixz Iyz] about
/// the mass center) and empty geometry / wrap object lists.
pub fn body(name: &str, mass: f64, mass_center: &Vector3<f64>, inertia: &[f64; 6]) -> Element {
    Element::new("Body")
        .with_attr("name", name)
        .with_child(Element::new("attached_geometry"))
        .with_child(
            Element::new("WrapObjectSet")
                .with_attr("name", "wrapobjectset")
                .with_child(Element::new("objects"))
                .with_child(Element::new("groups")),
        )
        .with_prop("mass", fmt_f64(mass))
        .with_prop("mass_center", v3(mass_center))
        .with_prop("inertia", fmt_numbers(inertia))
}

/// `<Mesh>` geometry for a body's `attached_geometry`.
pub fn mesh(name: &str, mesh_file: &str, scale_factors: &Vector3<f64>) -> Element {
    Element::new("Mesh")
        .with_attr("name", name)
        .with_prop("socket_frame", "..")
        .with_prop("scale_factors", v3(scale_factors))
        .with_prop("mesh_file", mesh_file)
}

/// `<PhysicalOffsetFrame>`: `socket_parent` is a socket path (e.g.
/// `/bodyset/L5`, `../../../ground` from inside a joint's `frames`);
/// `orientation` body-fixed XYZ (rad).
pub fn offset_frame(
    name: &str,
    socket_parent: &str,
    translation: &Vector3<f64>,
    orientation: &Vector3<f64>,
) -> Element {
    Element::new("PhysicalOffsetFrame")
        .with_attr("name", name)
        .with_child(
            Element::new("FrameGeometry")
                .with_attr("name", "frame_geometry")
                .with_prop("socket_frame", "..")
                .with_prop("scale_factors", "0.2 0.2 0.2"),
        )
        .with_prop("socket_parent", socket_parent)
        .with_prop("translation", v3(translation))
        .with_prop("orientation", v3(orientation))
}

/// `<Coordinate>` with default value and range; clamped off, unlocked.
pub fn coordinate(name: &str, default_value: f64, range: [f64; 2]) -> Element {
    Element::new("Coordinate")
        .with_attr("name", name)
        .with_prop("default_value", fmt_f64(default_value))
        .with_prop("default_speed_value", "0")
        .with_prop("range", fmt_numbers(&range))
        .with_prop("clamped", "false")
        .with_prop("locked", "false")
}

/// One TransformAxis of a CustomJoint: `coordinate` None gives a Constant 0
/// function, Some(c) a LinearFunction (1, 0) of coordinate c.
pub(crate) fn transform_axis(name: &str, axis: &Vector3<f64>, coordinate: Option<&str>) -> Element {
    let (coords, function) = match coordinate {
        Some(c) => (
            c.to_string(),
            Element::new("LinearFunction")
                .with_attr("name", "function")
                .with_prop("coefficients", "1 0"),
        ),
        None => (
            String::new(),
            Element::new("Constant")
                .with_attr("name", "function")
                .with_prop("value", "0"),
        ),
    };
    Element::new("TransformAxis")
        .with_attr("name", name)
        .with_child(Element::new("coordinates").with_text(coords))
        .with_prop("axis", v3(axis))
        .with_child(function)
}

/// `<CustomJoint>` with its two offset frames (built with
/// [`offset_frame`]; the sockets name them), its coordinates and the six
/// transform axes in order rotation1..3, translation1..3.
pub fn custom_joint(
    name: &str,
    parent_frame: Element,
    child_frame: Element,
    coordinates: Vec<Element>,
    axes: [Element; 6],
) -> Element {
    let mut coords = Element::new("coordinates");
    for c in coordinates {
        coords = coords.with_child(c);
    }
    let mut st = Element::new("SpatialTransform");
    for a in axes {
        st = st.with_child(a);
    }
    Element::new("CustomJoint")
        .with_attr("name", name)
        .with_prop("socket_parent_frame", parent_frame.name_attr().to_string())
        .with_prop("socket_child_frame", child_frame.name_attr().to_string())
        .with_child(coords)
        .with_child(
            Element::new("frames")
                .with_child(parent_frame)
                .with_child(child_frame),
        )
        .with_child(st)
}

/// The six `<TransformAxis>` of a SpatialTransform, named rotation1..3 and
/// translation1..3, on the directions `dirs`, each driven by its
/// coordinate (or by none: a constant zero axis).
pub fn transform_axes(dirs: &[Vector3<f64>; 6], coordinates: [Option<&str>; 6]) -> [Element; 6] {
    std::array::from_fn(|i| {
        let label = if i < 3 {
            format!("rotation{}", i + 1)
        } else {
            format!("translation{}", i - 2)
        };
        transform_axis(&label, &dirs[i], coordinates[i])
    })
}

/// `<WeldJoint>` between its two offset frames (built with
/// [`offset_frame`]; the sockets name them).
pub fn weld_joint(name: &str, parent_frame: Element, child_frame: Element) -> Element {
    Element::new("WeldJoint")
        .with_attr("name", name)
        .with_prop("socket_parent_frame", parent_frame.name_attr().to_string())
        .with_prop("socket_child_frame", child_frame.name_attr().to_string())
        .with_child(
            Element::new("frames")
                .with_child(parent_frame)
                .with_child(child_frame),
        )
}

/// The usual spine CustomJoint: coordinates `<prefix>_rx, _ry, _rz, _tx,
/// _ty, _tz` on axes X, Y, Z of the parent frame (rotations body-fixed
/// X-Y-Z), each with range `rot_range` / `trans_range` (a test fixture).
#[cfg(test)]
fn custom_joint_6dof(
    name: &str,
    prefix: &str,
    parent_frame: Element,
    child_frame: Element,
    rot_range: [f64; 2],
    trans_range: [f64; 2],
) -> Element {
    let ax = [Vector3::x(), Vector3::y(), Vector3::z()];
    let names = ["rx", "ry", "rz", "tx", "ty", "tz"];
    let coords: Vec<Element> = names
        .iter()
        .enumerate()
        .map(|(i, n)| {
            coordinate(
                &format!("{prefix}_{n}"),
                0.0,
                if i < 3 { rot_range } else { trans_range },
            )
        })
        .collect();
    let cn = names.map(|n| format!("{prefix}_{n}"));
    let axes = transform_axes(
        &std::array::from_fn(|i| ax[i % 3]),
        std::array::from_fn(|i| Some(cn[i].as_str())),
    );
    custom_joint(name, parent_frame, child_frame, coords, axes)
}

/// `<BushingForce>` between two frames (socket paths), stiffness and damping
/// per axis (rotational Nm/rad and Nm/(rad/s), translational N/m and N/(m/s)).
pub fn bushing_force(
    name: &str,
    socket_frame1: &str,
    socket_frame2: &str,
    rotational_stiffness: &Vector3<f64>,
    translational_stiffness: &Vector3<f64>,
    rotational_damping: &Vector3<f64>,
    translational_damping: &Vector3<f64>,
) -> Element {
    Element::new("BushingForce")
        .with_attr("name", name)
        .with_prop("socket_frame1", socket_frame1)
        .with_prop("socket_frame2", socket_frame2)
        .with_prop("rotational_stiffness", v3(rotational_stiffness))
        .with_prop("translational_stiffness", v3(translational_stiffness))
        .with_prop("rotational_damping", v3(rotational_damping))
        .with_prop("translational_damping", v3(translational_damping))
}

/// `<Marker>` fixed to a frame (socket path) at `location`.
pub fn marker(
    name: &str,
    socket_parent_frame: &str,
    location: &Vector3<f64>,
    fixed: bool,
) -> Element {
    Element::new("Marker")
        .with_attr("name", name)
        .with_prop("socket_parent_frame", socket_parent_frame)
        .with_prop("location", v3(location))
        .with_prop("fixed", if fixed { "true" } else { "false" })
}

/// `<WrapSphere>` for a body's WrapObjectSet.
pub fn wrap_sphere(
    name: &str,
    translation: &Vector3<f64>,
    xyz_body_rotation: &Vector3<f64>,
    radius: f64,
    quadrant: &str,
) -> Element {
    Element::new("WrapSphere")
        .with_attr("name", name)
        .with_prop("xyz_body_rotation", v3(xyz_body_rotation))
        .with_prop("translation", v3(translation))
        .with_prop("quadrant", quadrant)
        .with_prop("radius", fmt_f64(radius))
}

/// `<PathWrap>` for a GeometryPath's PathWrapSet.
pub fn path_wrap(name: &str, wrap_object: &str, method: &str, range: [i64; 2]) -> Element {
    Element::new("PathWrap")
        .with_attr("name", name)
        .with_prop("wrap_object", wrap_object)
        .with_prop("method", method)
        .with_prop("range", format!("{} {}", range[0], range[1]))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::osim::model::JointKind;
    use crate::osim::Document;

    #[test]
    fn built_model_reads_back_typed() {
        let mut d = Document::new_model("built");
        let z = Vector3::zeros();
        d.insert_component(
            "BodySet",
            body(
                "L5",
                1.2,
                &Vector3::new(-0.01, 0.0, 0.0),
                &[1e-3, 2e-3, 1e-3, 0.0, 0.0, 0.0],
            ),
        )
        .unwrap();
        let pf = offset_frame(
            "ground_offset",
            "/ground",
            &Vector3::new(0.0, 1.0, 0.0),
            &Vector3::new(0.0, 0.0, 0.1),
        );
        let cf = offset_frame("L5_offset", "/bodyset/L5", &z, &z);
        d.insert_component(
            "JointSet",
            custom_joint_6dof("j", "g_L5", pf, cf, [-1.0, 1.0], [-0.1, 0.1]),
        )
        .unwrap();
        d.insert_component(
            "ForceSet",
            bushing_force(
                "b",
                "/jointset/j/ground_offset",
                "/jointset/j/L5_offset",
                &Vector3::repeat(50.0),
                &Vector3::repeat(1e5),
                &z,
                &z,
            ),
        )
        .unwrap();
        d.insert_component(
            "MarkerSet",
            marker("m", "/bodyset/L5", &Vector3::new(0.0, 0.02, 0.0), false),
        )
        .unwrap();
        let text = d.to_xml_string();
        let m = Document::parse(&text, "built.osim")
            .unwrap()
            .model()
            .unwrap();
        assert_eq!(m.coordinates().count(), 6);
        let JointKind::Custom { axes } = &m.joints[0].kind else {
            panic!("not custom")
        };
        assert_eq!(axes[4].coordinates, vec!["g_L5_ty".to_string()]);
        let jf = &m.joint_frames().unwrap()[0];
        assert_eq!(
            (jf.parent_body.as_str(), jf.child_body.as_str()),
            ("ground", "L5")
        );
        assert!(
            (jf.parent_in_body.translation.vector - Vector3::new(0.0, 1.0, 0.0)).norm() < 1e-15
        );
        assert_eq!(m.bushings().count(), 1);
    }
}
