//! Stanford PLY reading (ASCII, binary little- and big-endian) and ASCII
//! writing.
//!
//! The `vertex` element must have `x`, `y`, `z` properties (any numeric
//! type; other properties such as normals or colours are skipped); the
//! `face` element must have a list property `vertex_indices` (or
//! `vertex_index`); polygons are triangulated as fans. Other elements are
//! parsed and ignored. Declared element counts are checked against the size
//! of the body before anything is allocated from them.

use super::TriMesh;
use crate::error::{Error, Result};
use nalgebra::Point3;
use std::path::Path;

/// Read a PLY file.
pub fn read(path: &Path) -> Result<TriMesh> {
    let bytes = super::read_file_bytes(path)?;
    read_bytes(&bytes, path)
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn parse(s: &str) -> Option<Scalar> {
        Some(match s {
            "char" | "int8" => Scalar::I8,
            "uchar" | "uint8" => Scalar::U8,
            "short" | "int16" => Scalar::I16,
            "ushort" | "uint16" => Scalar::U16,
            "int" | "int32" => Scalar::I32,
            "uint" | "uint32" => Scalar::U32,
            "float" | "float32" => Scalar::F32,
            "double" | "float64" => Scalar::F64,
            _ => return None,
        })
    }
    fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }
    fn is_int(self) -> bool {
        !matches!(self, Scalar::F32 | Scalar::F64)
    }
}

#[derive(Debug, Clone)]
enum Prop {
    Scalar(String, Scalar),
    List(String, Scalar, Scalar),
}

#[derive(Debug, Clone)]
struct Element {
    name: String,
    count: usize,
    props: Vec<Prop>,
    line: usize,
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Fmt {
    Ascii,
    Le,
    Be,
}

/// Parse PLY bytes; `name` is used in error messages.
pub fn read_bytes(bytes: &[u8], name: &Path) -> Result<TriMesh> {
    // The `ply` magic line, then the header text up to `end_header`.
    let (header, body_start) = split_header(bytes, name)?;
    // Format and element declarations with their properties.
    let (fmt, elements) = read_header(header, name)?;
    let body = &bytes[body_start..];
    // Refuse declared counts the body cannot hold before allocating from them.
    check_counts(&elements, fmt, body.len(), name)?;
    let mut src = match fmt {
        Fmt::Ascii => Source::Ascii(AsciiSrc::new(
            body,
            name,
            super::line_of(bytes, body_start),
        )?),
        _ => Source::Bin {
            bytes: body,
            pos: 0,
            be: fmt == Fmt::Be,
        },
    };
    // Every element's instances: the vertex coordinates and face index lists.
    let (vertices, faces) = read_body(&elements, &mut src, name)?;
    // Faces checked against the vertex count and triangulated as fans.
    let triangles = triangulate(faces, vertices.len(), name)?;
    Ok(TriMesh {
        vertices,
        triangles,
    })
}

/// The header text (from the start to `end_header`) and where the body
/// starts (after the `end_header` line).
fn split_header<'a>(bytes: &'a [u8], name: &Path) -> Result<(&'a str, usize)> {
    if !bytes.starts_with(b"ply\n") && !bytes.starts_with(b"ply\r\n") {
        return Err(Error::parse(
            name,
            "line 1",
            "not a PLY file: must start with `ply`",
        ));
    }
    let end = find(bytes, b"end_header")
        .ok_or_else(|| Error::parse(name, "header", "no `end_header` line (truncated file?)"))?;
    let body_start = bytes[end..]
        .iter()
        .position(|&b| b == b'\n')
        .map(|k| end + k + 1)
        .unwrap_or(bytes.len());
    let header = std::str::from_utf8(&bytes[..end])
        .map_err(|_| Error::parse(name, "header", "header is not ASCII text"))?;
    Ok((header, body_start))
}

/// The body format and the declared elements of the header (lines after
/// the magic line).
fn read_header(header: &str, name: &Path) -> Result<(Fmt, Vec<Element>)> {
    let mut fmt = None;
    let mut elements: Vec<Element> = Vec::new();
    for (i, line) in header.lines().enumerate().skip(1) {
        let ln = i + 1;
        let loc = || format!("line {ln}");
        let t: Vec<&str> = line.split_whitespace().collect();
        match t.first().copied() {
            None | Some("comment") | Some("obj_info") => {}
            Some("format") => fmt = Some(read_format(&t, line, name, ln)?),
            Some("element") => elements.push(read_element(&t, name, ln)?),
            Some("property") => {
                let el = elements
                    .last_mut()
                    .ok_or_else(|| Error::parse(name, loc(), "`property` before any `element`"))?;
                el.props.push(read_property(&t, name, ln)?);
            }
            Some(other) => {
                let shown: String = other.chars().take(20).collect();
                return Err(Error::parse(
                    name,
                    loc(),
                    format!("unknown header keyword `{shown}`"),
                ));
            }
        }
    }
    let fmt = fmt.ok_or_else(|| Error::parse(name, "header", "no `format` line"))?;
    Ok((fmt, elements))
}

/// A `format` line (tokens `t`) at line `ln`.
fn read_format(t: &[&str], line: &str, name: &Path, ln: usize) -> Result<Fmt> {
    Ok(match (t.get(1).copied(), t.get(2).copied()) {
        (Some("ascii"), Some("1.0")) => Fmt::Ascii,
        (Some("binary_little_endian"), Some("1.0")) => Fmt::Le,
        (Some("binary_big_endian"), Some("1.0")) => Fmt::Be,
        _ => {
            return Err(Error::parse(
                name,
                format!("line {ln}"),
                format!("unsupported format line `{line}`"),
            ))
        }
    })
}

/// An `element NAME COUNT` line (tokens `t`) at line `ln`, without properties.
fn read_element(t: &[&str], name: &Path, ln: usize) -> Result<Element> {
    let loc = || format!("line {ln}");
    let (Some(n), Some(c)) = (t.get(1), t.get(2)) else {
        return Err(Error::parse(
            name,
            loc(),
            "`element` needs a name and a count",
        ));
    };
    let count = c.parse::<usize>().map_err(|_| {
        Error::parse(
            name,
            loc(),
            format!("element count `{c}` is not an integer"),
        )
    })?;
    Ok(Element {
        name: n.to_string(),
        count,
        props: Vec::new(),
        line: ln,
    })
}

/// A `property TYPE NAME` or `property list COUNT ITEM NAME` line (tokens
/// `t`) at line `ln`.
fn read_property(t: &[&str], name: &Path, ln: usize) -> Result<Prop> {
    let loc = || format!("line {ln}");
    let ty = |s: Option<&&str>| -> Result<Scalar> {
        let s = s.copied().unwrap_or("");
        Scalar::parse(s)
            .ok_or_else(|| Error::parse(name, loc(), format!("unknown property type `{s}`")))
    };
    if t.get(1) == Some(&"list") {
        let ct = ty(t.get(2))?;
        let it = ty(t.get(3))?;
        if !ct.is_int() {
            return Err(Error::parse(
                name,
                loc(),
                "list count type must be an integer",
            ));
        }
        let pn = t
            .get(4)
            .ok_or_else(|| Error::parse(name, loc(), "list property needs a name"))?;
        Ok(Prop::List(pn.to_string(), ct, it))
    } else {
        let st = ty(t.get(1))?;
        let pn = t
            .get(2)
            .ok_or_else(|| Error::parse(name, loc(), "property needs a name"))?;
        Ok(Prop::Scalar(pn.to_string(), st))
    }
}

/// Every instance takes at least one byte (ASCII: a line; binary: its
/// fixed-size part): refuse counts a body of `body_len` bytes cannot hold.
fn check_counts(elements: &[Element], fmt: Fmt, body_len: usize, name: &Path) -> Result<()> {
    let mut min_total: u128 = 0;
    for el in elements {
        let per: usize = if fmt == Fmt::Ascii {
            2
        } else {
            el.props
                .iter()
                .map(|p| match p {
                    Prop::Scalar(_, s) => s.size(),
                    Prop::List(_, c, _) => c.size(),
                })
                .sum::<usize>()
                .max(1)
        };
        min_total += el.count as u128 * per as u128;
    }
    if min_total > body_len as u128 + 1 {
        return Err(Error::parse(
            name,
            "header",
            format!(
                "declared element counts need at least {min_total} bytes but the body has {body_len} \
                 (truncated file or wrong counts)"
            ),
        ));
    }
    Ok(())
}

/// A face's vertex indices and the face's instance number.
type Face = (Vec<i64>, usize);

/// Read the instances of every element in order: the vertices (of the
/// `vertex` element) and the index lists of the `face` element.
fn read_body(
    elements: &[Element],
    src: &mut Source<'_>,
    name: &Path,
) -> Result<(Vec<Point3<f64>>, Vec<Face>)> {
    let mut vertices: Option<Vec<Point3<f64>>> = None;
    let mut faces: Vec<Face> = Vec::new();
    for el in elements {
        let xyz = vertex_props(el, name)?;
        let face_prop = face_prop(el, name)?;
        let mut verts = Vec::new();
        for k in 0..el.count {
            let vals = read_instance(el, k, xyz, face_prop, src, &mut faces, name)?;
            if xyz.is_some() {
                verts.push(Point3::from(vals));
            }
        }
        if xyz.is_some() {
            vertices = Some(verts);
        }
    }
    let vertices = vertices.ok_or_else(|| Error::parse(name, "header", "no `vertex` element"))?;
    Ok((vertices, faces))
}

/// Positions of the `x`, `y`, `z` properties of the `vertex` element
/// (`None` for other elements).
fn vertex_props(el: &Element, name: &Path) -> Result<Option<[usize; 3]>> {
    if el.name != "vertex" {
        return Ok(None);
    }
    let pos = |n: &str| {
        el.props
            .iter()
            .position(|p| matches!(p, Prop::Scalar(pn, _) if pn == n))
    };
    match (pos("x"), pos("y"), pos("z")) {
        (Some(a), Some(b), Some(c)) => Ok(Some([a, b, c])),
        _ => Err(Error::parse(
            name,
            format!("line {}", el.line),
            "element `vertex` lacks scalar x, y, z properties",
        )),
    }
}

/// Position of the `vertex_indices` list of the `face` element (`None` for
/// other elements).
fn face_prop(el: &Element, name: &Path) -> Result<Option<usize>> {
    if el.name != "face" {
        return Ok(None);
    }
    el.props
        .iter()
        .position(
            |p| matches!(p, Prop::List(pn, _, _) if pn == "vertex_indices" || pn == "vertex_index"),
        )
        .ok_or_else(|| {
            Error::parse(
                name,
                format!("line {}", el.line),
                "element `face` lacks a `vertex_indices` list property",
            )
        })
        .map(Some)
}

/// Instance `k` of `el`: its coordinates when `xyz` names them (checked
/// finite), its face list pushed onto `faces` when `face_prop` names it.
fn read_instance(
    el: &Element,
    k: usize,
    xyz: Option<[usize; 3]>,
    face_prop: Option<usize>,
    src: &mut Source<'_>,
    faces: &mut Vec<Face>,
    name: &Path,
) -> Result<[f64; 3]> {
    let loc = || format!("element {} {k}", el.name);
    src.start_instance(name, &loc())?;
    let mut vals = [0.0f64; 3];
    for (j, p) in el.props.iter().enumerate() {
        match p {
            Prop::Scalar(_, s) => {
                let v = src.scalar(*s, name, &loc())?;
                if let Some(xyz) = xyz {
                    if let Some(c) = xyz.iter().position(|&q| q == j) {
                        vals[c] = v;
                    }
                }
            }
            Prop::List(_, c, it) => {
                let n = src.scalar(*c, name, &loc())?;
                if !(0.0..=1e6).contains(&n) {
                    return Err(Error::parse(
                        name,
                        loc(),
                        format!("list length {n} is not plausible"),
                    ));
                }
                let mut list = Vec::new();
                for _ in 0..n as usize {
                    list.push(src.scalar(*it, name, &loc())?);
                }
                if face_prop == Some(j) {
                    if !it.is_int() {
                        return Err(Error::parse(
                            name,
                            loc(),
                            "vertex_indices must have an integer type",
                        ));
                    }
                    faces.push((list.iter().map(|&x| x as i64).collect(), k));
                }
            }
        }
    }
    src.end_instance(name, &loc())?;
    if xyz.is_some() && !vals.iter().all(|v| v.is_finite()) {
        return Err(Error::parse(
            name,
            loc(),
            format!("non-finite coordinate {vals:?}"),
        ));
    }
    Ok(vals)
}

/// Triangles of the faces (fans), each index checked against the `n_vertices`.
fn triangulate(faces: Vec<Face>, n_vertices: usize, name: &Path) -> Result<Vec<[u32; 3]>> {
    let n = n_vertices as i64;
    let mut triangles = Vec::new();
    for (f, k) in faces {
        if f.len() < 3 {
            return Err(Error::parse(
                name,
                format!("element face {k}"),
                format!("face has {} vertices, at least 3 expected", f.len()),
            ));
        }
        if let Some(&bad) = f.iter().find(|&&i| i < 0 || i >= n) {
            return Err(Error::parse(
                name,
                format!("element face {k}"),
                format!("vertex index {bad} is outside 0..{n}"),
            ));
        }
        for j in 1..f.len() - 1 {
            triangles.push([f[0] as u32, f[j] as u32, f[j + 1] as u32]);
        }
    }
    Ok(triangles)
}

fn find(hay: &[u8], needle: &[u8]) -> Option<usize> {
    hay.windows(needle.len()).position(|w| w == needle)
}

struct AsciiSrc<'a> {
    lines: Vec<(usize, Vec<&'a str>)>,
    line: usize,
    tok: usize,
}

impl<'a> AsciiSrc<'a> {
    fn new(body: &'a [u8], name: &Path, first_line: usize) -> Result<Self> {
        let text = std::str::from_utf8(body).map_err(|e| {
            Error::parse(
                name,
                format!(
                    "line {}",
                    first_line + super::line_of(body, e.valid_up_to()) - 1
                ),
                "ASCII PLY body is not text",
            )
        })?;
        let lines = text
            .lines()
            .enumerate()
            .map(|(i, l)| (first_line + i, l.split_whitespace().collect::<Vec<_>>()))
            .filter(|(_, t)| !t.is_empty())
            .collect();
        Ok(AsciiSrc {
            lines,
            line: 0,
            tok: 0,
        })
    }
}

enum Source<'a> {
    Ascii(AsciiSrc<'a>),
    Bin {
        bytes: &'a [u8],
        pos: usize,
        be: bool,
    },
}

impl Source<'_> {
    fn start_instance(&mut self, name: &Path, loc: &str) -> Result<()> {
        if let Source::Ascii(a) = self {
            if a.line >= a.lines.len() {
                return Err(Error::parse(name, loc, "body ends early (truncated file?)"));
            }
            a.tok = 0;
        }
        Ok(())
    }
    fn end_instance(&mut self, name: &Path, loc: &str) -> Result<()> {
        if let Source::Ascii(a) = self {
            let (ln, toks) = &a.lines[a.line];
            if a.tok != toks.len() {
                return Err(Error::parse(
                    name,
                    format!("line {ln}, {loc}"),
                    format!("{} values on the line, {} expected", toks.len(), a.tok),
                ));
            }
            a.line += 1;
        }
        Ok(())
    }
    fn scalar(&mut self, s: Scalar, name: &Path, loc: &str) -> Result<f64> {
        match self {
            Source::Ascii(a) => {
                let (ln, toks) = &a.lines[a.line];
                let t = toks.get(a.tok).ok_or_else(|| {
                    Error::parse(
                        name,
                        format!("line {ln}, {loc}"),
                        "too few values on the line",
                    )
                })?;
                a.tok += 1;
                let v = if s.is_int() {
                    t.parse::<i64>().map(|x| x as f64).ok()
                } else {
                    t.parse::<f64>().ok()
                };
                v.ok_or_else(|| {
                    let shown: String = t.chars().take(24).collect();
                    Error::parse(
                        name,
                        format!("line {ln}, {loc}"),
                        format!("`{shown}` is not a valid {s:?} value"),
                    )
                })
            }
            Source::Bin { bytes, pos, be } => {
                let n = s.size();
                let b = bytes.get(*pos..*pos + n).ok_or_else(|| {
                    Error::parse(name, loc, "binary body ends early (truncated file?)")
                })?;
                *pos += n;
                let mut a8 = [0u8; 8];
                a8[..n].copy_from_slice(b);
                if *be {
                    a8[..n].reverse();
                }
                let le = |k: usize| -> [u8; 8] {
                    let mut x = [0u8; 8];
                    x[..k].copy_from_slice(&a8[..k]);
                    x
                };
                Ok(match s {
                    Scalar::I8 => a8[0] as i8 as f64,
                    Scalar::U8 => a8[0] as f64,
                    Scalar::I16 => i16::from_le_bytes([a8[0], a8[1]]) as f64,
                    Scalar::U16 => u16::from_le_bytes([a8[0], a8[1]]) as f64,
                    Scalar::I32 => i32::from_le_bytes([a8[0], a8[1], a8[2], a8[3]]) as f64,
                    Scalar::U32 => u32::from_le_bytes([a8[0], a8[1], a8[2], a8[3]]) as f64,
                    Scalar::F32 => f32::from_le_bytes([a8[0], a8[1], a8[2], a8[3]]) as f64,
                    Scalar::F64 => f64::from_le_bytes(le(8)),
                })
            }
        }
    }
}

/// ASCII PLY with double-precision coordinates (lossless for f64).
pub fn to_ascii(mesh: &TriMesh) -> String {
    use crate::util::fmt_f64;
    let mut s = format!(
        "ply\nformat ascii 1.0\ncomment written by osim-spine; units: metres\n\
         element vertex {}\nproperty double x\nproperty double y\nproperty double z\n\
         element face {}\nproperty list uchar int vertex_indices\nend_header\n",
        mesh.vertices.len(),
        mesh.triangles.len()
    );
    for p in &mesh.vertices {
        s.push_str(&format!(
            "{} {} {}\n",
            fmt_f64(p.x),
            fmt_f64(p.y),
            fmt_f64(p.z)
        ));
    }
    for t in &mesh.triangles {
        s.push_str(&format!("3 {} {} {}\n", t[0], t[1], t[2]));
    }
    s
}

/// Write an ASCII PLY file atomically.
pub fn write(path: &Path, mesh: &TriMesh) -> Result<()> {
    crate::util::write_atomic(path, to_ascii(mesh).as_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn mesh() -> TriMesh {
        TriMesh::new(
            vec![
                Point3::new(0.1, 0.2, 0.3),
                Point3::new(1.0 / 3.0, 0.0, -1.0),
                Point3::new(0.0, 5.0, 1e-9),
            ],
            vec![[0, 1, 2]],
        )
        .unwrap()
    }

    #[test]
    fn ascii_round_trip_is_exact() {
        let m = mesh();
        let r = read_bytes(to_ascii(&m).as_bytes(), Path::new("a.ply")).unwrap();
        assert_eq!(r, m);
    }

    #[test]
    fn binary_both_endians_with_extra_properties() {
        for be in [false, true] {
            let fmt = if be {
                "binary_big_endian"
            } else {
                "binary_little_endian"
            };
            let mut b = format!(
                "ply\nformat {fmt} 1.0\nelement vertex 4\nproperty float x\nproperty float y\n\
                 property float z\nproperty uchar red\nelement face 1\n\
                 property list uchar int vertex_indices\nend_header\n"
            )
            .into_bytes();
            let pts = [
                [0.0f32, 0.0, 0.0],
                [1.0, 0.0, 0.0],
                [1.0, 1.0, 0.0],
                [0.0, 1.0, 0.5],
            ];
            for p in pts {
                for c in p {
                    b.extend(if be { c.to_be_bytes() } else { c.to_le_bytes() });
                }
                b.push(7);
            }
            b.push(4);
            for i in [0i32, 1, 2, 3] {
                b.extend(if be { i.to_be_bytes() } else { i.to_le_bytes() });
            }
            let m = read_bytes(&b, Path::new("b.ply")).unwrap();
            assert_eq!(m.triangles, vec![[0, 1, 2], [0, 2, 3]]);
            assert_eq!(m.vertices[3], Point3::new(0.0, 1.0, 0.5));
        }
    }

    #[test]
    fn bad_index_and_huge_count() {
        let s = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n\
                 property float z\nelement face 1\nproperty list uchar int vertex_indices\n\
                 end_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 3\n";
        let e = read_bytes(s.as_bytes(), Path::new("i.ply"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("i.ply") && e.contains("face 0") && e.contains("index 3"),
            "{e}"
        );
        let s = "ply\nformat binary_little_endian 1.0\nelement vertex 4000000000\n\
                 property float x\nproperty float y\nproperty float z\nend_header\n";
        let e = read_bytes(s.as_bytes(), Path::new("h.ply"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("h.ply") && e.contains("declared"), "{e}");
    }

    #[test]
    fn header_steps_read_alone() {
        let bytes = b"ply\nformat binary_big_endian 1.0\ncomment x\nelement vertex 2\n\
                      property float x\nproperty float y\nproperty double z\n\
                      element face 1\nproperty list uchar int vertex_indices\nend_header\nBODY";
        let name = Path::new("s.ply");
        let (header, body_start) = split_header(bytes, name).unwrap();
        assert_eq!(&bytes[body_start..], b"BODY");
        let (fmt, elements) = read_header(header, name).unwrap();
        assert_eq!(fmt, Fmt::Be);
        assert_eq!(elements.len(), 2);
        assert_eq!(
            (elements[0].name.as_str(), elements[0].count),
            ("vertex", 2)
        );
        assert_eq!(vertex_props(&elements[0], name).unwrap(), Some([0, 1, 2]));
        assert_eq!(face_prop(&elements[1], name).unwrap(), Some(0));
        // 2 vertices of 4 + 4 + 8 bytes and a face count byte: 33 bytes at least
        assert!(check_counts(&elements, fmt, 33, name).is_ok());
        let e = check_counts(&elements, fmt, 20, name)
            .unwrap_err()
            .to_string();
        assert!(e.contains("at least 33 bytes"), "{e}");
        // a polygon becomes a fan; an index past the vertices is refused
        let tris = triangulate(vec![(vec![0, 1, 2, 3], 0)], 4, name).unwrap();
        assert_eq!(tris, vec![[0, 1, 2], [0, 2, 3]]);
        assert!(triangulate(vec![(vec![0, 1, 4], 0)], 4, name).is_err());
    }
}
