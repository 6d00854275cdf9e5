//! [`Document`]: an .osim file as a lossless XML tree in canonical 4.x form,
//! with an editing API (components by set and name, properties) used by
//! every part of the tool that reads or writes models. Typed property
//! helpers are in `props`, the typed snapshot ([`Document::model`]) in
//! `model`.

use super::legacy::{CURRENT_VERSION, OLDEST_VERSION};
use super::props::loc;
use super::xml::{self, Element, Node, XmlTree};
use crate::error::{Error, Result};
use std::path::{Path, PathBuf};

/// The component sets of a Model (tag names), in the order OpenSim writes them.
pub(crate) const SETS: [&str; 9] = [
    "BodySet",
    "JointSet",
    "ControllerSet",
    "ConstraintSet",
    "ForceSet",
    "MarkerSet",
    "ContactGeometrySet",
    "ProbeSet",
    "ComponentSet",
];

/// An OpenSim document held as its XML tree (canonical 4.x form).
#[derive(Debug, Clone)]
pub struct Document {
    tree: XmlTree,
    path: PathBuf,
    original_version: u32,
}

impl Document {
    /// Read and check a .osim file (size-capped), upgrading 2.x/3.x documents.
    pub fn read(path: impl AsRef<Path>) -> Result<Document> {
        let path = path.as_ref();
        let text = xml::read_file_capped(path)?;
        Document::parse(&text, path)
    }

    /// Parse .osim text; `path` names the source in error messages.
    pub fn parse(text: &str, path: impl AsRef<Path>) -> Result<Document> {
        let path = path.as_ref().to_path_buf();
        let mut tree = xml::parse(text, &path)?;
        let root = &tree.root;
        if root.name != "OpenSimDocument" {
            return Err(Error::parse(
                &path,
                loc(root),
                format!(
                    "root element is <{}>, expected <OpenSimDocument>",
                    root.name
                ),
            ));
        }
        let vtext = root.attr("Version").ok_or_else(|| {
            Error::parse(
                &path,
                loc(root),
                "missing the Version attribute of <OpenSimDocument>",
            )
        })?;
        let version: u32 = vtext.trim().parse().map_err(|_| {
            Error::parse(
                &path,
                loc(root),
                format!("Version \"{vtext}\" is not an integer"),
            )
        })?;
        if !(OLDEST_VERSION..=CURRENT_VERSION).contains(&version) {
            return Err(Error::parse(
                &path,
                loc(root),
                format!(
                    "unknown document Version {version} (supported: {OLDEST_VERSION}..{CURRENT_VERSION}, OpenSim 1.9 to 4.6)"
                ),
            ));
        }
        let models: Vec<&Element> = root.elements().filter(|e| e.name == "Model").collect();
        match models.len() {
            1 => {}
            0 => {
                return Err(Error::parse(
                    &path,
                    loc(root),
                    "no <Model> element in <OpenSimDocument>",
                ));
            }
            _ => {
                return Err(Error::parse(
                    &path,
                    loc(models[1]),
                    "more than one <Model> in the document",
                ));
            }
        }
        if version < 40000 {
            super::legacy::upgrade(&mut tree, version, &path)?;
        } else if version < CURRENT_VERSION {
            super::legacy::upgrade_4x(&mut tree);
        }
        Ok(Document {
            tree,
            path,
            original_version: version,
        })
    }

    /// An empty 4.x model document named `name` (ground and empty sets).
    pub fn new_model(name: &str) -> Document {
        let mut model = Element::new("Model").with_attr("name", name);
        model.children.push(Node::Element(
            Element::new("Ground").with_attr("name", "ground"),
        ));
        model.children.push(Node::Element(
            Element::new("gravity").with_text("0 -9.8066499999999994 0"),
        ));
        for s in SETS {
            model.children.push(Node::Element(empty_set(s)));
        }
        let root = Element::new("OpenSimDocument")
            .with_attr("Version", CURRENT_VERSION.to_string())
            .with_child(model);
        Document {
            tree: XmlTree {
                declaration: Some("version=\"1.0\" encoding=\"UTF-8\"".into()),
                prolog: vec![],
                root,
                epilog: vec![],
                source_len: 0,
            },
            path: PathBuf::from(format!("<new model {name}>")),
            original_version: CURRENT_VERSION,
        }
    }

    /// The file this document came from (or a placeholder), for messages.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Version of the document as held (40600 for upgraded legacy files,
    /// the file's own for 4.x files).
    pub fn version(&self) -> u32 {
        self.tree
            .root
            .attr("Version")
            .and_then(|v| v.trim().parse().ok())
            .unwrap_or(CURRENT_VERSION)
    }

    /// Version the file had when read (before any upgrade).
    pub fn original_version(&self) -> u32 {
        self.original_version
    }

    /// The XML tree.
    pub fn tree(&self) -> &XmlTree {
        &self.tree
    }

    /// Serialise (deterministic, tab-indented).
    pub fn to_xml_string(&self) -> String {
        self.tree.to_xml_string()
    }

    /// Write atomically to `path`.
    pub fn write(&self, path: impl AsRef<Path>) -> Result<()> {
        crate::util::write_atomic(path.as_ref(), self.to_xml_string().as_bytes())
    }

    /// The files that put this model at `out` so that OpenSim finds all
    /// its meshes: the meshes found where this document's own file looks
    /// (and in `extra`) but not beside `out`, bound for `out`'s
    /// `Geometry/`, then the model itself, last. References to meshes found
    /// nowhere are removed from the written model unless `keep_missing`
    /// (they are display-only, and OpenSim would warn on every load); they
    /// are returned either way.
    #[allow(clippy::type_complexity)]
    pub fn files_for(
        &self,
        out: &Path,
        extra: &[PathBuf],
        keep_missing: bool,
    ) -> Result<(Vec<(PathBuf, Vec<u8>)>, Vec<String>)> {
        use super::geometry::{drop_meshes, mesh_copies, mesh_files};
        let copies = mesh_copies(&mesh_files(self.model_element()), self.path(), out, extra)?;
        let xml = if keep_missing || copies.missing.is_empty() {
            self.to_xml_string()
        } else {
            let mut doc = self.clone();
            drop_meshes(doc.model_element_mut(), &copies.missing);
            doc.to_xml_string()
        };
        let mut files = copies.files;
        files.push((out.to_path_buf(), xml.into_bytes()));
        Ok((files, copies.missing))
    }

    /// Write [`Self::files_for`] (all or nothing); returns the meshes found
    /// nowhere.
    pub fn write_with_meshes(
        &self,
        out: &Path,
        extra: &[PathBuf],
        keep_missing: bool,
    ) -> Result<Vec<String>> {
        let (files, missing) = self.files_for(out, extra, keep_missing)?;
        crate::util::write_all_or_nothing(&files)?;
        Ok(missing)
    }

    /// The `<Model>` element.
    pub fn model_element(&self) -> &Element {
        // `parse`/`new_model` guarantee exactly one Model child.
        self.tree
            .root
            .child("Model")
            .expect("Document invariant: one <Model>")
    }

    /// The `<Model>` element, mutable.
    pub fn model_element_mut(&mut self) -> &mut Element {
        self.tree
            .root
            .child_mut("Model")
            .expect("Document invariant: one <Model>")
    }

    /// The `<objects>` of set `set` (e.g. "BodySet"), if the set exists.
    pub(crate) fn set_objects(&self, set: &str) -> Option<&Element> {
        self.model_element().child(set)?.child("objects")
    }

    /// The `<objects>` of set `set`, created (with the set) when absent.
    pub fn set_objects_mut(&mut self, set: &str) -> &mut Element {
        let model = self.model_element_mut();
        if model.child(set).is_none() {
            model.children.push(Node::Element(empty_set(set)));
        }
        model.child_or_insert(set).child_or_insert("objects")
    }

    /// All components of a set, in file order.
    pub fn components(&self, set: &str) -> Vec<&Element> {
        self.set_objects(set)
            .map(|o| o.elements().collect())
            .unwrap_or_default()
    }

    /// The component named `name` in set `set`.
    pub fn component(&self, set: &str, name: &str) -> Option<&Element> {
        self.set_objects(set)?
            .elements()
            .find(|e| e.attr("name") == Some(name))
    }

    /// The component named `name` in set `set`, mutable.
    pub fn component_mut(&mut self, set: &str, name: &str) -> Option<&mut Element> {
        self.model_element_mut()
            .child_mut(set)?
            .child_mut("objects")?
            .elements_mut()
            .find(|e| e.attr("name") == Some(name))
    }

    /// Append a component to a set; refuses a name already in the set.
    pub fn insert_component(&mut self, set: &str, component: Element) -> Result<()> {
        let name = component.name_attr().to_string();
        if name.is_empty() {
            return Err(Error::invalid(
                self.path.display().to_string(),
                format!("cannot insert an unnamed <{}> into {set}", component.name),
            ));
        }
        if self.component(set, &name).is_some() {
            return Err(Error::invalid(
                self.path.display().to_string(),
                format!("{set} already has a component named '{name}'"),
            ));
        }
        self.set_objects_mut(set)
            .children
            .push(Node::Element(component));
        Ok(())
    }

    /// Replace the component named `name` in `set` (keeping its position);
    /// returns the old element.
    pub fn replace_component(
        &mut self,
        set: &str,
        name: &str,
        component: Element,
    ) -> Result<Element> {
        let ctx = self.path.display().to_string();
        let slot = self
            .component_mut(set, name)
            .ok_or_else(|| Error::invalid(ctx, format!("{set} has no component named '{name}'")))?;
        Ok(std::mem::replace(slot, component))
    }

    /// Set a property (direct child) of the Model element.
    pub fn set_model_property(&mut self, name: &str, text: impl Into<String>) {
        self.model_element_mut().set_child_text(name, text);
    }
}

/// `<XSet name="xset"><objects /><groups /></XSet>`.
pub(crate) fn empty_set(tag: &str) -> Element {
    Element::new(tag)
        .with_attr("name", tag.to_lowercase())
        .with_child(Element::new("objects"))
        .with_child(Element::new("groups"))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::osim::props::{f64_prop, set_f64, set_vec3, vec3_prop};
    use nalgebra::Vector3;

    #[test]
    fn set_editing() {
        let mut d = Document::new_model("m");
        let b = Element::new("Body")
            .with_attr("name", "L5")
            .with_prop("mass", "1.2");
        d.insert_component("BodySet", b.clone()).unwrap();
        assert!(
            d.insert_component("BodySet", b).is_err(),
            "duplicate accepted"
        );
        assert_eq!(d.components("BodySet").len(), 1);
        let c = d.component_mut("BodySet", "L5").unwrap();
        set_f64(c, "mass", 2.5);
        set_vec3(c, "mass_center", &Vector3::new(0.1, 0.0, -0.0));
        let c = d.component("BodySet", "L5").unwrap();
        assert_eq!(f64_prop(c, "mass", d.path()).unwrap(), 2.5);
        assert_eq!(
            vec3_prop(c, "mass_center", d.path()).unwrap(),
            Vector3::new(0.1, 0.0, 0.0)
        );
        let old = d
            .replace_component(
                "BodySet",
                "L5",
                Element::new("Body").with_attr("name", "L4"),
            )
            .unwrap();
        assert_eq!(old.name_attr(), "L5");
        assert!(d.component("BodySet", "L4").is_some());
        // Re-parse what we write.
        let text = d.to_xml_string();
        let d2 = Document::parse(&text, "mem.osim").unwrap();
        assert_eq!(d2.version(), CURRENT_VERSION);
    }

    #[test]
    fn typed_getters_reject_bad_values() {
        let e = Element::new("Body")
            .with_attr("name", "b")
            .with_prop("mass", "nan")
            .with_prop("mass_center", "1 2")
            .with_prop("x", "abc");
        let f = Path::new("f.osim");
        assert!(f64_prop(&e, "mass", f)
            .unwrap_err()
            .to_string()
            .contains("not finite"));
        assert!(vec3_prop(&e, "mass_center", f)
            .unwrap_err()
            .to_string()
            .contains("expected 3"));
        assert!(f64_prop(&e, "x", f)
            .unwrap_err()
            .to_string()
            .contains("not a number"));
        assert!(f64_prop(&e, "nothing", f)
            .unwrap_err()
            .to_string()
            .contains("missing required"));
    }
}
