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
pub use nifti::NiftiHeader;
use nifti::NiftiType;
use std::path::Path;

/// Largest label map read (voxels): 2^29 (e.g. 1024 x 1024 x 512), about
/// 1 GiB of 16-bit labels. The header's size is checked before reading.
pub(crate) const MAX_VOXELS: u64 = 1 << 29;

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

    /// World (RAS mm) position of voxel (0, 0, 0).
    pub fn origin(&self) -> Vector3<f64> {
        self.affine.fixed_view::<3, 1>(0, 3).into_owned()
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
/// ([`crate::util::input`]), then [`parse`]; a `.nii.gz` is decompressed
/// as a stream, never whole.
pub fn read(path: &Path) -> Result<LabelMap> {
    let raw = crate::util::input::read_bytes_capped(path, MAX_FILE_BYTES, "label maps")?;
    if raw.starts_with(&[0x1f, 0x8b]) {
        let gz = || flate2::read::MultiGzDecoder::new(&raw[..]);
        read_from(gz, true, path)
    } else {
        parse(&raw, path)
    }
}

/// Check and read a single-file NIfTI-1 image (`.nii` bytes, already
/// decompressed); `path` names the file in errors.
pub fn parse(bytes: &[u8], path: &Path) -> Result<LabelMap> {
    read_from(|| bytes, false, path)
}

/// Read a label map from the byte stream `open()` gives (called once per
/// pass): the header checked (dimensions, datatype, geometry, the volume's
/// declared size) before anything is allocated; then the volume streamed
/// twice, first to check every label and find the labelled voxels, then to
/// keep only their box (with a voxel's margin, so a structure touches the
/// box's edge only where it touches the map's). A `stream` (gzip) must end
/// where its header says: one that holds more is refused, not expanded.
fn read_from<R: std::io::Read>(
    open: impl Fn() -> R,
    stream: bool,
    path: &Path,
) -> Result<LabelMap> {
    // The header, from its first 348 bytes.
    let mut head = [0u8; 348];
    let got = fill(&mut open(), &mut head, path)?;
    if got < head.len() {
        return Err(Error::parse(
            path,
            "header",
            format!("truncated: {got} bytes, a NIfTI-1 header has 348"),
        ));
    }
    let header = NiftiHeader::from_reader(&head[..]).map_err(|e| nifti_error(path, "header", e))?;
    let dims = check_dims(&header, path)?;
    let dtype = check_datatype(&header, path)?;
    let Geometry {
        mut affine,
        transform,
        mut notes,
    } = geometry(&header, path)?;
    let volume = check_volume_offset(&header, path)?;
    let voxels = Voxels {
        dims,
        dtype,
        big_endian: header.endianness == nifti::Endianness::Big,
        offset: volume,
        stream,
    };
    // Pass 1: every value a label; the box of the labelled voxels.
    let mut lo = dims;
    let mut hi = [0usize; 3];
    voxels.each(&mut open(), path, |ijk, _| {
        for k in 0..3 {
            lo[k] = lo[k].min(ijk[k]);
            hi[k] = hi[k].max(ijk[k]);
        }
    })?;
    // The kept box: the labelled voxels and a voxel around them (the
    // first voxel when none is labelled).
    if lo[0] > hi[0] {
        (lo, hi) = ([0; 3], [0; 3]);
    }
    let lo = [0, 1, 2].map(|k| lo[k].saturating_sub(1));
    let hi = [0, 1, 2].map(|k| (hi[k] + 1).min(dims[k] - 1));
    let kept = [0, 1, 2].map(|k| hi[k] - lo[k] + 1);
    // Pass 2: the box's labels.
    let mut labels = vec![0u16; kept.iter().product()];
    voxels.each(&mut open(), path, |ijk, label| {
        let [i, j, k] = [0, 1, 2].map(|k| ijk[k] - lo[k]);
        labels[i + kept[0] * (j + kept[1] * k)] = label;
    })?;
    let corner = affine * Point3::from(lo.map(|x| x as f64)).to_homogeneous();
    affine.set_column(3, &corner);
    if header.scl_slope != 0.0 && (header.scl_slope != 1.0 || header.scl_inter != 0.0) {
        notes.push(format!(
            "intensity scaling (scl_slope {}, scl_inter {}) ignored: labels are the stored integers",
            header.scl_slope, header.scl_inter
        ));
    }
    Ok(LabelMap {
        dims: kept,
        labels,
        affine,
        transform,
        notes,
    })
}

/// Read into `buf` until it is full or the stream ends: the bytes read.
fn fill(r: &mut impl std::io::Read, buf: &mut [u8], path: &Path) -> Result<usize> {
    let mut n = 0;
    while n < buf.len() {
        match r.read(&mut buf[n..]) {
            Ok(0) => break,
            Ok(k) => n += k,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => {
                return Err(Error::parse(
                    path,
                    "gzip",
                    format!("not a readable gzip stream ({e})"),
                ))
            }
        }
    }
    Ok(n)
}

/// The volume's byte offset, `vox_offset`: within the file's cap and after
/// the header (extensions are not used).
fn check_volume_offset(h: &NiftiHeader, path: &Path) -> Result<u64> {
    let offset = h.vox_offset;
    if !offset.is_finite() || offset < 352.0 || offset > MAX_FILE_BYTES as f32 {
        return Err(Error::parse(
            path,
            "header vox_offset",
            format!("{offset}: expected the byte offset of the volume (352 or more)"),
        ));
    }
    Ok(offset as u64)
}

/// Where and how a header says its voxels are stored.
struct Voxels {
    dims: [usize; 3],
    dtype: NiftiType,
    big_endian: bool,
    /// Byte offset of the first voxel.
    offset: u64,
    /// A decompressed stream, which must end with the volume.
    stream: bool,
}

impl Voxels {
    /// Call `f` with each labelled voxel's (i, j, k) and label, in file
    /// order (i fastest), reading `r` a slab at a time; the first value that is not
    /// a label, a volume shorter than announced, or (for a stream) more
    /// bytes after it, is an error.
    fn each(
        &self,
        r: &mut impl std::io::Read,
        path: &Path,
        mut f: impl FnMut([usize; 3], u16),
    ) -> Result<()> {
        let size = self.dtype.size_of();
        let total = self.dims.iter().product::<usize>();
        let need = self.offset + (total * size) as u64;
        let short = |have: u64| {
            let [x, y, z] = self.dims;
            Error::parse(
                path,
                "volume",
                format!(
                    "truncated: the file has {have} bytes but its header announces {need} ({x}x{y}x{z} voxels of {size} bytes from offset {})",
                    self.offset
                ),
            )
        };
        // Skip the header and extensions.
        let mut skip = vec![0u8; 1 << 16];
        let mut at = 0u64;
        while at < self.offset {
            let want = (self.offset - at).min(skip.len() as u64) as usize;
            let n = fill(r, &mut skip[..want], path)?;
            at += n as u64;
            if n < want {
                return Err(short(at));
            }
        }
        // The voxels, a slab of up to 64 Ki at a time; an all-zero slab
        // (background) at once.
        let per = 1usize << 16;
        let mut buf = vec![0u8; per * size];
        let mut i = 0usize;
        while i < total {
            let n = (total - i).min(per);
            let slab = &mut buf[..n * size];
            let got = fill(r, slab, path)?;
            if got < n * size {
                return Err(short(at + got as u64));
            }
            at += got as u64;
            if slab.iter().all(|&b| b == 0) {
                i += n;
                continue;
            }
            for v in slab.chunks_exact(size) {
                let x = self.value(v);
                if !(0.0..=65535.0).contains(&x) || x.fract() != 0.0 {
                    return Err(Error::parse(
                        path,
                        format!("voxel {i}"),
                        format!("value {x} is not a label (an integer 0..65535)"),
                    ));
                }
                if x != 0.0 {
                    let [nx, ny, _] = self.dims;
                    f([i % nx, (i / nx) % ny, i / (nx * ny)], x as u16);
                }
                i += 1;
            }
        }
        if self.stream && fill(r, &mut skip[..1], path)? > 0 {
            return Err(Error::parse(
                path,
                "gzip",
                format!("the stream holds more than the {need} bytes its header announces: refusing to expand it"),
            ));
        }
        Ok(())
    }

    /// One stored value (`bytes` of the datatype's size), as a number.
    fn value(&self, bytes: &[u8]) -> f64 {
        macro_rules! num {
            ($ty:ty) => {{
                let a = bytes.try_into().unwrap_or_default();
                if self.big_endian {
                    <$ty>::from_be_bytes(a) as f64
                } else {
                    <$ty>::from_le_bytes(a) as f64
                }
            }};
        }
        match self.dtype {
            NiftiType::Uint8 => f64::from(bytes[0]),
            NiftiType::Int8 => f64::from(bytes[0] as i8),
            NiftiType::Uint16 => num!(u16),
            NiftiType::Int16 => num!(i16),
            NiftiType::Uint32 => num!(u32),
            NiftiType::Int32 => num!(i32),
            NiftiType::Uint64 => num!(u64),
            NiftiType::Int64 => num!(i64),
            NiftiType::Float32 => num!(f32),
            _ => num!(f64),
        }
    }
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

/// A header's voxel-to-world transform, as the NIfTI-1 reference
/// (`nifti1_io.c`) and nibabel read it.
#[derive(Debug, Clone)]
pub struct Geometry {
    /// Voxel index (i, j, k) -> world RAS millimetres.
    pub affine: Matrix4<f64>,
    /// Which transform gave it (`sform`, `qform`).
    pub transform: &'static str,
    /// Repairs made on the way (a voxel size's sign, a quaternion's norm,
    /// units assumed), each said once.
    pub notes: Vec<String>,
}

/// The header's voxel-to-world transform in millimetres: the sform when
/// `sform_code > 0`, else the qform when `qform_code > 0`, as
/// `nifti_convert_nhdr2nim` chooses. The qform follows
/// `nifti_quatern_to_mat44`: a quaternion (b, c, d) of norm 1 or more is
/// normalised (a half turn), the handedness is `qfac = pixdim[0]`'s alone,
/// a zero voxel size is taken as 1 and a negative one by its magnitude
/// (nibabel's repair; never a mirror). Refused: neither code set, a
/// negative code or a negative `qfac` other than -1 (the two readers
/// differ on them), a non-finite or singular transform.
pub fn geometry(h: &NiftiHeader, path: &Path) -> Result<Geometry> {
    let mut notes = Vec::new();
    for (field, code) in [("sform_code", h.sform_code), ("qform_code", h.qform_code)] {
        if code < 0 {
            return Err(Error::parse(
                path,
                format!("header {field}"),
                format!("{code}: a transform code is 0 (unset) or positive; readers disagree on a negative one"),
            ));
        }
    }
    let (mut a, which) = if h.sform_code > 0 {
        (sform(h), "sform")
    } else if h.qform_code > 0 {
        (qform(h, path, &mut notes)?, "qform")
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
    Ok(Geometry {
        affine: a,
        transform: which,
        notes,
    })
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

/// The qform (`nifti_quatern_to_mat44`): rotation from the quaternion
/// (b, c, d), voxel sizes `pixdim[1..3]`, `qfac = pixdim[0]` (-1 flips k),
/// offsets.
fn qform(h: &NiftiHeader, path: &Path, notes: &mut Vec<String>) -> Result<Matrix4<f64>> {
    let qfac = h.pixdim[0];
    if qfac < 0.0 && qfac != -1.0 {
        return Err(Error::parse(
            path,
            "header pixdim[0]",
            format!("qfac {qfac}: expected 1 or -1 (nifti1_io reads it as -1, a mirrored k axis, nibabel as 1): the patient's handedness is ambiguous"),
        ));
    }
    let (a, b, c, d) = unit_quaternion(h, notes);
    #[rustfmt::skip]
    let r = Matrix3::new(
        a * a + b * b - c * c - d * d, 2.0 * (b * c - a * d), 2.0 * (b * d + a * c),
        2.0 * (b * c + a * d), a * a + c * c - b * b - d * d, 2.0 * (c * d - a * b),
        2.0 * (b * d - a * c), 2.0 * (c * d + a * b), a * a + d * d - c * c - b * b,
    );
    let mut s = Vector3::zeros();
    for k in 0..3 {
        s[k] = voxel_size(h.pixdim[k + 1], k + 1, notes);
    }
    if qfac < 0.0 {
        s.z = -s.z;
    }
    let mut m = Matrix4::identity();
    m.fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&(r * Matrix3::from_diagonal(&s)));
    m[(0, 3)] = h.quatern_x as f64;
    m[(1, 3)] = h.quatern_y as f64;
    m[(2, 3)] = h.quatern_z as f64;
    Ok(m)
}

/// The quaternion (a, b, c, d) as `nifti_quatern_to_mat44` completes it:
/// a = sqrt(1 - |(b, c, d)|^2), except when that is below 1e-7 (a half
/// turn, or a norm above 1): then a = 0 exactly and (b, c, d) scaled to
/// norm 1, with a note when the norm was above 1.
fn unit_quaternion(h: &NiftiHeader, notes: &mut Vec<String>) -> (f64, f64, f64, f64) {
    let (b, c, d) = (h.quatern_b as f64, h.quatern_c as f64, h.quatern_d as f64);
    let n2 = b * b + c * c + d * d;
    let a = 1.0 - n2;
    if a >= 1e-7 {
        return (a.sqrt(), b, c, d);
    }
    if n2 > 1.0 + 1e-6 {
        notes.push(format!(
            "qform quaternion (b, c, d) = ({b}, {c}, {d}) has norm {:.4} > 1: normalised to a half turn, as the NIfTI-1 reference does",
            n2.sqrt()
        ));
    }
    let n = n2.sqrt();
    (0.0, b / n, c / n, d / n)
}

/// A qform voxel size: a zero (or non-finite) one taken as 1 mm-unit, a
/// negative one by its magnitude, each with a note; never a mirror.
fn voxel_size(x: f32, k: usize, notes: &mut Vec<String>) -> f64 {
    if x > 0.0 {
        x as f64
    } else if x < 0.0 {
        notes.push(format!(
            "pixdim[{k}] {x} is negative: its magnitude used (the handedness is qfac's, pixdim[0])"
        ));
        -(x as f64)
    } else {
        notes.push(format!(
            "pixdim[{k}] {x} is not a voxel size: 1 used, as the NIfTI-1 reference does"
        ));
        1.0
    }
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
