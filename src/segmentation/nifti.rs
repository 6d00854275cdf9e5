//! NIfTI-1 label maps (`.nii`, `.nii.gz`) through the `nifti` crate: the
//! header is read and checked first (dimensions, datatype, voxel count
//! against [`MAX_VOXELS`], a non-singular qform/sform affine), then the
//! volume is read into one integer label per voxel.
//!
//! World coordinates: the NIfTI standard defines the qform/sform world as
//! RAS+ (x to the patient's right... i.e. +x = left-to-right, +y =
//! posterior-to-anterior, +z = inferior-to-superior) in the header's
//! spatial units; the map's [`LabelMap::affine`] takes voxel indices to
//! that world in millimetres. The sform is used when its code is set,
//! else the qform (quaternion, `pixdim`, `qfac`); with neither the
//! orientation is unknown and the file is refused.

use crate::error::{Error, Result};
use nalgebra::{Matrix3, Matrix4, Point3, Vector3};
use nifti::{NiftiHeader, NiftiObject, NiftiType};
use std::path::Path;

/// Largest label map read (voxels): 2^29 (e.g. 1024 x 1024 x 512), about
/// 1 GiB of 16-bit labels. The header's size is checked before reading.
pub const MAX_VOXELS: u64 = 1 << 29;

/// A label map in memory.
#[derive(Debug, Clone)]
pub struct LabelMap {
    /// Voxels along i, j, k.
    pub dims: [usize; 3],
    /// Labels, i fastest (NIfTI order).
    pub labels: Vec<u16>,
    /// Voxel index (i, j, k) -> world RAS millimetres.
    pub affine: Matrix4<f64>,
    /// Which transform of the header gave the affine (`sform`, `qform`).
    pub transform: &'static str,
    /// Remarks (units assumed, scaling ignored, ...).
    pub notes: Vec<String>,
}

impl LabelMap {
    /// Linear index of voxel (i, j, k).
    pub fn index(&self, i: usize, j: usize, k: usize) -> usize {
        i + self.dims[0] * (j + self.dims[1] * k)
    }

    /// World (RAS mm) position of a (fractional) voxel index.
    pub fn world(&self, ijk: &Point3<f64>) -> Point3<f64> {
        Point3::from_homogeneous(self.affine * ijk.to_homogeneous()).unwrap_or(*ijk)
    }

    /// Voxel edge lengths along i, j, k (mm).
    pub fn spacing(&self) -> Vector3<f64> {
        let m = self.affine.fixed_view::<3, 3>(0, 0);
        Vector3::new(m.column(0).norm(), m.column(1).norm(), m.column(2).norm())
    }
}

/// Largest label-map file read (bytes, after gzip decompression): the
/// header, extensions and [`MAX_VOXELS`] 32-bit labels.
pub const MAX_FILE_BYTES: u64 = 4 * MAX_VOXELS + (1 << 20);

/// Read and check a label map: the bytes come through the input gate
/// ([`crate::util::input`]), a `.nii.gz` is decompressed with the same cap
/// on the bytes it yields, then [`parse`].
pub fn read(path: &Path) -> Result<LabelMap> {
    let raw = crate::util::input::read_bytes_capped(path, MAX_FILE_BYTES, "label maps")?;
    let bytes = if raw.starts_with(&[0x1f, 0x8b]) {
        gunzip_capped(&raw, path)?
    } else {
        raw
    };
    parse(&bytes, path)
}

/// Decompress gzip bytes, refusing more than [`MAX_FILE_BYTES`] of output
/// (a gzip bomb is refused, not expanded).
fn gunzip_capped(raw: &[u8], path: &Path) -> Result<Vec<u8>> {
    use std::io::Read;
    let mut out = Vec::new();
    flate2::read::MultiGzDecoder::new(raw)
        .take(MAX_FILE_BYTES + 1)
        .read_to_end(&mut out)
        .map_err(|e| Error::parse(path, "gzip", format!("not a readable gzip stream ({e})")))?;
    if out.len() as u64 > MAX_FILE_BYTES {
        return Err(Error::parse(
            path,
            "gzip",
            format!("decompresses to more than {MAX_FILE_BYTES} bytes: refusing to expand it"),
        ));
    }
    Ok(out)
}

/// Check and read a single-file NIfTI-1 image (`.nii` bytes, already
/// decompressed); `path` names the file in errors.
pub fn parse(bytes: &[u8], path: &Path) -> Result<LabelMap> {
    let header = NiftiHeader::from_reader(bytes).map_err(|e| nifti_error(path, "header", e))?;
    let dims = check_dims(&header, path)?;
    let dtype = check_datatype(&header, path)?;
    check_length(&header, dims, dtype, bytes.len(), path)?;
    let (affine, transform, mut notes) = header_affine(&header, path)?;
    // The header is sound: now the volume. Extensions are not used, and the
    // crate would allocate what their size fields claim: the reader sees
    // the extender bytes as 0 (no extensions) and the volume right after
    // (`check_length` put vox_offset within the file, at 352 or more).
    use std::io::Read;
    let volume_at = header.vox_offset as usize;
    let no_ext = bytes[..348].chain(&[0u8; 4][..]).chain(&bytes[volume_at..]);
    let obj =
        nifti::InMemNiftiObject::from_reader(no_ext).map_err(|e| nifti_error(path, "volume", e))?;
    let volume = obj.into_volume();
    let labels = to_labels(volume, dtype, path)?;
    if header.scl_slope != 0.0 && (header.scl_slope != 1.0 || header.scl_inter != 0.0) {
        notes.push(format!(
            "intensity scaling (scl_slope {}, scl_inter {}) ignored: labels are the stored integers",
            header.scl_slope, header.scl_inter
        ));
    }
    Ok(LabelMap {
        dims,
        labels,
        affine,
        transform,
        notes,
    })
}

/// The file holds the whole volume the header announces (checked before
/// the volume is allocated): `vox_offset` plus voxels x bytes per voxel.
fn check_length(
    h: &NiftiHeader,
    dims: [usize; 3],
    t: NiftiType,
    len: usize,
    path: &Path,
) -> Result<()> {
    let offset = h.vox_offset;
    if !offset.is_finite() || offset < 352.0 || offset > MAX_FILE_BYTES as f32 {
        return Err(Error::parse(
            path,
            "header vox_offset",
            format!("{offset}: expected the byte offset of the volume (352 or more)"),
        ));
    }
    let voxels = dims.iter().map(|&d| d as u64).product::<u64>();
    let need = offset as u64 + voxels * t.size_of() as u64;
    if (len as u64) < need {
        return Err(Error::parse(
            path,
            "volume",
            format!(
                "the file has {len} bytes but its header announces {need} ({}x{}x{} voxels of {} bytes from offset {offset})",
                dims[0], dims[1], dims[2], t.size_of()
            ),
        ));
    }
    Ok(())
}

/// An error of the `nifti` crate with the file and stage named.
fn nifti_error(path: &Path, stage: &str, e: nifti::NiftiError) -> Error {
    Error::parse(path, stage, format!("not a readable NIfTI-1 file ({e})"))
}

/// The three spatial dimensions; refuses 4-D (or more) images with more
/// than one volume, empty ones and ones over [`MAX_VOXELS`].
fn check_dims(h: &NiftiHeader, path: &Path) -> Result<[usize; 3]> {
    let nd = h.dim[0] as usize;
    if !(1..=7).contains(&nd) {
        return Err(Error::parse(
            path,
            "header dim[0]",
            format!("{nd} dimensions: expected 3"),
        ));
    }
    if nd > 3 && h.dim[4..=nd].iter().any(|&d| d > 1) {
        return Err(Error::parse(
            path,
            "header dim",
            format!(
                "a {nd}-D image ({:?}): a label map has 3 dimensions (one volume)",
                &h.dim[1..=nd]
            ),
        ));
    }
    let d = [h.dim[1] as usize, h.dim[2] as usize, h.dim[3] as usize];
    if nd < 3 || d.contains(&0) {
        return Err(Error::parse(
            path,
            "header dim",
            format!(
                "dimensions {:?}: a label map needs three non-zero dimensions",
                &h.dim[1..=nd]
            ),
        ));
    }
    let n = d.iter().map(|&x| x as u64).product::<u64>();
    if n > MAX_VOXELS {
        return Err(Error::parse(
            path,
            "header dim",
            format!(
                "{} x {} x {} = {n} voxels: label maps are limited to {MAX_VOXELS}",
                d[0], d[1], d[2]
            ),
        ));
    }
    Ok(d)
}

/// Integer (or integer-valued float) datatypes only.
fn check_datatype(h: &NiftiHeader, path: &Path) -> Result<NiftiType> {
    let t = h.data_type().map_err(|_| {
        Error::parse(
            path,
            "header datatype",
            format!("unknown datatype code {}", h.datatype),
        )
    })?;
    if h.bitpix as usize != 8 * t.size_of() {
        return Err(Error::parse(
            path,
            "header bitpix",
            format!(
                "{} bits per voxel contradicts the datatype {t:?} ({} bits)",
                h.bitpix,
                8 * t.size_of()
            ),
        ));
    }
    match t {
        NiftiType::Uint8
        | NiftiType::Int8
        | NiftiType::Uint16
        | NiftiType::Int16
        | NiftiType::Uint32
        | NiftiType::Int32
        | NiftiType::Uint64
        | NiftiType::Int64
        | NiftiType::Float32
        | NiftiType::Float64 => Ok(t),
        other => Err(Error::parse(
            path,
            "header datatype",
            format!(
                "datatype {other:?} (code {}) is not supported for a label map: expected integers (uint8..int64) or integer-valued float32/float64",
                h.datatype
            ),
        )),
    }
}

/// Voxel -> world RAS mm from the sform (preferred) or the qform; refuses a
/// missing, non-finite, zero or singular transform.
fn header_affine(
    h: &NiftiHeader,
    path: &Path,
) -> Result<(Matrix4<f64>, &'static str, Vec<String>)> {
    let mut notes = Vec::new();
    let (mut a, which) = if h.sform_code > 0 {
        (sform(h), "sform")
    } else if h.qform_code > 0 {
        (qform(h), "qform")
    } else {
        return Err(Error::parse(
            path,
            "header qform_code/sform_code",
            "both are 0: the voxel-to-world transform (and so left/right) is unknown",
        ));
    };
    let scale = match h.xyzt_to_space() {
        Ok(nifti::Unit::Meter) => 1000.0,
        Ok(nifti::Unit::Micron) => 1e-3,
        Ok(nifti::Unit::Mm) => 1.0,
        _ => {
            notes.push("spatial units not declared in xyzt_units: millimetres assumed".into());
            1.0
        }
    };
    a.fixed_view_mut::<3, 4>(0, 0).scale_mut(scale);
    check_affine(&a, which, path)?;
    Ok((a, which, notes))
}

/// The sform rows.
fn sform(h: &NiftiHeader) -> Matrix4<f64> {
    let r = [h.srow_x, h.srow_y, h.srow_z];
    let mut m = Matrix4::identity();
    for i in 0..3 {
        for j in 0..4 {
            m[(i, j)] = r[i][j] as f64;
        }
    }
    m
}

/// The qform: rotation from the quaternion (b, c, d), voxel sizes
/// `pixdim[1..3]`, `qfac = pixdim[0]` (-1 flips k), offsets.
fn qform(h: &NiftiHeader) -> Matrix4<f64> {
    let (b, c, d) = (h.quatern_b as f64, h.quatern_c as f64, h.quatern_d as f64);
    let a = (1.0 - (b * b + c * c + d * d)).max(0.0).sqrt();
    #[rustfmt::skip]
    let r = Matrix3::new(
        a * a + b * b - c * c - d * d, 2.0 * (b * c - a * d), 2.0 * (b * d + a * c),
        2.0 * (b * c + a * d), a * a + c * c - b * b - d * d, 2.0 * (c * d - a * b),
        2.0 * (b * d - a * c), 2.0 * (c * d + a * b), a * a + d * d - c * c - b * b,
    );
    let qfac = if h.pixdim[0] < 0.0 { -1.0 } else { 1.0 };
    let s = Vector3::new(
        h.pixdim[1] as f64,
        h.pixdim[2] as f64,
        qfac * h.pixdim[3] as f64,
    );
    let mut m = Matrix4::identity();
    m.fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&(r * Matrix3::from_diagonal(&s)));
    m[(0, 3)] = h.quatern_x as f64;
    m[(1, 3)] = h.quatern_y as f64;
    m[(2, 3)] = h.quatern_z as f64;
    m
}

/// Finite, every voxel edge non-zero, and not singular (the three edges
/// span a volume: |det| at least 1e-6 of the product of their lengths).
fn check_affine(a: &Matrix4<f64>, which: &str, path: &Path) -> Result<()> {
    let m = a.fixed_view::<3, 3>(0, 0).into_owned();
    let lengths: f64 = (0..3).map(|k| m.column(k).norm()).product();
    let finite = a.iter().all(|x| x.is_finite());
    if !finite || lengths == 0.0 || m.determinant().abs() < 1e-6 * lengths {
        return Err(Error::parse(
            path,
            format!("header {which}"),
            format!(
                "the voxel-to-world transform is {} (rows {:?}): expected three independent non-zero voxel edges",
                if !finite { "not finite" } else if lengths == 0.0 { "zero" } else { "singular" },
                [a.row(0).iter().copied().collect::<Vec<_>>(), a.row(1).iter().copied().collect(), a.row(2).iter().copied().collect()]
            ),
        ));
    }
    Ok(())
}

/// The volume's values as 16-bit labels: integer, 0..=65535.
fn to_labels(v: nifti::InMemNiftiVolume, t: NiftiType, path: &Path) -> Result<Vec<u16>> {
    macro_rules! conv {
        ($ty:ty) => {{
            let data: Vec<$ty> = v
                .into_nifti_typed_data()
                .map_err(|e| nifti_error(path, "volume", e))?;
            labels_from(data.into_iter().map(|x| x as f64), path)
        }};
    }
    match t {
        NiftiType::Uint8 => {
            let data: Vec<u8> = v
                .into_nifti_typed_data()
                .map_err(|e| nifti_error(path, "volume", e))?;
            Ok(data.into_iter().map(u16::from).collect())
        }
        NiftiType::Uint16 => v
            .into_nifti_typed_data()
            .map_err(|e| nifti_error(path, "volume", e)),
        NiftiType::Int8 => conv!(i8),
        NiftiType::Int16 => conv!(i16),
        NiftiType::Uint32 => conv!(u32),
        NiftiType::Int32 => conv!(i32),
        NiftiType::Uint64 => conv!(u64),
        NiftiType::Int64 => conv!(i64),
        NiftiType::Float32 => conv!(f32),
        NiftiType::Float64 => conv!(f64),
        other => Err(Error::parse(
            path,
            "header datatype",
            format!("datatype {other:?} is not supported for a label map"),
        )),
    }
}

/// Values as labels; the first negative, non-integer or too large value is
/// an error naming its voxel.
fn labels_from(values: impl Iterator<Item = f64>, path: &Path) -> Result<Vec<u16>> {
    let mut out = Vec::with_capacity(values.size_hint().0);
    for (i, x) in values.enumerate() {
        if !(0.0..=65535.0).contains(&x) || x.fract() != 0.0 {
            return Err(Error::parse(
                path,
                format!("voxel {i}"),
                format!("value {x} is not a label (an integer 0..65535)"),
            ));
        }
        out.push(x as u16);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::segmentation::voxelise::{nifti_bytes, HeaderTransform};

    fn small() -> LabelMap {
        LabelMap {
            dims: [3, 2, 2],
            labels: (0..12).map(|i| (i % 4) as u16).collect(),
            affine: Matrix4::identity(),
            transform: "sform",
            notes: Vec::new(),
        }
    }

    #[test]
    fn round_trip_and_ignored_extensions() {
        let map = small();
        let bytes = nifti_bytes(&map, HeaderTransform::Sform);
        let back = parse(&bytes, Path::new("a.nii")).unwrap();
        assert_eq!(back.labels, map.labels);
        // An extension whose size field claims 1.5 GB (fuzz finding: the
        // crate allocated it): the extender flag set, vox_offset 360.
        let mut ext = bytes[..348].to_vec();
        ext.extend_from_slice(&[1, 0, 0, 0]);
        ext.extend_from_slice(&1_500_000_000i32.to_le_bytes());
        ext.extend_from_slice(&4i32.to_le_bytes());
        ext.extend_from_slice(&bytes[352..]);
        ext[108..112].copy_from_slice(&360f32.to_le_bytes());
        let back = parse(&ext, Path::new("ext.nii")).unwrap();
        assert_eq!(back.labels, map.labels);
        // vox_offset inside the header is refused.
        let mut low = bytes.clone();
        low[108..112].copy_from_slice(&100f32.to_le_bytes());
        let e = parse(&low, Path::new("low.nii")).unwrap_err().to_string();
        assert!(e.contains("vox_offset"), "{e}");
    }
}
