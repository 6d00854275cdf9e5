//! Upgrade of OpenSim 1.9 / 2.x / 3.x documents (Version < 40000) to the 4.x
//! form, following what OpenSim 4.6 does when it reads them:
//!
//! - the `ground` Body becomes `<Ground>` (with its geometry and wrap objects);
//! - `inertia_xx..inertia_yz` become `<inertia>` [Ixx Iyy Izz Ixy Ixz Iyz];
//! - joints nested in bodies (`<Joint><XJoint>`) move to the `JointSet`, with
//!   parent/child PhysicalOffsetFrames `<parent>_offset` / `<child>_offset`
//!   from `location_in_parent`/`orientation_in_parent` and
//!   `location`/`orientation`; `reverse` = true swaps the parent and child
//!   frame sockets (as OpenSim's Joint upgrade does); `CoordinateSet`
//!   becomes the `coordinates` list; TransformAxis `<function>` wrappers are
//!   unwrapped;
//! - BushingForce `body_1`/`location_body_1`/`orientation_body_1` (and 2)
//!   become frames `<body>_offset` with `socket_frame1`/`socket_frame2`;
//! - marker and path point `body` become `socket_parent_frame`;
//!   ConditionalPathPoint `coordinate` becomes `socket_coordinate`;
//!   MovingPathPoint `x_coordinate`.. become `socket_x_coordinate`..;
//! - VisibleObject geometry (`geometry_files` or `GeometrySet`/
//!   `DisplayGeometry`) becomes `attached_geometry` Meshes `<body>_geom_<i>`
//!   (scale factors multiplied; display transforms are not kept);
//! - coupler `isDisabled` becomes `isEnforced`; obsolete `motion_type` and
//!   `initial_value` of coordinates are dropped;
//! - Thelen2003Muscle `pennation_angle` -> `pennation_angle_at_optimal`,
//!   `Vmax` -> `max_contraction_velocity`;
//! - frame vectors created from old properties are rounded to 6 significant
//!   digits exactly as OpenSim 4.6 does ([`fmt_g6`]).
//!
//! The document then says Version="40600".

use super::document::{fmt_numbers, loc, parse_numbers, CURRENT_VERSION};
use super::xml::{Element, Node, XmlTree};
use crate::error::{Error, Result};
use std::collections::BTreeMap;
use std::path::Path;

struct Up<'a> {
    file: &'a Path,
    /// Coordinate name -> joint name (for socket paths).
    coord_joint: BTreeMap<String, String>,
}

impl Up<'_> {
    fn err(&self, e: &Element, msg: impl Into<String>) -> Error {
        Error::parse(self.file, loc(e), msg)
    }

    /// Socket path of a body named in an old file ("ground" or a body).
    fn body_path(&self, name: &str) -> String {
        if name == "ground" {
            "/ground".to_string()
        } else {
            format!("/bodyset/{name}")
        }
    }

    fn vec3_text(&self, e: &Element, prop: &str) -> Result<[f64; 3]> {
        match e.child(prop) {
            None => Ok([0.0; 3]),
            Some(c) => {
                let v = parse_numbers(&c.text(), c, self.file)?;
                match v.as_slice() {
                    [a, b, c3] => Ok([*a, *b, *c3]),
                    _ => Err(self.err(c, format!("expected 3 numbers, found {}", v.len()))),
                }
            }
        }
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
pub fn fmt_g6(x: f64) -> String {
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

/// Numbers of `text` rounded through [`fmt_g6`] (None stays None).
fn g6_text(text: Option<String>, at: &Element, up: &Up) -> Result<Option<String>> {
    match text {
        None => Ok(None),
        Some(t) => {
            let v = parse_numbers(&t, at, up.file)?;
            Ok(Some(
                v.iter().map(|x| fmt_g6(*x)).collect::<Vec<_>>().join(" "),
            ))
        }
    }
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

/// Upgrade `tree` (document version `version` < 40000) in place.
pub fn upgrade(tree: &mut XmlTree, version: u32, path: &Path) -> Result<()> {
    let mut up = Up {
        file: path,
        coord_joint: BTreeMap::new(),
    };
    let model = tree
        .root
        .child_mut("Model")
        .ok_or_else(|| Error::parse(path, "<OpenSimDocument>", "no <Model>"))?;
    // Very old files keep the sets inside <DynamicsEngine><SimbodyEngine>.
    if let Some(mut de) = take_child(model, "DynamicsEngine") {
        if let Some(engine) = de.elements_mut().next() {
            let inner: Vec<Node> = std::mem::take(&mut engine.children);
            for n in inner {
                if let Node::Element(e) = &n {
                    if model.child(&e.name).is_some() {
                        continue;
                    }
                }
                model.children.push(n);
            }
        }
    }

    // 1. Bodies: ground, inertia, joints, geometry.
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
                upgrade_inertia(&mut b, &up)?;
                if let Some(mut jholder) = take_child(&mut b, "Joint") {
                    if let Some(j) = jholder.elements_mut().next() {
                        let j = std::mem::take(j);
                        joints.push(upgrade_joint(j, &bname, &mut up)?);
                    }
                }
                upgrade_visible(&mut b, &bname, &up)?;
                upgrade_wraps(&mut b);
                if bname == "ground" {
                    let mut g = Element::new("Ground").with_attr("name", "ground");
                    g.line = b.line;
                    for keep in ["attached_geometry", "WrapObjectSet"] {
                        if let Some(c) = take_child(&mut b, keep) {
                            g.children.push(Node::Element(c));
                        }
                    }
                    ground = Some(g);
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
    // 2. JointSet.
    let mut js = model
        .child("JointSet")
        .cloned()
        .unwrap_or_else(|| super::document::empty_set("JointSet"));
    js.set_attr("name", "jointset");
    {
        let objs = js.child_or_insert("objects");
        for j in joints {
            objs.children.push(Node::Element(j));
        }
    }
    model.remove_children("JointSet");
    let pos = model
        .children
        .iter()
        .position(|n| matches!(n, Node::Element(e) if e.name == "BodySet"))
        .map(|i| i + 1)
        .unwrap_or(model.children.len());
    model.children.insert(pos, Node::Element(js));

    // 3. Sets: names, markers, forces, constraints.
    for set in model.elements_mut().filter(|e| e.name.ends_with("Set")) {
        let lower = set.name.to_lowercase();
        set.set_attr("name", lower);
    }
    if let Some(objs) = model
        .child_mut("MarkerSet")
        .and_then(|s| s.child_mut("objects"))
    {
        for mk in objs.elements_mut() {
            upgrade_body_socket(mk, &up)?;
            mk.remove_children("VisibleObject");
        }
    }
    if let Some(objs) = model
        .child_mut("ForceSet")
        .and_then(|s| s.child_mut("objects"))
    {
        for f in objs.elements_mut() {
            upgrade_force(f, &up)?;
        }
    }
    if let Some(objs) = model
        .child_mut("ConstraintSet")
        .and_then(|s| s.child_mut("objects"))
    {
        for c in objs.elements_mut() {
            if let Some(d) = take_child(c, "isDisabled") {
                let disabled = d.text().trim() == "true";
                c.set_child_text("isEnforced", if disabled { "false" } else { "true" });
            }
        }
    }
    let _ = version;
    tree.root.set_attr("Version", CURRENT_VERSION.to_string());
    Ok(())
}

fn upgrade_inertia(b: &mut Element, up: &Up) -> Result<()> {
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
        match take_child(b, k) {
            Some(c) => {
                let t = c.text().trim().to_string();
                let v = parse_numbers(&t, &c, up.file)?;
                if v.len() != 1 {
                    return Err(up.err(&c, "expected one number"));
                }
                texts.push(t);
            }
            None => texts.push("0".into()),
        }
    }
    b.set_child_text("inertia", texts.join(" "));
    Ok(())
}

fn upgrade_joint(mut j: Element, child: &str, up: &mut Up) -> Result<Element> {
    let jname = match j.attr("name") {
        Some(n) if !n.trim().is_empty() => n.trim().to_string(),
        _ => format!("{}_{}", j.name.to_lowercase(), child),
    };
    j.set_attr("name", jname.clone());
    let parent = match take_child(&mut j, "parent_body") {
        Some(p) => p.text().trim().to_string(),
        None => return Err(up.err(&j, "joint without <parent_body>")),
    };
    if parent.is_empty() {
        return Err(up.err(&j, "<parent_body> is empty"));
    }
    up.vec3_text(&j, "location_in_parent")?;
    up.vec3_text(&j, "orientation_in_parent")?;
    up.vec3_text(&j, "location")?;
    up.vec3_text(&j, "orientation")?;
    let jc = j.clone();
    let lp = g6_text(
        take_child(&mut j, "location_in_parent").map(|e| e.text()),
        &jc,
        up,
    )?;
    let op = g6_text(
        take_child(&mut j, "orientation_in_parent").map(|e| e.text()),
        &jc,
        up,
    )?;
    let lc = g6_text(take_child(&mut j, "location").map(|e| e.text()), &jc, up)?;
    let oc = g6_text(take_child(&mut j, "orientation").map(|e| e.text()), &jc, up)?;
    let reverse = take_child(&mut j, "reverse")
        .map(|r| r.text().trim() == "true")
        .unwrap_or(false);
    let pf = format!("{parent}_offset");
    let cf = format!("{child}_offset");
    let (sp, sc) = if reverse {
        (cf.clone(), pf.clone())
    } else {
        (pf.clone(), cf.clone())
    };

    // Coordinates: CoordinateSet/objects -> coordinates.
    let mut coords = Element::new("coordinates");
    if let Some(cs) = take_child(&mut j, "CoordinateSet") {
        if let Some(objs) = cs.child("objects") {
            for c in objs.elements() {
                let mut c = c.clone();
                c.remove_children("motion_type");
                c.remove_children("initial_value");
                up.coord_joint
                    .insert(c.name_attr().to_string(), jname.clone());
                coords.children.push(Node::Element(c));
            }
        }
    }
    // SpatialTransform: unwrap <function>.
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
    let frames = Element::new("frames")
        .with_child(offset_frame(&pf, &up.body_path(&parent), lp, op))
        .with_child(offset_frame(&cf, &up.body_path(child), lc, oc));
    // Rebuild in 4.x order.
    let mut out = Element::new(j.name.clone());
    out.attrs = j.attrs.clone();
    out.line = j.line;
    out = out
        .with_prop("socket_parent_frame", sp)
        .with_prop("socket_child_frame", sc)
        .with_child(coords)
        .with_child(frames);
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

fn upgrade_visible(b: &mut Element, body: &str, up: &Up) -> Result<()> {
    let Some(vo) = take_child(b, "VisibleObject") else {
        return Ok(());
    };
    let scale = match vo.child("scale_factors") {
        Some(c) => {
            let v = parse_numbers(&c.text(), c, up.file)?;
            if v.len() == 3 {
                [v[0], v[1], v[2]]
            } else {
                [1.0; 3]
            }
        }
        None => [1.0; 3],
    };
    let mut meshes: Vec<(String, [f64; 3])> = Vec::new();
    if let Some(files) = vo.child("geometry_files") {
        for f in files.text().split_whitespace() {
            meshes.push((f.to_string(), scale));
        }
    }
    if let Some(objs) = vo.child("GeometrySet").and_then(|g| g.child("objects")) {
        for dg in objs.elements() {
            let Some(file) = dg.child_text("geometry_file").filter(|f| !f.is_empty()) else {
                continue;
            };
            let s2 = match dg.child("scale_factors") {
                Some(c) => {
                    let v = parse_numbers(&c.text(), c, up.file)?;
                    if v.len() == 3 {
                        [v[0], v[1], v[2]]
                    } else {
                        [1.0; 3]
                    }
                }
                None => [1.0; 3],
            };
            meshes.push((file, [scale[0] * s2[0], scale[1] * s2[1], scale[2] * s2[2]]));
        }
    }
    let ag = b.child_or_insert("attached_geometry");
    for (i, (file, s)) in meshes.into_iter().enumerate() {
        ag.children.push(Node::Element(
            Element::new("Mesh")
                .with_attr("name", format!("{body}_geom_{i}"))
                .with_prop("socket_frame", "..")
                .with_prop("scale_factors", fmt_numbers(&s))
                .with_prop("mesh_file", file),
        ));
    }
    Ok(())
}

fn upgrade_wraps(b: &mut Element) {
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

/// `<body>X</body>` -> `<socket_parent_frame>/bodyset/X</socket_parent_frame>`.
fn upgrade_body_socket(e: &mut Element, up: &Up) -> Result<()> {
    if let Some(b) = take_child(e, "body") {
        let name = b.text().trim().to_string();
        if name.is_empty() {
            return Err(up.err(&b, "<body> is empty"));
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

fn upgrade_force(f: &mut Element, up: &Up) -> Result<()> {
    if f.name == "BushingForce" && f.child("body_1").is_some() {
        let b1 = take_child(f, "body_1")
            .map(|e| e.text().trim().to_string())
            .unwrap_or_default();
        let b2 = take_child(f, "body_2")
            .map(|e| e.text().trim().to_string())
            .unwrap_or_default();
        if b1.is_empty() || b2.is_empty() {
            return Err(up.err(f, "BushingForce needs <body_1> and <body_2>"));
        }
        up.vec3_text(f, "location_body_1")?;
        up.vec3_text(f, "orientation_body_1")?;
        up.vec3_text(f, "location_body_2")?;
        up.vec3_text(f, "orientation_body_2")?;
        let fc = f.clone();
        let l1 = g6_text(take_child(f, "location_body_1").map(|e| e.text()), &fc, up)?;
        let o1 = g6_text(
            take_child(f, "orientation_body_1").map(|e| e.text()),
            &fc,
            up,
        )?;
        let l2 = g6_text(take_child(f, "location_body_2").map(|e| e.text()), &fc, up)?;
        let o2 = g6_text(
            take_child(f, "orientation_body_2").map(|e| e.text()),
            &fc,
            up,
        )?;
        let (n1, n2) = (format!("{b1}_offset"), format!("{b2}_offset"));
        let frames = Element::new("frames")
            .with_child(offset_frame(&n1, &up.body_path(&b1), l1, o1))
            .with_child(offset_frame(&n2, &up.body_path(&b2), l2, o2));
        let rest = std::mem::take(&mut f.children);
        f.children
            .push(Node::Element(Element::new("socket_frame1").with_text(n1)));
        f.children
            .push(Node::Element(Element::new("socket_frame2").with_text(n2)));
        f.children.push(Node::Element(frames));
        f.children.extend(rest);
    }
    if f.name == "Thelen2003Muscle" {
        rename_child(f, "pennation_angle", "pennation_angle_at_optimal");
        rename_child(f, "Vmax", "max_contraction_velocity");
    }
    if let Some(gp) = f.child_mut("GeometryPath") {
        gp.remove_children("VisibleObject");
        if let Some(objs) = gp
            .child_mut("PathPointSet")
            .and_then(|s| s.child_mut("objects"))
        {
            for p in objs.elements_mut() {
                upgrade_body_socket(p, up)?;
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
        }
    }
    Ok(())
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
}
