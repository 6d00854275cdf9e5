//! Inputs for the `palpate` benchmark (benches/palpate.sh): the default
//! base model's vertebrae at the default pose written (a) as a folder of
//! 18 binary STL meshes in LPS millimetres and (b) voxelised into a
//! 512 x 512 x 400 NIfTI label map (0.8 x 0.8 x 1.25 mm, TotalSegmentator
//! labels, 18 labels).
//!
//! `cargo run --release --example palpate_inputs -- OUT_DIR`

use nalgebra::{Matrix3, Matrix4, Point3, Vector3};
use osim_spine::base::kin::Kinematics;
use osim_spine::landmarks::{Frame, Level};
use osim_spine::mesh::{self, TriMesh};
use osim_spine::osim::Document;
use osim_spine::segmentation::voxelise::{self, HeaderTransform};
use std::path::PathBuf;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let out = PathBuf::from(
        std::env::args()
            .nth(1)
            .ok_or("usage: palpate_inputs OUT_DIR")?,
    );
    let base = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("base_model");
    let doc = Document::read(base.join("base.osim"))?;
    let model = doc.model()?;
    let kin = Kinematics::new(&model)?;
    let poses = kin.body_poses(&kin.default_values())?;
    let to_lps = Frame::Lps.to_opensim().transpose();
    let mut meshes: Vec<(Level, TriMesh)> = Vec::new();
    for (body, file) in model.mesh_files() {
        let Some(level) = Level::from_body_name(&body) else {
            continue;
        };
        let mut m = mesh::read(&base.join(file))?.transformed(&poses[&body]);
        for v in m.vertices.iter_mut() {
            *v = Point3::from(to_lps * v.coords * 1e3);
        }
        meshes.push((level, m));
    }
    meshes.sort_by_key(|(l, _)| *l);
    let folder = out.join("folder");
    std::fs::create_dir_all(&folder)?;
    for (l, m) in &meshes {
        let name = if l.is_sacrum() {
            "sacrum.stl".to_string()
        } else {
            format!("{l}.stl")
        };
        mesh::stl::write_binary(&folder.join(name), m)?;
    }
    // RAS world, voxel axes along L, P, S (as DICOM-derived maps).
    let ras: Vec<(u16, TriMesh)> = meshes
        .iter()
        .map(|(l, m)| {
            let mut r = m.clone();
            for v in r.vertices.iter_mut() {
                *v = Point3::new(-v.x, -v.y, v.z);
            }
            let label = if l.is_sacrum() {
                25
            } else {
                43 - l.index() as u16
            };
            (label, r)
        })
        .collect();
    let lo = ras
        .iter()
        .flat_map(|(_, m)| m.vertices.iter())
        .fold(Vector3::repeat(f64::MAX), |a, v| a.inf(&v.coords));
    let hi = ras
        .iter()
        .flat_map(|(_, m)| m.vertices.iter())
        .fold(Vector3::repeat(f64::MIN), |a, v| a.sup(&v.coords));
    let dims = [512, 512, 400];
    let step = Vector3::new(0.8, 0.8, 1.25);
    let m = Matrix3::from_diagonal(&Vector3::new(-step.x, -step.y, step.z));
    let centre = (lo + hi) / 2.0;
    let half = Vector3::new(-step.x * 256.0, -step.y * 256.0, step.z * 200.0);
    let mut a = Matrix4::identity();
    a.fixed_view_mut::<3, 3>(0, 0).copy_from(&m);
    a.fixed_view_mut::<3, 1>(0, 3).copy_from(&(centre - half));
    let refs: Vec<(u16, &TriMesh)> = ras.iter().map(|(l, m)| (*l, m)).collect();
    let map = voxelise::voxelise(&refs, dims, a);
    std::fs::write(
        out.join("labels.nii"),
        voxelise::nifti_bytes(&map, HeaderTransform::Sform),
    )?;
    println!(
        "wrote {} meshes to {} and a 512x512x400 label map",
        meshes.len(),
        folder.display()
    );
    Ok(())
}
