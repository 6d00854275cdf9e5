//! Surfaces of the labels of a [`LabelMap`]: one pass over the volume for
//! each label's voxel count and bounding box, then per label, on its
//! bounding box only (plus a margin), the occupancy smoothed by a
//! separable [1 2 1]/4 kernel and its 0.5 level set extracted by surface
//! nets (`fast-surface-nets`); vertices taken to world coordinates by the
//! map's affine. The surface lies on the voxel faces where the label's
//! boundary is flat, and between them where it is curved.

use super::nifti::LabelMap;
use crate::mesh::TriMesh;
use fast_surface_nets::ndshape::RuntimeShape;
use fast_surface_nets::{surface_nets, SurfaceNetsBuffer};
use nalgebra::Point3;

/// Voxel count, bounding box and moments of one label.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LabelStats {
    /// Number of voxels.
    pub count: u64,
    /// Inclusive lower voxel index bounds.
    pub min: [usize; 3],
    /// Inclusive upper voxel index bounds.
    pub max: [usize; 3],
    /// Sums of the voxel indices (i, j, k) and of their products (ii, jj,
    /// kk, ij, ik, jk): the label's centroid and second moments.
    pub sum: [f64; 3],
    /// Sums of the products ii, jj, kk, ij, ik, jk.
    pub sum_sq: [f64; 6],
}

impl LabelStats {
    /// `true` when the label touches a face of the volume (the field of
    /// view may cut it).
    pub fn touches_edge(&self, dims: &[usize; 3]) -> bool {
        (0..3).any(|k| self.min[k] == 0 || self.max[k] + 1 == dims[k])
    }

    /// The union of two labels' statistics (a level with two labels).
    pub fn union(mut self, b: &LabelStats) -> LabelStats {
        self.count += b.count;
        for k in 0..3 {
            self.min[k] = self.min[k].min(b.min[k]);
            self.max[k] = self.max[k].max(b.max[k]);
            self.sum[k] += b.sum[k];
        }
        for k in 0..6 {
            self.sum_sq[k] += b.sum_sq[k];
        }
        self
    }

    /// Centroid (voxel index coordinates) and covariance (voxels^2).
    pub fn moments(&self) -> (nalgebra::Point3<f64>, nalgebra::Matrix3<f64>) {
        let n = self.count.max(1) as f64;
        let m = nalgebra::Vector3::from(self.sum) / n;
        let q = self.sum_sq.map(|v| v / n);
        let c = nalgebra::Matrix3::new(q[0], q[3], q[4], q[3], q[1], q[5], q[4], q[5], q[2])
            - m * m.transpose();
        (m.into(), c)
    }
}

/// Statistics of every non-zero label present, by label.
#[allow(clippy::needless_range_loop)]
pub fn label_stats(map: &LabelMap) -> std::collections::BTreeMap<u16, LabelStats> {
    let mut stats: Vec<Option<LabelStats>> = vec![None; 65536];
    let [nx, ny, _] = map.dims;
    for (idx, &l) in map.labels.iter().enumerate() {
        if l == 0 {
            continue;
        }
        let p = [idx % nx, (idx / nx) % ny, idx / (nx * ny)];
        let s = stats[l as usize].get_or_insert(LabelStats {
            count: 0,
            min: p,
            max: p,
            sum: [0.0; 3],
            sum_sq: [0.0; 6],
        });
        s.count += 1;
        for k in 0..3 {
            s.min[k] = s.min[k].min(p[k]);
            s.max[k] = s.max[k].max(p[k]);
        }
        let [x, y, z] = p.map(|v| v as f64);
        s.sum[0] += x;
        s.sum[1] += y;
        s.sum[2] += z;
        for (acc, v) in s
            .sum_sq
            .iter_mut()
            .zip([x * x, y * y, z * z, x * y, x * z, y * z])
        {
            *acc += v;
        }
    }
    stats
        .into_iter()
        .enumerate()
        .filter_map(|(l, s)| s.map(|s| (l as u16, s)))
        .collect()
}

/// Margin of voxels around a bounding box (1 for the smoothing kernel, 1
/// so that the surface closes inside the box).
const PAD: usize = 2;

/// The closed surface of the voxels whose label is in `labels`, inside the
/// (inclusive) box `min..=max`, in world millimetres.
pub fn extract(map: &LabelMap, labels: &[u16], min: [usize; 3], max: [usize; 3]) -> TriMesh {
    extract_with_voxels(map, labels, min, max).0
}

/// A label's boundary voxels: the voxels inside with a face-neighbour
/// outside, where the label's surface runs.
#[derive(Debug, Clone, PartialEq)]
pub struct BoundaryVoxels {
    /// Voxel centres (world millimetres).
    pub centres: Vec<Point3<f64>>,
    /// The voxel's edge vectors along i, j, k (world millimetres).
    pub edges: [nalgebra::Vector3<f64>; 3],
}

/// [`extract`] and the boundary voxels the surface was drawn around.
pub fn extract_with_voxels(
    map: &LabelMap,
    labels: &[u16],
    min: [usize; 3],
    max: [usize; 3],
) -> (TriMesh, BoundaryVoxels) {
    let size = [0, 1, 2].map(|k| max[k] - min[k] + 1 + 2 * PAD);
    let occupancy = box_occupancy(map, labels, min, size);
    let voxels = boundary_voxels(map, &occupancy, min, size);
    let smooth = smooth121(occupancy, size);
    let sdf: Vec<f32> = smooth.iter().map(|&o| 0.5 - o).collect();
    let shape = RuntimeShape::<u32, 3>::new(size.map(|s| s as u32));
    let mut buf = SurfaceNetsBuffer::default();
    let hi = size.map(|s| s as u32 - 1);
    surface_nets(&sdf, &shape, [0; 3], hi, &mut buf);
    (to_world(map, &buf, min), voxels)
}

/// The occupied voxels of the padded box with a face-neighbour empty (the
/// padding is empty, so every neighbour index is inside the box).
fn boundary_voxels(
    map: &LabelMap,
    occ: &[f32],
    min: [usize; 3],
    size: [usize; 3],
) -> BoundaryVoxels {
    let at = |i: usize, j: usize, k: usize| occ[i + size[0] * (j + size[1] * k)] > 0.5;
    let mut centres = Vec::new();
    for k in PAD..size[2] - PAD {
        for j in PAD..size[1] - PAD {
            for i in PAD..size[0] - PAD {
                if !at(i, j, k) {
                    continue;
                }
                // Inside, with a face-neighbour outside.
                let interior = at(i - 1, j, k)
                    && at(i + 1, j, k)
                    && at(i, j - 1, k)
                    && at(i, j + 1, k)
                    && at(i, j, k - 1)
                    && at(i, j, k + 1);
                if !interior {
                    let ijk = [i, j, k].map(|c| c as f64 - PAD as f64);
                    centres.push(map.world(&Point3::new(
                        ijk[0] + min[0] as f64,
                        ijk[1] + min[1] as f64,
                        ijk[2] + min[2] as f64,
                    )));
                }
            }
        }
    }
    let a = map.affine.fixed_view::<3, 3>(0, 0).into_owned();
    BoundaryVoxels {
        centres,
        edges: [a.column(0).into(), a.column(1).into(), a.column(2).into()],
    }
}

/// 1.0 inside the labels, 0.0 outside, on the padded box.
fn box_occupancy(map: &LabelMap, labels: &[u16], min: [usize; 3], size: [usize; 3]) -> Vec<f32> {
    let mut occ = vec![0f32; size[0] * size[1] * size[2]];
    let dims = map.dims;
    for k in PAD..size[2] - PAD {
        let gk = min[2] + k - PAD;
        for j in PAD..size[1] - PAD {
            let gj = min[1] + j - PAD;
            let row = map.index(min[0], gj, gk);
            let out = size[0] * (j + size[1] * k);
            for i in PAD..size[0] - PAD {
                let gi = i - PAD;
                if gi + min[0] < dims[0] && labels.contains(&map.labels[row + gi]) {
                    occ[out + i] = 1.0;
                }
            }
        }
    }
    occ
}

/// Separable [1 2 1]/4 smoothing along each axis (edges clamped to 0).
fn smooth121(mut v: Vec<f32>, size: [usize; 3]) -> Vec<f32> {
    let strides = [1, size[0], size[0] * size[1]];
    for (axis, &stride) in strides.iter().enumerate() {
        let src = v.clone();
        let n = size[axis];
        for (idx, out) in v.iter_mut().enumerate() {
            let c = (idx / stride) % n;
            let lo = if c > 0 { src[idx - stride] } else { 0.0 };
            let hi = if c + 1 < n { src[idx + stride] } else { 0.0 };
            *out = 0.25 * lo + 0.5 * src[idx] + 0.25 * hi;
        }
    }
    v
}

/// Surface-nets output (box-local voxel coordinates) to a world mesh;
/// triangles turned outward when the affine mirrors.
fn to_world(map: &LabelMap, buf: &SurfaceNetsBuffer, min: [usize; 3]) -> TriMesh {
    let off = [0, 1, 2].map(|k| min[k] as f64 - PAD as f64);
    let vertices: Vec<Point3<f64>> = buf
        .positions
        .iter()
        .map(|p| {
            let ijk = Point3::new(
                p[0] as f64 + off[0],
                p[1] as f64 + off[1],
                p[2] as f64 + off[2],
            );
            map.world(&ijk)
        })
        .collect();
    let mut triangles: Vec<[u32; 3]> = buf
        .indices
        .chunks_exact(3)
        .map(|t| [t[0], t[1], t[2]])
        .collect();
    let mut mesh = TriMesh {
        vertices,
        triangles: std::mem::take(&mut triangles),
    };
    if mesh.signed_volume() < 0.0 {
        for t in mesh.triangles.iter_mut() {
            t.swap(1, 2);
        }
    }
    mesh
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Matrix4;

    /// A ball of radius 10 voxels in a 40^3 map with 1 mm voxels.
    fn ball_map(affine: Matrix4<f64>) -> LabelMap {
        let n = 40;
        let mut labels = vec![0u16; n * n * n];
        for k in 0..n {
            for j in 0..n {
                for i in 0..n {
                    let d = [i, j, k].map(|x| x as f64 - 19.5);
                    if (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt() <= 10.0 {
                        labels[i + n * (j + n * k)] = 7;
                    }
                }
            }
        }
        LabelMap {
            dims: [n; 3],
            labels,
            affine,
            transform: "sform",
            notes: vec![],
        }
    }

    #[test]
    fn ball_surface_is_closed_outward_and_the_right_size() {
        // A mirrored affine (x flipped) must still give an outward surface.
        let mut a = Matrix4::identity();
        a[(0, 0)] = -1.0;
        let map = ball_map(a);
        let stats = label_stats(&map);
        let s = stats[&7];
        assert!(!s.touches_edge(&map.dims));
        let mesh = extract(&map, &[7], s.min, s.max);
        assert!(mesh.edge_report().is_watertight());
        let v = mesh.signed_volume();
        let exact = 4.0 / 3.0 * std::f64::consts::PI * 1000.0;
        assert!((v / exact - 1.0).abs() < 0.08, "volume {v} vs {exact}");
        let c = mesh.volume_centroid().unwrap();
        assert!((c - Point3::new(-19.5, 19.5, 19.5)).norm() < 0.05, "{c}");
    }
}
