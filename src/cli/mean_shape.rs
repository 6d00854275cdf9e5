//! `osim-spine mean-shape MESHES... --out MESH`: the mean of meshes in
//! vertex correspondence (same vertex count and triangles) by generalised
//! Procrustes analysis ([`crate::mesh::gpa_meshes`]), e.g. a mean sacrum
//! from segmentations exported from one template.

use crate::error::Error;
use clap::Args as ClapArgs;
use std::path::PathBuf;

/// Arguments of `mean-shape`.
#[derive(Debug, ClapArgs)]
pub struct Args {
    /// Input meshes (at least two), in vertex correspondence.
    #[arg(required = true, num_args = 2..)]
    pub meshes: Vec<PathBuf>,
    /// Output mesh (format by extension).
    #[arg(long, value_name = "MESH")]
    pub out: PathBuf,
    /// Allow the output to go where an input is (it may be replaced).
    #[arg(long)]
    pub force: bool,
    /// Remove size differences too (similarity Procrustes); by default
    /// only position and orientation are removed.
    #[arg(long)]
    pub scale: bool,
}

/// Run `mean-shape`; returns the exit code.
pub fn run(args: Args) -> anyhow::Result<i32> {
    // Never overwrite an input.
    let protected = crate::util::guard::Protected::default().inputs(&args.meshes);
    crate::util::guard::check_outputs(&[&args.out], &protected, args.force)?;
    let mut meshes = Vec::new();
    for p in &args.meshes {
        meshes.push(crate::mesh::read(p)?);
    }
    let fmt = crate::mesh::Format::from_path(&args.out)?;
    let (mean, res) = crate::mesh::gpa_meshes(&meshes, args.scale, 1e-12).map_err(|e| {
        Error::invalid(
            "mean-shape",
            format!(
                "{e} (inputs: {})",
                args.meshes
                    .iter()
                    .map(|p| p.display().to_string())
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        )
    })?;
    crate::util::write_atomic(&args.out, &crate::mesh::to_bytes(fmt, &mean))?;
    crate::outln!(
        "mean of {} meshes ({} vertices): RMS distance to the mean {:.3} mm after {} iterations; wrote {}",
        meshes.len(),
        mean.vertices.len(),
        res.rms * 1e3,
        res.iterations,
        args.out.display()
    );
    Ok(0)
}
