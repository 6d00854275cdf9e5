//! `osim-spine info MODEL [--json] [--geometry DIR]`: a summary of a model
//! (bodies, joints and coordinates, forces by class, muscles, markers, wrap
//! objects, mesh files that cannot be found or escape their folder).

use crate::osim::geometry::{self, MeshLookup};
use crate::osim::model::Model;
use crate::osim::Document;
use clap::Args as ClapArgs;
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::PathBuf;

/// Arguments of `info`.
#[derive(Debug, ClapArgs)]
pub struct Args {
    /// The .osim model (any version from 1.9 to 4.6).
    pub model: PathBuf,
    /// Print the summary as JSON.
    #[arg(long)]
    pub json: bool,
    /// Extra folder to search for mesh files (after the model's folder and its Geometry/).
    #[arg(long, value_name = "DIR")]
    pub geometry: Vec<PathBuf>,
}

/// The summary printed by `info`.
#[derive(Debug, Serialize)]
pub struct Summary {
    /// Path of the model file.
    pub file: String,
    /// The model's name.
    pub name: String,
    /// Document version as read.
    pub version_read: u32,
    /// Document version after the upgrade on reading.
    pub version: u32,
    /// Gravity in ground (m/s^2).
    pub gravity: [f64; 3],
    /// Sum of the body masses (kg).
    pub total_mass: f64,
    /// Body names.
    pub bodies: Vec<String>,
    /// Every joint.
    pub joints: Vec<JointSummary>,
    /// Number of coordinates.
    pub coordinates: usize,
    /// Number of forces by OpenSim class.
    pub forces_by_class: BTreeMap<String, usize>,
    /// Number of muscles.
    pub muscles: usize,
    /// Number of markers.
    pub markers: usize,
    /// Number of wrap objects (bodies and ground) by OpenSim class.
    pub wrap_objects: BTreeMap<String, usize>,
    /// Number of constraints.
    pub constraints: usize,
    /// Number of mesh references.
    pub mesh_files: usize,
    /// Meshes not found (`body: file`).
    pub meshes_missing: Vec<String>,
    /// Meshes refused because their path escapes the geometry folders (`body: why`).
    pub meshes_refused: Vec<String>,
}

/// One joint in the summary.
#[derive(Debug, Serialize)]
pub struct JointSummary {
    /// The joint's name.
    pub name: String,
    /// Its OpenSim class.
    pub class: String,
    /// Its parent frame's body.
    pub parent: String,
    /// Its child frame's body.
    pub child: String,
    /// Its coordinates.
    pub coordinates: Vec<CoordinateSummary>,
}

/// One coordinate: range and default in the file's units (rad or m), and
/// whether it is locked.
#[derive(Debug, Serialize)]
pub struct CoordinateSummary {
    /// The coordinate's name.
    pub name: String,
    /// `rotational`, `translational` or `coupled`.
    pub motion: String,
    /// Range [min, max] (rad or m).
    pub range: [f64; 2],
    /// Default value (rad or m).
    pub default: f64,
    /// Locked at its default.
    pub locked: bool,
}

impl CoordinateSummary {
    /// `name [lo, hi] deg` (or mm), `locked` when locked.
    fn render(&self) -> String {
        let (f, unit) = match self.motion.as_str() {
            "translational" => (1e3, "mm"),
            "rotational" => (180.0 / std::f64::consts::PI, "deg"),
            _ => (1.0, ""),
        };
        let lock = if self.locked { ", locked" } else { "" };
        format!(
            "{} [{:.0}, {:.0}]{}{unit}{lock}",
            self.name,
            self.range[0] * f,
            self.range[1] * f,
            if unit.is_empty() { "" } else { " " }
        )
    }
}

/// Build the summary of a read model.
pub fn summarize(doc: &Document, model: &Model, extra: &[PathBuf]) -> crate::Result<Summary> {
    let frames = model.joint_frames()?;
    let joints = model
        .joints
        .iter()
        .zip(frames.iter())
        .map(|(j, f)| JointSummary {
            name: j.name.clone(),
            class: j.class.clone(),
            parent: f.parent_body.clone(),
            child: f.child_body.clone(),
            coordinates: j
                .coordinates
                .iter()
                .map(|c| CoordinateSummary {
                    name: c.name.clone(),
                    motion: format!("{:?}", c.motion_type).to_lowercase(),
                    range: c.range,
                    default: c.default_value,
                    locked: c.locked,
                })
                .collect(),
        })
        .collect();
    let mut forces_by_class = BTreeMap::new();
    for f in &model.forces {
        *forces_by_class.entry(f.class().to_string()).or_insert(0) += 1;
    }
    let mut wrap_objects = BTreeMap::new();
    for w in model
        .bodies
        .iter()
        .flat_map(|b| b.wrap_objects.iter())
        .chain(model.ground.wrap_objects.iter())
    {
        *wrap_objects.entry(w.class().to_string()).or_insert(0) += 1;
    }
    let meshes = model.mesh_files();
    let mut meshes_missing = Vec::new();
    let mut meshes_refused = Vec::new();
    for (body, file) in &meshes {
        match geometry::resolve(doc.path(), file, extra) {
            MeshLookup::Found(_) => {}
            MeshLookup::Missing => meshes_missing.push(format!("{body}: {file}")),
            MeshLookup::Escapes(why) => meshes_refused.push(format!("{body}: {why}")),
        }
    }
    Ok(Summary {
        file: doc.path().display().to_string(),
        name: model.name.clone(),
        version_read: doc.original_version(),
        version: doc.version(),
        gravity: [model.gravity.x, model.gravity.y, model.gravity.z],
        total_mass: model.bodies.iter().map(|b| b.mass).sum(),
        bodies: model.bodies.iter().map(|b| b.name.clone()).collect(),
        joints,
        coordinates: model.coordinates().count(),
        forces_by_class,
        muscles: model.muscles().count(),
        markers: model.markers.len(),
        wrap_objects,
        constraints: model.constraints.len(),
        mesh_files: meshes.len(),
        meshes_missing,
        meshes_refused,
    })
}

/// Human-readable rendering of a summary.
pub fn render(s: &Summary) -> String {
    use std::fmt::Write;
    let mut o = String::new();
    let _ = writeln!(
        o,
        "model {} ({}; document version {}, held as {})",
        s.name, s.file, s.version_read, s.version
    );
    let _ = writeln!(
        o,
        "gravity {} {} {}",
        s.gravity[0], s.gravity[1], s.gravity[2]
    );
    let _ = writeln!(
        o,
        "bodies: {} (total mass {:.2} kg)",
        s.bodies.len(),
        s.total_mass
    );
    let _ = writeln!(
        o,
        "joints: {} ({} coordinates)",
        s.joints.len(),
        s.coordinates
    );
    for j in &s.joints {
        let _ = writeln!(
            o,
            "  {} [{}] {} -> {}: {}",
            j.name,
            j.class,
            j.parent,
            j.child,
            j.coordinates
                .iter()
                .map(CoordinateSummary::render)
                .collect::<Vec<_>>()
                .join("; ")
        );
    }
    let _ = writeln!(o, "forces: {}", s.forces_by_class.values().sum::<usize>());
    for (c, n) in &s.forces_by_class {
        let _ = writeln!(o, "  {c}: {n}");
    }
    let _ = writeln!(o, "muscles: {}", s.muscles);
    let _ = writeln!(o, "markers: {}", s.markers);
    let _ = writeln!(o, "constraints: {}", s.constraints);
    let _ = writeln!(
        o,
        "wrap objects: {}",
        s.wrap_objects.values().sum::<usize>()
    );
    for (c, n) in &s.wrap_objects {
        let _ = writeln!(o, "  {c}: {n}");
    }
    let _ = writeln!(
        o,
        "mesh files: {} ({} not found, {} refused)",
        s.mesh_files,
        s.meshes_missing.len(),
        s.meshes_refused.len()
    );
    // The first few missing meshes, then a count (--json lists them all).
    const SHOWN: usize = 5;
    for m in s.meshes_missing.iter().take(SHOWN) {
        let _ = writeln!(o, "  not found: {m}");
    }
    if s.meshes_missing.len() > SHOWN {
        let _ = writeln!(
            o,
            "  ... and {} more not found (all in --json; add their folder with --geometry DIR)",
            s.meshes_missing.len() - SHOWN
        );
    }
    for m in &s.meshes_refused {
        let _ = writeln!(o, "  refused: {m}");
    }
    o
}

/// Run `info`; returns the exit code.
pub fn run(args: Args) -> anyhow::Result<i32> {
    let doc = Document::read(&args.model)?;
    let model = typed_model(&doc)?;
    let s = summarize(&doc, &model, &args.geometry)?;
    refuse_escaping_meshes(&s)?;
    for w in crate::osim::lint::warnings(&model) {
        crate::errln!("warning: {}: {w}", args.model.display());
    }
    if args.json {
        crate::outln!("{}", serde_json::to_string_pretty(&s)?);
    } else {
        crate::out!("{}", render(&s));
    }
    Ok(0)
}

/// Error when a mesh_file is absolute or climbs out with `..` (reported, never followed).
pub fn refuse_escaping_meshes(s: &Summary) -> anyhow::Result<()> {
    if let Some(first) = s.meshes_refused.first() {
        anyhow::bail!(
            "{}: <Mesh> of body {first}; refusing to follow it ({} such mesh file(s))",
            s.file,
            s.meshes_refused.len()
        );
    }
    Ok(())
}

/// The typed model of `doc`. An error in a legacy file (upgraded on
/// reading) says which version the file was written in, since the names it
/// gives are those of the 4.x upgrade (`docs/legacy-upgrade.md`).
pub fn typed_model(doc: &Document) -> anyhow::Result<crate::osim::Model> {
    let v = doc.original_version();
    doc.model().map_err(|e| {
        let e = anyhow::Error::from(e);
        if v < 40000 {
            e.context(format!(
                "a Version {v} document, checked after its upgrade to 4.x (the names below are those of the upgrade, see docs/legacy-upgrade.md)"
            ))
        } else {
            e
        }
    })
}
