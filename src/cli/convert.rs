//! `osim-spine convert IN OUT [--geometry DIR] [--drop-missing-meshes]`: models of any supported
//! version to the canonical 4.x form (validated before anything is
//! written); mesh files by extension through `crate::mesh`.

use crate::osim::Document;
use clap::Args as ClapArgs;
use std::path::{Path, PathBuf};

/// Arguments of `convert`.
#[derive(Debug, ClapArgs)]
pub struct Args {
    /// Input: a .osim model (1.9 to 4.6) or a mesh file.
    pub input: PathBuf,
    /// Output path (.osim for models; a mesh extension for meshes).
    pub output: PathBuf,
    /// Allow the output to go where an input is (it may be replaced).
    #[arg(long)]
    pub force: bool,
    /// Extra folder to search for mesh files of the model.
    #[arg(long, value_name = "DIR")]
    pub geometry: Vec<PathBuf>,
    /// Remove the references to mesh files found nowhere (the model's
    /// folder, its Geometry/, --geometry), so that OpenSim loads the output
    /// without "Couldn't find file" warnings. By default they are kept, as
    /// OpenSim's own upgrade keeps them; either way they are named.
    #[arg(long)]
    pub drop_missing_meshes: bool,
}

const MESH_EXTENSIONS: [&str; 4] = ["vtp", "stl", "obj", "ply"];

fn ext(p: &Path) -> String {
    p.extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase()
}

fn convert_checked(args: &Args) -> anyhow::Result<(Document, super::info::Summary)> {
    let doc = Document::read(&args.input)?;
    let model = super::info::typed_model(&doc)?;
    let s = super::info::summarize(&doc, &model, &args.geometry)?;
    super::info::refuse_escaping_meshes(&s)?;
    let keep = !args.drop_missing_meshes;
    let missing = doc.write_with_meshes(&args.output, &args.geometry, keep)?;
    super::warn_missing_meshes(&args.output, &missing, keep);
    Ok((doc, s))
}

/// Run `convert`; returns the exit code.
pub fn run(args: Args) -> anyhow::Result<i32> {
    // Never overwrite an input.
    let protected = crate::util::guard::Protected::default().inputs([&args.input]);
    crate::util::guard::check_outputs(&[&args.output], &protected, args.force)?;
    let (ein, eout) = (ext(&args.input), ext(&args.output));
    let in_mesh = MESH_EXTENSIONS.contains(&ein.as_str());
    let out_mesh = MESH_EXTENSIONS.contains(&eout.as_str());
    if in_mesh || out_mesh {
        if !(in_mesh && out_mesh) {
            anyhow::bail!(
                "{} -> {}: a mesh converts only to a mesh (.vtp .stl .obj .ply)",
                args.input.display(),
                args.output.display()
            );
        }
        let mesh = crate::mesh::read(&args.input)?;
        crate::mesh::write(&args.output, &mesh)?;
        crate::errln!(
            "wrote {} ({} vertices, {} triangles)",
            args.output.display(),
            mesh.vertices.len(),
            mesh.triangles.len()
        );
        return Ok(0);
    }
    if ein != "osim" && ein != "xml" {
        anyhow::bail!(
            "{}: unknown input type '.{ein}' (expected .osim or a mesh: .vtp .stl .obj .ply)",
            args.input.display()
        );
    }
    if eout != "osim" && eout != "xml" {
        anyhow::bail!(
            "{}: a model must be written to a .osim file",
            args.output.display()
        );
    }
    let (doc, s) = convert_checked(&args)?;
    crate::errln!(
        "wrote {} (version {} -> {}; {} bodies, {} joints, {} forces, {} markers)",
        args.output.display(),
        doc.original_version(),
        doc.version(),
        s.bodies.len(),
        s.joints.len(),
        s.forces_by_class.values().sum::<usize>(),
        s.markers
    );
    if !s.meshes_missing.is_empty() {
        crate::errln!(
            "note: {} of {} mesh files not found beside the model (see `osim-spine info`)",
            s.meshes_missing.len(),
            s.mesh_files
        );
    }
    for m in &s.meshes_refused {
        crate::errln!("warning: mesh {m}");
    }
    Ok(0)
}
