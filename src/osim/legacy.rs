//! Upgrade of OpenSim 1.9 / 2.x / 3.x / 4.0-development documents (Version
//! < 40000) to the 4.x form, following OpenSim 4.6's own version-update rules
//! (`updateFromXMLNode` of each class; the version each rule applies to is
//! given). `docs/legacy-upgrade.md` lists the rules and the deliberate
//! differences; `tests/osim_legacy_rules.rs` checks them against OpenSim.
//!
//! Model and bodies:
//! - very old files keep the sets in `<DynamicsEngine><SimbodyEngine>`: moved up;
//! - the `ground` Body becomes `<Ground>` (with its geometry and wrap objects);
//! - `inertia_xx..inertia_yz` become `<inertia>` [Ixx Iyy Izz Ixy Ixz Iyz];
//! - geometry: `VisibleObject` `geometry_files` (version < 20101) or
//!   `GeometrySet`/`DisplayGeometry` become Meshes `<body>_geom_<i>` (i from 1;
//!   scale factors multiplied; `color`/`opacity` -> `Appearance`); a
//!   DisplayGeometry with a non-zero `transform` hangs from a new
//!   PhysicalOffsetFrame `<body>_geom_frame_<i>` in the body's `components`;
//! - wrap objects lose their display properties;
//! - `FrameSet` (4.0 development, < 30512) moves to the model's `components`.
//!
//! Joints:
//! - joints nested in bodies (`<Joint><XJoint>`, < 30500) and JointSet joints
//!   naming their bodies in `<connectors><Connector_PhysicalFrame_>`
//!   (30500..30504) move to the JointSet with parent/child
//!   PhysicalOffsetFrames `<parent>_offset` / `<child>_offset` made from
//!   `location_in_parent`/`orientation_in_parent` and `location`/`orientation`
//!   (nested) or `location_in_child`/`orientation_in_child` (connectors), the
//!   vectors rounded to 6 significant digits as OpenSim does ([`fmt_g6`]);
//!   `reverse` = true swaps the parent and child frame sockets; an unnamed
//!   joint is named after its class in lower case; `CoordinateSet` becomes
//!   `coordinates` (obsolete `motion_type`, `initial_value` dropped);
//!   TransformAxis `<function>` wrappers are unwrapped.
//!
//! Components:
//! - `isDisabled` (< 30509/30511) becomes `appliesForce` (forces),
//!   `isEnforced` (constraints) and `enabled` (controllers, probes), negated;
//! - marker and path point `body` become `socket_parent_frame`; 4.0
//!   development `<connectors>` become `socket_<name>`;
//!   ConditionalPathPoint `coordinate` and MovingPathPoint `x_coordinate`..
//!   become coordinate sockets;
//! - BushingForce `body_1`/`location_body_1`/`orientation_body_1` (and 2)
//!   become a frame `<body>_offset` with `socket_frame1`/`socket_frame2`, or
//!   the body itself when its offset is zero;
//! - muscles (< 30513): `min_control` 0 and `max_control` 1 are dropped so the
//!   muscle's own defaults apply (Thelen2003/Millard2012: `min_control` =
//!   `minimum_activation` 0.01); `MusclePointSet` and `pennation_angle`
//!   renamed (<= 20301); GeometryPath default colour (< 30516);
//! - controllers' `actuator_list` becomes `socket_actuators`.
//!
//! The document then says Version="40600". 4.x files before 4.6 get
//! [`upgrade_4x`] (the path actuators' `geometrypath` becomes `path`).

use super::props::{fmt_numbers, loc, parse_numbers};
use super::xml::{Element, Node, XmlTree};
use crate::error::{Error, Result};
use std::collections::BTreeMap;
use std::path::Path;

/// The document version OpenSim 4.6 writes (and that upgraded documents get).
pub const CURRENT_VERSION: u32 = 40600;
/// Oldest document version accepted (OpenSim 1.9 era files still load in 4.6).
pub const OLDEST_VERSION: u32 = 10500;

/// State of one upgrade: the file, its own version, and what later rules
/// need from earlier ones.
struct Up<'a> {
    file: &'a Path,
    /// The document version the file was written in.
    version: u32,
    /// Coordinate name -> joint name (for socket paths).
    coord_joint: BTreeMap<String, String>,
}

impl Up<'_> {
    /// An error at `e` that names the file's own version.
    fn err(&self, e: &Element, msg: impl Into<String>) -> Error {
        Error::parse(
            self.file,
            loc(e),
            format!("{} (a Version {} document)", msg.into(), self.version),
        )
    }

    /// Socket path of a body named in an old file ("ground" or a body).
    fn body_path(&self, name: &str) -> String {
        if name == "ground" {
            "/ground".to_string()
        } else {
            format!("/bodyset/{name}")
        }
    }

    /// Numbers of a property that must hold `n` of them (None when absent).
    fn numbers(&self, e: &Element, prop: &str, n: usize) -> Result<Option<Vec<f64>>> {
        let Some(c) = e.child(prop) else {
            return Ok(None);
        };
        let v = parse_numbers(&c.text(), c, self.file)?;
        if v.len() != n {
            let class = &e.name;
            return Err(self.err(
                c,
                format!(
                    "<{prop}> of a {} {class}: expected {n} numbers, found {}",
                    self.version,
                    v.len()
                ),
            ));
        }
        Ok(Some(v))
    }
}

fn take_child(e: &mut Element, name: &str) -> Option<Element> {
    let i = e
        .children
        .iter()
        .position(|n| matches!(n, Node::Element(c) if c.name == name))?;
    match e.children.remove(i) {
        Node::Element(c) => Some(c),
        _ => None,
    }
}

fn rename_child(e: &mut Element, from: &str, to: &str) {
    if let Some(c) = e.child_mut(from) {
        c.name = to.to_string();
    }
}

/// Format like C++ streams with their default precision (`%g`, 6
/// significant digits): OpenSim 4.6 passes the vectors of the joint and
/// bushing frames it creates while upgrading through this text form (checked:
/// its in-memory model holds the rounded values), so an upgraded model must
/// hold the same rounded values to reproduce OpenSim's kinematics. (It also
/// *prints* LinearFunction coefficients of old files with 6 digits, but
/// computes with the full values; those are kept verbatim here.)
pub(crate) fn fmt_g6(x: f64) -> String {
    if x == 0.0 || !x.is_finite() {
        return if x == 0.0 { "0".into() } else { format!("{x}") };
    }
    let sci = format!("{x:.5e}");
    let (mant, exp) = sci.split_once('e').unwrap_or((&sci, "0"));
    let exp: i32 = exp.parse().unwrap_or(0);
    let trim = |s: String| -> String {
        if s.contains('.') {
            s.trim_end_matches('0').trim_end_matches('.').to_string()
        } else {
            s
        }
    };
    if (-4..6).contains(&exp) {
        trim(format!("{:.*}", (5 - exp) as usize, x))
    } else {
        let m = trim(mant.to_string());
        let sign = if exp < 0 { '-' } else { '+' };
        format!("{m}e{sign}{:02}", exp.abs())
    }
}

/// A frame vector of an old joint or bushing: taken out of `e`, checked
/// (3 numbers) and rounded through [`fmt_g6`]; None when absent.
fn take_g6_vec3(e: &mut Element, prop: &str, up: &Up) -> Result<Option<String>> {
    let Some(v) = up.numbers(e, prop, 3)? else {
        return Ok(None);
    };
    take_child(e, prop);
    Ok(Some(
        v.iter().map(|x| fmt_g6(*x)).collect::<Vec<_>>().join(" "),
    ))
}

/// True when a (rounded) vector text is absent or all zeros.
fn is_zero_vec(v: &Option<String>) -> bool {
    v.as_deref()
        .is_none_or(|t| t.split_whitespace().all(|x| x.parse::<f64>() == Ok(0.0)))
}

/// Offset frame element.
fn offset_frame(
    name: &str,
    parent: &str,
    translation: Option<String>,
    orientation: Option<String>,
) -> Element {
    Element::new("PhysicalOffsetFrame")
        .with_attr("name", name)
        .with_prop("socket_parent", parent)
        .with_prop("translation", translation.unwrap_or_else(|| "0 0 0".into()))
        .with_prop("orientation", orientation.unwrap_or_else(|| "0 0 0".into()))
}

/// Apply `f` to every object of the model's set `set` (if any).
fn each_object(
    model: &mut Element,
    set: &str,
    mut f: impl FnMut(&mut Element) -> Result<()>,
) -> Result<()> {
    if let Some(objs) = model.child_mut(set).and_then(|s| s.child_mut("objects")) {
        for o in objs.elements_mut() {
            f(o)?;
        }
    }
    Ok(())
}

/// Upgrade `tree` (document version `version` < 40000) in place.
pub fn upgrade(tree: &mut XmlTree, version: u32, path: &Path) -> Result<()> {
    let mut up = Up {
        file: path,
        version,
        coord_joint: BTreeMap::new(),
    };
    let model = tree
        .root
        .child_mut("Model")
        .ok_or_else(|| Error::parse(path, "<OpenSimDocument>", "no <Model>"))?;
    // Model level: engine sets, bodies (with nested joints), JointSet, frames.
    move_engine_sets_to_model(model);
    let nested = upgrade_bodies(model, &mut up)?;
    upgrade_jointset(model, nested, &mut up)?;
    frameset_to_components(model);
    name_sets_in_lower_case(model);
    // Components, set by set.
    each_object(model, "MarkerSet", |mk| upgrade_marker(mk, &up))?;
    each_object(model, "ForceSet", |f| upgrade_force(f, &up))?;
    each_object(model, "ConstraintSet", |c| {
        connectors_to_sockets(c);
        is_disabled_to(c, "isEnforced");
        Ok(())
    })?;
    each_object(model, "ControllerSet", |c| {
        controller_actuator_list_to_socket(c);
        is_disabled_to(c, "enabled");
        Ok(())
    })?;
    each_object(model, "ProbeSet", |p| {
        is_disabled_to(p, "enabled");
        Ok(())
    })?;
    tree.root.set_attr("Version", CURRENT_VERSION.to_string());
    Ok(())
}

/// Upgrade a 4.x `tree` written before 4.6 (`40000 <= version < 40600`):
/// the paths of path actuators, muscles and path springs, a `GeometryPath`
/// named `geometrypath` (or `GeometryPath`), are the 4.6 property `path`.
/// OpenSim 4.6 applies the same rename when it loads such a file (and logs
/// "Updating Model file from 40000"); a model it printed then says 40600.
pub fn upgrade_4x(tree: &mut XmlTree) {
    if let Some(model) = tree.root.child_mut("Model") {
        if let Some(forces) = model.child_mut("ForceSet") {
            if let Some(objects) = forces.child_mut("objects") {
                for f in objects.elements_mut() {
                    for gp in f.elements_mut().filter(|e| e.name == "GeometryPath") {
                        if matches!(gp.attr("name"), Some("geometrypath" | "GeometryPath")) {
                            gp.set_attr("name", "path");
                        }
                    }
                }
            }
        }
    }
    tree.root.set_attr("Version", CURRENT_VERSION.to_string());
}

/// Very old files keep the sets inside `<DynamicsEngine><SimbodyEngine>`.
fn move_engine_sets_to_model(model: &mut Element) {
    let Some(mut de) = take_child(model, "DynamicsEngine") else {
        return;
    };
    let inner: Vec<Node> = de
        .elements_mut()
        .next()
        .map(|engine| std::mem::take(&mut engine.children))
        .unwrap_or_default();
    for n in inner {
        if let Node::Element(e) = &n {
            if model.child(&e.name).is_some() {
                continue;
            }
        }
        model.children.push(n);
    }
}

/// Every `...Set` element of the model gets its lower-case name.
fn name_sets_in_lower_case(model: &mut Element) {
    for set in model.elements_mut().filter(|e| e.name.ends_with("Set")) {
        let lower = set.name.to_lowercase();
        set.set_attr("name", lower);
    }
}

/// Bodies: inertia, nested joints (returned, upgraded), geometry, wrap
/// objects; the `ground` body becomes `<Ground>`.
fn upgrade_bodies(model: &mut Element, up: &mut Up) -> Result<Vec<Element>> {
    let mut joints: Vec<Element> = Vec::new();
    let mut ground: Option<Element> = None;
    if let Some(bodyset) = model.child_mut("BodySet") {
        bodyset.set_attr("name", "bodyset");
        if let Some(objects) = bodyset.child_mut("objects") {
            let old = std::mem::take(&mut objects.children);
            for n in old {
                let Node::Element(mut b) = n else {
                    objects.children.push(n);
                    continue;
                };
                let bname = b.name_attr().to_string();
                inertia_components_to_vec6(&mut b, up)?;
                if let Some(j) = take_nested_joint(&mut b) {
                    joints.push(nested_joint_to_jointset(j, &bname, up)?);
                }
                visible_object_to_attached_geometry(&mut b, &bname, up)?;
                wrap_objects_without_display(&mut b);
                if bname == "ground" {
                    ground = Some(ground_body_to_ground(b));
                } else {
                    objects.children.push(Node::Element(b));
                }
            }
        }
    }
    if let Some(g) = ground {
        model.remove_children("Ground");
        model.children.insert(0, Node::Element(g));
    }
    Ok(joints)
}

/// The old `ground` Body: a `<Ground>` keeping its geometry and wrap objects.
fn ground_body_to_ground(mut b: Element) -> Element {
    let mut g = Element::new("Ground").with_attr("name", "ground");
    g.line = b.line;
    for keep in ["components", "attached_geometry", "WrapObjectSet"] {
        if let Some(c) = take_child(&mut b, keep) {
            g.children.push(Node::Element(c));
        }
    }
    g
}

/// `inertia_xx..inertia_yz` -> `<inertia>` [Ixx Iyy Izz Ixy Ixz Iyz].
fn inertia_components_to_vec6(b: &mut Element, up: &Up) -> Result<()> {
    const KEYS: [&str; 6] = [
        "inertia_xx",
        "inertia_yy",
        "inertia_zz",
        "inertia_xy",
        "inertia_xz",
        "inertia_yz",
    ];
    if b.child("inertia").is_some() || KEYS.iter().all(|k| b.child(k).is_none()) {
        return Ok(());
    }
    let mut texts = Vec::new();
    for k in KEYS {
        match up.numbers(b, k, 1)? {
            Some(_) => texts.push(take_child(b, k).map(|c| c.text().trim().to_string())),
            None => texts.push(None),
        }
    }
    let texts: Vec<String> = texts
        .into_iter()
        .map(|t| t.unwrap_or_else(|| "0".into()))
        .collect();
    b.set_child_text("inertia", texts.join(" "));
    Ok(())
}

/// One mesh of an old body's VisibleObject.
struct OldMesh {
    /// Its number in the Mesh name: from 0 for `geometry_files`, from 1 for
    /// DisplayGeometry entries (as OpenSim numbers them).
    index: usize,
    file: String,
    scale: [f64; 3],
    /// DisplayGeometry `transform` (rX rY rZ tx ty tz) when not all zero.
    transform: Option<Vec<f64>>,
    color: Option<Vec<f64>>,
    opacity: Option<Vec<f64>>,
}

/// Scale factors of a VisibleObject or DisplayGeometry (1 1 1 when absent).
fn scale_of(e: &Element, up: &Up) -> Result<[f64; 3]> {
    Ok(match up.numbers(e, "scale_factors", 3)? {
        Some(v) => [v[0], v[1], v[2]],
        None => [1.0; 3],
    })
}

/// The meshes of a VisibleObject: `geometry_files` (read by OpenSim only
/// before version 20101) and `GeometrySet` DisplayGeometry entries.
fn old_meshes(vo: &Element, up: &Up) -> Result<Vec<OldMesh>> {
    let scale = scale_of(vo, up)?;
    let mut meshes = Vec::new();
    if let Some(files) = vo.child("geometry_files").filter(|_| up.version < 20101) {
        for (index, f) in files.text().split_whitespace().enumerate() {
            meshes.push(OldMesh {
                index,
                file: f.to_string(),
                scale,
                transform: None,
                color: None,
                opacity: None,
            });
        }
    }
    if let Some(objs) = vo.child("GeometrySet").and_then(|g| g.child("objects")) {
        for (k, dg) in objs.elements().enumerate() {
            let Some(file) = dg.child_text("geometry_file").filter(|f| !f.is_empty()) else {
                continue;
            };
            let s2 = scale_of(dg, up)?;
            let transform = up.numbers(dg, "transform", 6)?;
            meshes.push(OldMesh {
                index: k + 1,
                file,
                scale: [scale[0] * s2[0], scale[1] * s2[1], scale[2] * s2[2]],
                transform: transform.filter(|t| t.iter().any(|x| *x != 0.0)),
                color: up.numbers(dg, "color", 3)?,
                opacity: up.numbers(dg, "opacity", 1)?,
            });
        }
    }
    Ok(meshes)
}

/// The 4.x Mesh of an old mesh, named `<body>_geom_<i>`.
fn mesh_element(m: &OldMesh, body: &str, i: usize) -> Element {
    let mut mesh = Element::new("Mesh")
        .with_attr("name", format!("{body}_geom_{i}"))
        .with_prop("socket_frame", "..")
        .with_prop("scale_factors", fmt_numbers(&m.scale));
    if m.color.is_some() || m.opacity.is_some() {
        let mut app = Element::new("Appearance");
        if let Some(o) = &m.opacity {
            app = app.with_prop("opacity", fmt_numbers(o));
        }
        if let Some(c) = &m.color {
            app = app.with_prop("color", fmt_numbers(c));
        }
        mesh = mesh.with_child(app);
    }
    mesh.with_prop("mesh_file", m.file.clone())
}

/// VisibleObject geometry -> `attached_geometry` Meshes `<body>_geom_<i>`
/// (an empty list for an empty GeometrySet); a mesh with a display transform
/// hangs from a new offset frame `<body>_geom_frame_<i>` in the body's
/// `components`.
fn visible_object_to_attached_geometry(b: &mut Element, body: &str, up: &Up) -> Result<()> {
    let Some(vo) = take_child(b, "VisibleObject") else {
        return Ok(());
    };
    if vo.child("GeometrySet").is_some() {
        b.child_or_insert("attached_geometry");
    }
    for m in &old_meshes(&vo, up)? {
        let i = m.index;
        let mesh = mesh_element(m, body, i);
        match &m.transform {
            None => b
                .child_or_insert("attached_geometry")
                .children
                .push(Node::Element(mesh)),
            Some(t) => {
                let frame = offset_frame(
                    &format!("{body}_geom_frame_{i}"),
                    "..",
                    Some(fmt_numbers(&t[3..6])),
                    Some(fmt_numbers(&t[0..3])),
                )
                .with_child(Element::new("attached_geometry").with_child(mesh));
                b.child_or_insert("components")
                    .children
                    .push(Node::Element(frame));
            }
        }
    }
    Ok(())
}

/// Wrap objects lose their display properties.
fn wrap_objects_without_display(b: &mut Element) {
    if let Some(ws) = b.child_mut("WrapObjectSet") {
        ws.set_attr("name", "wrapobjectset");
        if let Some(objs) = ws.child_mut("objects") {
            for w in objs.elements_mut() {
                w.remove_children("VisibleObject");
                w.remove_children("display_preference");
            }
        }
    }
}

/// 4.0 development files (< 30512) list frames in a model `FrameSet`; 4.x
/// keeps them in the model's `components`.
fn frameset_to_components(model: &mut Element) {
    let Some(mut fs) = take_child(model, "FrameSet") else {
        return;
    };
    let frames: Vec<Node> = take_child(&mut fs, "objects")
        .map(|o| {
            o.children
                .into_iter()
                .filter(|n| matches!(n, Node::Element(_)))
                .collect()
        })
        .unwrap_or_default();
    model.child_or_insert("components").children.extend(frames);
}

/// The joint inside an old body's `<Joint>` holder, if any.
fn take_nested_joint(b: &mut Element) -> Option<Element> {
    let mut holder = take_child(b, "Joint")?;
    let joint = holder.elements_mut().next().map(std::mem::take);
    joint
}

/// The joint's name; an unnamed joint is named after its class in lower
/// case, as OpenSim names it.
fn joint_name(j: &Element) -> String {
    match j.attr("name") {
        Some(n) if !n.trim().is_empty() => n.trim().to_string(),
        _ => j.name.to_lowercase(),
    }
}

/// Where an old joint sits: parent and child body names and the four frame
/// vectors (location and orientation in parent, then in child).
struct OldJointFrames {
    parent: String,
    child: String,
    in_parent: [Option<String>; 2],
    in_child: [Option<String>; 2],
}

/// A joint nested in body `child` (< 30500): `parent_body`,
/// `location_in_parent`/`orientation_in_parent`, `location`/`orientation`.
fn nested_joint_to_jointset(mut j: Element, child: &str, up: &mut Up) -> Result<Element> {
    let class = j.name.clone();
    let parent = match take_child(&mut j, "parent_body") {
        Some(p) => p.text().trim().to_string(),
        None => {
            return Err(up.err(
                &j,
                format!(
                    "a {} {class} nested in <Body name=\"{child}\">: joint without <parent_body>",
                    up.version
                ),
            ))
        }
    };
    if parent.is_empty() {
        return Err(up.err(
            &j,
            format!("<parent_body> of a {} {class} is empty", up.version),
        ));
    }
    let frames = OldJointFrames {
        parent,
        child: child.to_string(),
        in_parent: [
            take_g6_vec3(&mut j, "location_in_parent", up)?,
            take_g6_vec3(&mut j, "orientation_in_parent", up)?,
        ],
        in_child: [
            take_g6_vec3(&mut j, "location", up)?,
            take_g6_vec3(&mut j, "orientation", up)?,
        ],
    };
    joint_with_offset_frames(j, frames, up)
}

/// Body named by a 4.0 development connector `connectee_name` ("../ground",
/// "rod1"): its last path element.
fn connectee_body(c: &Element) -> Option<String> {
    let t = c
        .child_text("connectee_name")
        .or_else(|| c.child_text("connected_to_name"))?;
    let last = t.rsplit('/').next().unwrap_or("").trim().to_string();
    (!last.is_empty() && last != "..").then_some(last)
}

/// A JointSet joint of 4.0 development files (30500..30504): its bodies in
/// `<connectors><Connector_PhysicalFrame_ name="parent_body">` / `child_body`,
/// its frames in `location_in_parent`.. `orientation_in_child`.
fn connector_joint_to_offset_frames(mut j: Element, up: &mut Up) -> Result<Element> {
    let class = j.name.clone();
    let v = up.version;
    let Some(conns) = take_child(&mut j, "connectors") else {
        return Err(up.err(
            &j,
            format!("a {v} {class} names its bodies in <connectors>, and this one has none"),
        ));
    };
    let body = |which: &str| -> Result<String> {
        conns
            .elements()
            .find(|c| c.name_attr() == which)
            .and_then(connectee_body)
            .ok_or_else(|| {
                up.err(
                    &conns,
                    format!(
                        "<connectors> of a {v} {class}: no <Connector_PhysicalFrame_ name=\"{which}\"> with a <connectee_name>"
                    ),
                )
            })
    };
    let (parent, child) = (body("parent_body")?, body("child_body")?);
    let frames = OldJointFrames {
        parent,
        child,
        in_parent: [
            take_g6_vec3(&mut j, "location_in_parent", up)?,
            take_g6_vec3(&mut j, "orientation_in_parent", up)?,
        ],
        in_child: [
            take_g6_vec3(&mut j, "location_in_child", up)?,
            take_g6_vec3(&mut j, "orientation_in_child", up)?,
        ],
    };
    joint_with_offset_frames(j, frames, up)
}

/// `CoordinateSet` -> `coordinates` (None when the joint has none);
/// records which joint owns each coordinate.
fn coordinate_set_to_coordinates(j: &mut Element, jname: &str, up: &mut Up) -> Option<Element> {
    let cs = take_child(j, "CoordinateSet")?;
    let mut coords = Element::new("coordinates");
    for c in cs.child("objects")?.elements() {
        let mut c = c.clone();
        c.remove_children("motion_type");
        c.remove_children("initial_value");
        up.coord_joint
            .insert(c.name_attr().to_string(), jname.to_string());
        coords.children.push(Node::Element(c));
    }
    (!coords.children.is_empty()).then_some(coords)
}

/// TransformAxis `<function><X/></function>` -> `<X name="function"/>`.
fn unwrap_transform_functions(j: &mut Element) {
    if let Some(st) = j.child_mut("SpatialTransform") {
        st.attrs.clear();
        for ax in st.elements_mut() {
            if let Some(mut w) = take_child(ax, "function") {
                if let Some(f) = w.elements_mut().next() {
                    let mut f = std::mem::take(f);
                    f.set_attr("name", "function");
                    ax.children.push(Node::Element(f));
                }
            }
        }
    }
}

/// The 4.x joint: sockets to new offset frames `<parent>_offset` and
/// `<child>_offset` (swapped when `reverse`), coordinates, frames, the rest.
fn joint_with_offset_frames(mut j: Element, fr: OldJointFrames, up: &mut Up) -> Result<Element> {
    let jname = joint_name(&j);
    let reverse = take_child(&mut j, "reverse").is_some_and(|r| r.text().trim() == "true");
    let pf = format!("{}_offset", fr.parent);
    let cf = format!("{}_offset", fr.child);
    let (sp, sc) = if reverse { (&cf, &pf) } else { (&pf, &cf) };
    let coords = coordinate_set_to_coordinates(&mut j, &jname, up);
    unwrap_transform_functions(&mut j);
    let [lp, op] = fr.in_parent;
    let [lc, oc] = fr.in_child;
    let frames = Element::new("frames")
        .with_child(offset_frame(&pf, &up.body_path(&fr.parent), lp, op))
        .with_child(offset_frame(&cf, &up.body_path(&fr.child), lc, oc));
    // Rebuild in 4.x order.
    let mut out = Element::new(j.name.clone());
    out.attrs = j.attrs.clone();
    out.set_attr("name", jname);
    out.line = j.line;
    out = out
        .with_prop("socket_parent_frame", sp.clone())
        .with_prop("socket_child_frame", sc.clone());
    if let Some(c) = coords {
        out = out.with_child(c);
    }
    out = out.with_child(frames);
    for n in j.children {
        if let Node::Element(e) = &n {
            if matches!(e.name.as_str(), "VisibleObject" | "coordinates" | "frames") {
                continue;
            }
        }
        out.children.push(n);
    }
    Ok(out)
}

/// A JointSet joint of the 30500..30504 form (bodies in `<connectors>`,
/// frames in `location_in_parent`..).
fn is_connector_joint(j: &Element, up: &Up) -> bool {
    up.version < 30505
        && (j.child("connectors").is_some() || j.child("location_in_parent").is_some())
}

/// The JointSet: joints of 4.0 development files upgraded in place, joints
/// that were nested in bodies appended (a new JointSet when the file had none).
fn upgrade_jointset(model: &mut Element, nested: Vec<Element>, up: &mut Up) -> Result<()> {
    let mut js = take_child(model, "JointSet")
        .unwrap_or_else(|| Element::new("JointSet").with_child(Element::new("objects")));
    js.set_attr("name", "jointset");
    let objs = js.child_or_insert("objects");
    let old = std::mem::take(&mut objs.children);
    for n in old {
        match n {
            Node::Element(j) if is_connector_joint(&j, up) => {
                objs.children
                    .push(Node::Element(connector_joint_to_offset_frames(j, up)?));
            }
            Node::Element(mut j) => {
                connectors_to_sockets(&mut j);
                objs.children.push(Node::Element(j));
            }
            other => objs.children.push(other),
        }
    }
    objs.children.extend(nested.into_iter().map(Node::Element));
    let pos = model
        .children
        .iter()
        .position(|n| matches!(n, Node::Element(e) if e.name == "BodySet"))
        .map(|i| i + 1)
        .unwrap_or(model.children.len());
    model.children.insert(pos, Node::Element(js));
    Ok(())
}

/// `isDisabled` (before 30509; probes 30511) -> `prop` (`appliesForce`,
/// `isEnforced` or `enabled`), its negation.
fn is_disabled_to(e: &mut Element, prop: &str) {
    if let Some(d) = take_child(e, "isDisabled") {
        let disabled = d.text().trim() == "true";
        e.set_child_text(prop, if disabled { "false" } else { "true" });
    }
}

/// 4.0 development `<connectors><Connector_X_ name="n"><connectee_name>p`
/// -> `<socket_n>p</socket_n>` (the path as written).
fn connectors_to_sockets(e: &mut Element) {
    let Some(conns) = take_child(e, "connectors") else {
        return;
    };
    for c in conns.elements() {
        let target = c
            .child_text("connectee_name")
            .or_else(|| c.child_text("connected_to_name"))
            .unwrap_or_default();
        e.set_child_text(&format!("socket_{}", c.name_attr()), target);
    }
}

/// A marker: `body` (< 30501) or `<connectors>` -> `socket_parent_frame`.
fn upgrade_marker(mk: &mut Element, up: &Up) -> Result<()> {
    body_to_socket_parent_frame(mk, up)?;
    connectors_to_sockets(mk);
    mk.remove_children("VisibleObject");
    Ok(())
}

/// `<body>X</body>` -> `<socket_parent_frame>/bodyset/X</socket_parent_frame>`.
fn body_to_socket_parent_frame(e: &mut Element, up: &Up) -> Result<()> {
    if let Some(b) = take_child(e, "body") {
        let name = b.text().trim().to_string();
        if name.is_empty() {
            let class = &e.name;
            return Err(up.err(&b, format!("<body> of a {} {class} is empty", up.version)));
        }
        e.set_child_text("socket_parent_frame", up.body_path(&name));
    }
    Ok(())
}

fn coord_path(up: &Up, name: &str) -> String {
    match up.coord_joint.get(name) {
        Some(j) => format!("/jointset/{j}/{name}"),
        None => name.to_string(),
    }
}

/// A force: `isDisabled`, connectors, bushing frames, muscle rules, path.
fn upgrade_force(f: &mut Element, up: &Up) -> Result<()> {
    is_disabled_to(f, "appliesForce");
    connectors_to_sockets(f);
    if f.name == "BushingForce" && f.child("body_1").is_some() {
        bushing_bodies_to_frames(f, up)?;
    }
    if is_muscle(f) {
        muscle_point_sets_to_geometry_path(f, up);
        muscle_pennation_angle_renamed(f, up);
        muscle_control_defaults(f, up)?;
        muscle_path_default_color(f, up);
    }
    if let Some(gp) = f.child_mut("GeometryPath") {
        path_points_to_sockets(gp, up)?;
    }
    Ok(())
}

/// A Muscle subclass (Thelen2003Muscle, Millard2012EquilibriumMuscle,
/// Schutte1993Muscle_Deprecated, RigidTendonMuscle, ...).
fn is_muscle(f: &Element) -> bool {
    f.name.contains("Muscle")
}

/// Up to 20301: a muscle's `MusclePointSet`/`MuscleWrapSet` are the
/// `PathPointSet`/`PathWrapSet` of its GeometryPath.
fn muscle_point_sets_to_geometry_path(f: &mut Element, up: &Up) {
    if up.version > 20301 {
        return;
    }
    if let Some(gp) = f.child_mut("GeometryPath") {
        rename_child(gp, "MusclePointSet", "PathPointSet");
        rename_child(gp, "MuscleWrapSet", "PathWrapSet");
        return;
    }
    let pts = take_child(f, "MusclePointSet");
    let wraps = take_child(f, "MuscleWrapSet");
    if pts.is_none() && wraps.is_none() {
        return;
    }
    let mut gp = Element::new("GeometryPath");
    for (mut s, name) in [(pts, "PathPointSet"), (wraps, "PathWrapSet")]
        .into_iter()
        .filter_map(|(s, n)| s.map(|s| (s, n)))
    {
        s.name = name.to_string();
        gp.children.push(Node::Element(s));
    }
    f.children.push(Node::Element(gp));
}

/// Up to 20301: `pennation_angle` -> `pennation_angle_at_optimal` (later
/// files' `pennation_angle` is not read by OpenSim, and is kept as written).
fn muscle_pennation_angle_renamed(f: &mut Element, up: &Up) {
    if up.version <= 20301 {
        rename_child(f, "pennation_angle", "pennation_angle_at_optimal");
    }
}

/// Before 30513: a muscle's `min_control` 0 and `max_control` 1 are dropped
/// so that the muscle's own defaults apply (Thelen2003Muscle and
/// Millard2012EquilibriumMuscle: `min_control` = their default
/// `minimum_activation`, 0.01); other values are kept.
fn muscle_control_defaults(f: &mut Element, up: &Up) -> Result<()> {
    if up.version >= 30513 {
        return Ok(());
    }
    for (prop, default) in [("min_control", 0.0), ("max_control", 1.0)] {
        if let Some(v) = up.numbers(f, prop, 1)? {
            if (v[0] - default).abs() <= 1e-14 {
                f.remove_children(prop);
            }
        }
    }
    Ok(())
}

/// Before 30516: a muscle path without a colour gets the default muscle red.
fn muscle_path_default_color(f: &mut Element, up: &Up) {
    if up.version >= 30516 {
        return;
    }
    if let Some(gp) = f.child_mut("GeometryPath") {
        if gp.child("default_color").is_none() && gp.child("Appearance").is_none() {
            let app = Element::new("Appearance").with_prop("color", "0.8 0.1 0.1");
            gp.children.insert(0, Node::Element(app));
        }
    }
}

/// Path points: `body` -> `socket_parent_frame`; ConditionalPathPoint
/// `coordinate` and MovingPathPoint `x_coordinate`.. -> coordinate sockets;
/// `XFunction`.. -> `x_location`..
fn path_points_to_sockets(gp: &mut Element, up: &Up) -> Result<()> {
    gp.remove_children("VisibleObject");
    name_unnamed_path_wraps(gp);
    let Some(objs) = gp
        .child_mut("PathPointSet")
        .and_then(|s| s.child_mut("objects"))
    else {
        return Ok(());
    };
    for p in objs.elements_mut() {
        body_to_socket_parent_frame(p, up)?;
        connectors_to_sockets(p);
        p.remove_children("VisibleObject");
        if let Some(c) = take_child(p, "coordinate") {
            p.set_child_text("socket_coordinate", coord_path(up, c.text().trim()));
        }
        for axis in ["x", "y", "z"] {
            if let Some(c) = take_child(p, &format!("{axis}_coordinate")) {
                p.set_child_text(
                    &format!("socket_{axis}_coordinate"),
                    coord_path(up, c.text().trim()),
                );
            }
            let upper = axis.to_uppercase();
            if let Some(mut old) = take_child(p, &format!("{upper}Function")) {
                old.name = format!("{axis}_location");
                p.children.push(Node::Element(old));
            }
        }
    }
    Ok(())
}

/// Unnamed PathWraps get the names OpenSim 4.6 gives them on loading
/// (`pathwrap`, then `pathwrap_0`, `pathwrap_1`.. for the duplicates), so
/// the converted file loads without OpenSim's duplicate-name warnings.
fn name_unnamed_path_wraps(gp: &mut Element) {
    let Some(objs) = gp
        .child_mut("PathWrapSet")
        .and_then(|s| s.child_mut("objects"))
    else {
        return;
    };
    let mut used: std::collections::BTreeSet<String> = objs
        .elements()
        .map(|w| w.name_attr().trim().to_string())
        .filter(|n| !n.is_empty())
        .collect();
    for w in objs.elements_mut() {
        if !w.name_attr().trim().is_empty() {
            continue;
        }
        let mut name = w.name.to_lowercase();
        let mut k = 0;
        while used.contains(&name) {
            name = format!("{}_{k}", w.name.to_lowercase());
            k += 1;
        }
        used.insert(name.clone());
        w.set_attr("name", name);
    }
}

/// One side of an old BushingForce: the body itself when its offset is
/// zero, else a new frame `<body>_offset` (vectors rounded like OpenSim).
fn bushing_side(f: &mut Element, k: u8, up: &Up) -> Result<(String, Option<Element>)> {
    let class = f.name.clone();
    let body = take_child(f, &format!("body_{k}"))
        .map(|e| e.text().trim().to_string())
        .filter(|b| !b.is_empty())
        .ok_or_else(|| {
            up.err(
                f,
                format!("a {} {class} needs <body_1> and <body_2>", up.version),
            )
        })?;
    let l = take_g6_vec3(f, &format!("location_body_{k}"), up)?;
    let o = take_g6_vec3(f, &format!("orientation_body_{k}"), up)?;
    if is_zero_vec(&l) && is_zero_vec(&o) {
        return Ok((up.body_path(&body), None));
    }
    let name = format!("{body}_offset");
    let frame = offset_frame(&name, &up.body_path(&body), l, o);
    Ok((name, Some(frame)))
}

/// BushingForce `body_1`/`location_body_1`/`orientation_body_1` (and 2) ->
/// `socket_frame1`/`socket_frame2` and their offset `frames`.
fn bushing_bodies_to_frames(f: &mut Element, up: &Up) -> Result<()> {
    let (s1, f1) = bushing_side(f, 1, up)?;
    let (s2, f2) = bushing_side(f, 2, up)?;
    let rest = std::mem::take(&mut f.children);
    f.children
        .push(Node::Element(Element::new("socket_frame1").with_text(s1)));
    f.children
        .push(Node::Element(Element::new("socket_frame2").with_text(s2)));
    let frames: Vec<Element> = [f1, f2].into_iter().flatten().collect();
    if !frames.is_empty() {
        let mut fr = Element::new("frames");
        fr.children.extend(frames.into_iter().map(Node::Element));
        f.children.push(Node::Element(fr));
    }
    f.children.extend(rest);
    Ok(())
}

/// A controller's `actuator_list` (names) -> `socket_actuators` (paths).
fn controller_actuator_list_to_socket(c: &mut Element) {
    if let Some(list) = take_child(c, "actuator_list") {
        let paths: Vec<String> = list
            .text()
            .split_whitespace()
            .map(|a| format!("/forceset/{a}"))
            .collect();
        c.set_child_text("socket_actuators", paths.join(" "));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn g6_matches_cpp_stream_default() {
        // Values as C++ `ostream << double` prints them (precision 6).
        for (x, s) in [
            (1.234567891234, "1.23457"),
            (0.123456789, "0.123457"),
            (0.220779220779221, "0.220779"),
            (1.000001234, "1"),
            (-0.017545, "-0.017545"),
            (123456789.0, "1.23457e+08"),
            (0.0000123456, "1.23456e-05"),
            (100000.0, "100000"),
            (1e6, "1e+06"),
            (-0.5, "-0.5"),
        ] {
            assert_eq!(fmt_g6(x), s, "{x}");
        }
    }

    #[test]
    fn nested_joint_becomes_jointset_entry_with_frames() {
        let src = r#"<OpenSimDocument Version="30000"><Model name="m"><BodySet><objects>
<Body name="ground"><mass>0</mass><Joint/></Body>
<Body name="b"><mass>1</mass><inertia_xx>0.1</inertia_xx><inertia_yy>0.2</inertia_yy><inertia_zz>0.3</inertia_zz>
<Joint><PinJoint name="p"><parent_body>ground</parent_body><location_in_parent>0 1.23456789 0</location_in_parent>
<orientation_in_parent>0 0 0</orientation_in_parent><location>0 0 0</location><orientation>0 0 0</orientation>
<CoordinateSet><objects><Coordinate name="q"><motion_type>rotational</motion_type></Coordinate></objects></CoordinateSet>
<reverse>true</reverse></PinJoint></Joint></Body></objects></BodySet>
<MarkerSet><objects><Marker name="mk"><body>b</body><location>0 0 1</location></Marker></objects></MarkerSet>
</Model></OpenSimDocument>"#;
        let d = crate::osim::Document::parse(src, "legacy.osim").unwrap();
        assert_eq!(d.version(), CURRENT_VERSION);
        assert_eq!(d.original_version(), 30000);
        let j = d.component("JointSet", "p").unwrap();
        // reverse swaps the sockets
        assert_eq!(j.child_text("socket_parent_frame").unwrap(), "b_offset");
        assert_eq!(j.child_text("socket_child_frame").unwrap(), "ground_offset");
        let f = j
            .child("frames")
            .unwrap()
            .child("PhysicalOffsetFrame")
            .unwrap();
        assert_eq!(f.child_text("translation").unwrap(), "0 1.23457 0");
        assert_eq!(f.child_text("socket_parent").unwrap(), "/ground");
        assert!(j
            .child("coordinates")
            .unwrap()
            .child("Coordinate")
            .unwrap()
            .child("motion_type")
            .is_none());
        let b = d.component("BodySet", "b").unwrap();
        assert_eq!(b.child_text("inertia").unwrap(), "0.1 0.2 0.3 0 0 0");
        assert!(d.component("BodySet", "ground").is_none());
        assert!(d.model_element().child("Ground").is_some());
        let mk = d.component("MarkerSet", "mk").unwrap();
        assert_eq!(mk.child_text("socket_parent_frame").unwrap(), "/bodyset/b");
    }

    /// A 3.x model around `forces` (ForceSet objects) at `version`.
    fn with_forces(version: u32, forces: &str) -> crate::osim::Document {
        let src = format!(
            r#"<OpenSimDocument Version="{version}"><Model name="m"><BodySet><objects>
<Body name="ground"><mass>0</mass><Joint/></Body>
<Body name="b"><mass>1</mass><Joint><PinJoint name="p"><parent_body>ground</parent_body>
<CoordinateSet><objects><Coordinate name="q"/></objects></CoordinateSet></PinJoint></Joint></Body>
</objects></BodySet><ForceSet><objects>{forces}</objects></ForceSet></Model></OpenSimDocument>"#
        );
        crate::osim::Document::parse(&src, "legacy.osim").unwrap()
    }

    #[test]
    fn muscle_control_defaults_follow_version_and_class() {
        let forces = r#"<Thelen2003Muscle name="t"><min_control>0</min_control><max_control>1</max_control></Thelen2003Muscle>
<Millard2012EquilibriumMuscle name="m"><min_control>0.05</min_control></Millard2012EquilibriumMuscle>
<CoordinateActuator name="a"><min_control>0</min_control></CoordinateActuator>"#;
        let d = with_forces(30000, forces);
        let t = d.component("ForceSet", "t").unwrap();
        assert!(t.child("min_control").is_none() && t.child("max_control").is_none());
        let m = d.component("ForceSet", "m").unwrap();
        assert_eq!(m.child_text("min_control").unwrap(), "0.05");
        let a = d.component("ForceSet", "a").unwrap();
        assert_eq!(a.child_text("min_control").unwrap(), "0");
        // From 30513 on, OpenSim reads a muscle's min_control 0 as written.
        let d = with_forces(30513, forces);
        let t = d.component("ForceSet", "t").unwrap();
        assert_eq!(t.child_text("min_control").unwrap(), "0");
    }

    #[test]
    fn is_disabled_becomes_applies_force() {
        let forces = r#"<Thelen2003Muscle name="off"><isDisabled>true</isDisabled></Thelen2003Muscle>
<Thelen2003Muscle name="on"><isDisabled> false </isDisabled></Thelen2003Muscle>"#;
        let d = with_forces(20303, forces);
        let off = d.component("ForceSet", "off").unwrap();
        assert_eq!(off.child_text("appliesForce").unwrap(), "false");
        assert!(off.child("isDisabled").is_none());
        let on = d.component("ForceSet", "on").unwrap();
        assert_eq!(on.child_text("appliesForce").unwrap(), "true");
    }

    #[test]
    fn bushing_with_zero_offset_connects_the_body() {
        let forces = r#"<BushingForce name="bu"><body_1>ground</body_1><body_2>b</body_2>
<location_body_1>0 0 0</location_body_1><location_body_2>0 0.123456789 0</location_body_2></BushingForce>"#;
        let d = with_forces(30000, forces);
        let bu = d.component("ForceSet", "bu").unwrap();
        assert_eq!(bu.child_text("socket_frame1").unwrap(), "/ground");
        assert_eq!(bu.child_text("socket_frame2").unwrap(), "b_offset");
        let f = bu.child("frames").unwrap();
        assert_eq!(f.elements().count(), 1);
        let fr = f.child("PhysicalOffsetFrame").unwrap();
        assert_eq!(fr.child_text("translation").unwrap(), "0 0.123457 0");
    }

    #[test]
    fn connector_joint_of_30501_gets_offset_frames() {
        let src = r#"<OpenSimDocument Version="30501"><Model name="m"><BodySet><objects>
<Body name="rod"><mass>1</mass><inertia>0 0 0 0 0 0</inertia></Body></objects></BodySet>
<FrameSet><objects/></FrameSet>
<JointSet><objects><PinJoint name="pin"><connectors>
<Connector_PhysicalFrame_ name="parent_body"><connectee_name>../ground</connectee_name></Connector_PhysicalFrame_>
<Connector_PhysicalFrame_ name="child_body"><connectee_name>rod</connectee_name></Connector_PhysicalFrame_>
</connectors><location_in_parent>0 0 0</location_in_parent><location_in_child>0 0.5 0</location_in_child>
<CoordinateSet><objects><Coordinate name="q"/></objects></CoordinateSet></PinJoint></objects></JointSet>
</Model></OpenSimDocument>"#;
        let d = crate::osim::Document::parse(src, "dp.osim").unwrap();
        let j = d.component("JointSet", "pin").unwrap();
        assert_eq!(
            j.child_text("socket_parent_frame").unwrap(),
            "ground_offset"
        );
        assert_eq!(j.child_text("socket_child_frame").unwrap(), "rod_offset");
        let frames: Vec<_> = j.child("frames").unwrap().elements().collect();
        assert_eq!(frames[0].child_text("socket_parent").unwrap(), "/ground");
        assert_eq!(
            frames[1].child_text("socket_parent").unwrap(),
            "/bodyset/rod"
        );
        assert_eq!(frames[1].child_text("translation").unwrap(), "0 0.5 0");
        assert!(d.model_element().child("FrameSet").is_none());
        d.model().unwrap();
    }

    #[test]
    fn display_geometry_becomes_named_meshes_and_frames() {
        let src = r#"<OpenSimDocument Version="30000"><Model name="m"><BodySet><objects>
<Body name="ground"><mass>0</mass><Joint/></Body>
<Body name="b"><mass>1</mass><Joint><PinJoint name="p"><parent_body>ground</parent_body></PinJoint></Joint>
<VisibleObject><GeometrySet><objects>
<DisplayGeometry><geometry_file>a.obj</geometry_file><transform>0 0 0 0 0.25 0</transform><color>1 0 0</color></DisplayGeometry>
<DisplayGeometry><geometry_file>b.obj</geometry_file><scale_factors>2 2 2</scale_factors></DisplayGeometry>
</objects></GeometrySet><scale_factors>1 1 0.5</scale_factors></VisibleObject></Body>
</objects></BodySet></Model></OpenSimDocument>"#;
        let d = crate::osim::Document::parse(src, "g.osim").unwrap();
        let b = d.component("BodySet", "b").unwrap();
        let m2 = b.child("attached_geometry").unwrap().child("Mesh").unwrap();
        assert_eq!(m2.name_attr(), "b_geom_2");
        assert_eq!(m2.child_text("scale_factors").unwrap(), "2 2 1");
        let fr = b
            .child("components")
            .unwrap()
            .child("PhysicalOffsetFrame")
            .unwrap();
        assert_eq!(fr.name_attr(), "b_geom_frame_1");
        assert_eq!(fr.child_text("translation").unwrap(), "0 0.25 0");
        let m1 = fr
            .child("attached_geometry")
            .unwrap()
            .child("Mesh")
            .unwrap();
        assert_eq!(m1.name_attr(), "b_geom_1");
        let app = m1.child("Appearance").unwrap();
        assert_eq!(app.child_text("color").unwrap(), "1 0 0");
    }
}
