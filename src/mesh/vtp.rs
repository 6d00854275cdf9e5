//! VTK XML PolyData (`.vtp`) reading and writing.
//!
//! Reader: every `Piece` of the file is merged into one mesh. Points may be
//! Float32/Float64 (or integer) arrays; cell arrays any integer type. Data
//! may be `ascii`, inline `binary` (base64, with the byte-count header
//! encoded separately or together with the data), or `appended` (raw or
//! base64 `AppendedData`), optionally compressed with
//! `vtkZLibDataCompressor` (block headers); `header_type` UInt32 or UInt64
//! and either `byte_order`. Polygons with more than three vertices are
//! triangulated as fans, triangle strips are converted with alternating
//! winding, and `Verts`/`Lines`/`PointData`/`CellData` are ignored. The
//! winding of the file's polygons is kept as it is.
//!
//! Declared sizes are never trusted for allocation: every count is checked
//! against the bytes actually present before memory is reserved, and zlib
//! blocks are inflated with a hard limit.
//!
//! Writer: [`to_ascii`] (the default of [`super::write`]) and
//! [`to_binary`]/[`write_binary`] (base64, optionally zlib-compressed), all
//! with Float64 points and Int64 connectivity, so a round trip is bit-exact.

use super::TriMesh;
use crate::error::{Error, Result};
use base64::Engine as _;
use nalgebra::Point3;
use std::io::Read;
use std::path::Path;

/// Largest expansion ratio that zlib can achieve (deflate's theoretical
/// limit is about 1032:1); declared uncompressed sizes beyond this times the
/// compressed size are rejected before inflating.
const ZLIB_MAX_RATIO: u64 = 1100;
/// Uncompressed block size used by the writer.
const BLOCK_SIZE: usize = 1 << 15;

/// Read a VTP file.
pub fn read(path: &Path) -> Result<TriMesh> {
    let bytes = super::read_file_bytes(path)?;
    read_bytes(&bytes, path)
}

// ---------------------------------------------------------------------------
// A minimal element tree of the XML part.

#[derive(Debug, Default)]
struct Elem {
    name: String,
    attrs: Vec<(String, String)>,
    text: String,
    children: Vec<Elem>,
    line: usize,
}

impl Elem {
    fn attr(&self, key: &str) -> Option<&str> {
        self.attrs
            .iter()
            .find(|(k, _)| k == key)
            .map(|(_, v)| v.as_str())
    }
    fn child(&self, name: &str) -> Option<&Elem> {
        self.children.iter().find(|c| c.name == name)
    }
    fn children_named<'a>(&'a self, name: &'a str) -> impl Iterator<Item = &'a Elem> + 'a {
        self.children.iter().filter(move |c| c.name == name)
    }
}

/// Parse the XML part with the crate's one XML tree
/// ([`crate::osim::xml::parse`]), so VTP files obey the same hostile-input
/// rules as `.osim` documents: no DOCTYPE, only the five predefined entities
/// and numeric character references, bounded nesting. The root is returned
/// as the only child of a `#document` element.
fn parse_xml(xml: &[u8], name: &Path) -> Result<Elem> {
    let text = std::str::from_utf8(xml).map_err(|e| {
        let line = super::line_of(xml, e.valid_up_to());
        Error::parse(name, format!("line {line}"), "XML part is not UTF-8 text")
    })?;
    let tree = crate::osim::xml::parse(text, name)?;
    Ok(Elem {
        name: "#document".into(),
        children: vec![to_elem(tree.root)],
        ..Default::default()
    })
}

/// The VTP reader's view of an element: attributes, text (text and CDATA
/// concatenated), child elements.
fn to_elem(el: crate::osim::xml::Element) -> Elem {
    let text = el.text();
    let children = el
        .children
        .into_iter()
        .filter_map(|n| match n {
            crate::osim::xml::Node::Element(e) => Some(to_elem(e)),
            _ => None,
        })
        .collect();
    Elem {
        name: el.name,
        attrs: el.attrs,
        text,
        children,
        line: el.line,
    }
}

// ---------------------------------------------------------------------------
// File-level settings.

#[derive(Debug, Clone, Copy, PartialEq)]
enum NumType {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    I64,
    U64,
    F32,
    F64,
}

impl NumType {
    fn parse(s: &str) -> Option<NumType> {
        Some(match s {
            "Int8" | "Char" => NumType::I8,
            "UInt8" | "UChar" => NumType::U8,
            "Int16" => NumType::I16,
            "UInt16" => NumType::U16,
            "Int32" => NumType::I32,
            "UInt32" => NumType::U32,
            "Int64" => NumType::I64,
            "UInt64" => NumType::U64,
            "Float32" => NumType::F32,
            "Float64" => NumType::F64,
            _ => return None,
        })
    }
    fn size(self) -> usize {
        match self {
            NumType::I8 | NumType::U8 => 1,
            NumType::I16 | NumType::U16 => 2,
            NumType::I32 | NumType::U32 | NumType::F32 => 4,
            NumType::I64 | NumType::U64 | NumType::F64 => 8,
        }
    }
    fn is_float(self) -> bool {
        matches!(self, NumType::F32 | NumType::F64)
    }
}

#[derive(Debug, Clone, Copy)]
struct Settings {
    big_endian: bool,
    header64: bool,
    zlib: bool,
}

/// The appended-data section, cut out of the file before XML parsing.
struct Appended<'a> {
    data: &'a [u8],
    base64: bool,
}

/// Split off `<AppendedData ...>_DATA</AppendedData>`: returns the XML with
/// that element removed, and the data after the underscore.
fn split_appended<'a>(bytes: &'a [u8], name: &Path) -> Result<(Vec<u8>, Option<Appended<'a>>)> {
    let Some(start) = find(bytes, b"<AppendedData") else {
        return Ok((bytes.to_vec(), None));
    };
    let line = super::line_of(bytes, start);
    let loc = || format!("line {line}, <AppendedData>");
    let gt = find(&bytes[start..], b">")
        .map(|k| start + k)
        .ok_or_else(|| Error::parse(name, loc(), "unterminated <AppendedData> tag"))?;
    let tag = String::from_utf8_lossy(&bytes[start..gt]);
    let base64 = if tag.contains("encoding=\"base64\"") || tag.contains("encoding='base64'") {
        true
    } else if tag.contains("encoding=\"raw\"") || tag.contains("encoding='raw'") {
        false
    } else {
        return Err(Error::parse(
            name,
            loc(),
            "AppendedData needs encoding=\"raw\" or encoding=\"base64\"",
        ));
    };
    let us = bytes[gt + 1..]
        .iter()
        .position(|&b| b == b'_')
        .map(|k| gt + 1 + k)
        .ok_or_else(|| Error::parse(name, loc(), "AppendedData has no `_` data marker"))?;
    if bytes[gt + 1..us].iter().any(|b| !b.is_ascii_whitespace()) {
        return Err(Error::parse(
            name,
            loc(),
            "unexpected characters before the `_` data marker",
        ));
    }
    let close = rfind(bytes, b"</AppendedData>")
        .filter(|&k| k > us)
        .ok_or_else(|| Error::parse(name, loc(), "AppendedData is not closed (truncated file?)"))?;
    let mut xml = bytes[..start].to_vec();
    xml.extend_from_slice(&bytes[close + b"</AppendedData>".len()..]);
    Ok((
        xml,
        Some(Appended {
            data: &bytes[us + 1..close],
            base64,
        }),
    ))
}

fn find(hay: &[u8], needle: &[u8]) -> Option<usize> {
    hay.windows(needle.len()).position(|w| w == needle)
}

fn rfind(hay: &[u8], needle: &[u8]) -> Option<usize> {
    hay.windows(needle.len()).rposition(|w| w == needle)
}

/// Parse VTP bytes; `name` is used in error messages.
pub fn read_bytes(bytes: &[u8], name: &Path) -> Result<TriMesh> {
    let (xml, appended) = split_appended(bytes, name)?;
    let doc = parse_xml(&xml, name)?;
    let root = doc.child("VTKFile").ok_or_else(|| {
        Error::parse(
            name,
            "line 1",
            "no <VTKFile> root element: not a VTK XML file",
        )
    })?;
    let rloc = format!("line {}, <VTKFile>", root.line);
    match root.attr("type") {
        Some("PolyData") => {}
        other => {
            return Err(Error::parse(
                name,
                rloc,
                format!("type=\"{}\", expected \"PolyData\"", other.unwrap_or("")),
            ))
        }
    }
    let big_endian = match root.attr("byte_order").unwrap_or("LittleEndian") {
        "LittleEndian" => false,
        "BigEndian" => true,
        o => {
            return Err(Error::parse(
                name,
                rloc,
                format!("byte_order `{o}`, expected LittleEndian or BigEndian"),
            ))
        }
    };
    let header64 = match root.attr("header_type").unwrap_or("UInt32") {
        "UInt32" => false,
        "UInt64" => true,
        o => {
            return Err(Error::parse(
                name,
                rloc,
                format!("header_type `{o}`, expected UInt32 or UInt64"),
            ))
        }
    };
    let zlib = match root.attr("compressor") {
        None | Some("") => false,
        Some("vtkZLibDataCompressor") => true,
        Some(o) => {
            return Err(Error::parse(
                name,
                rloc,
                format!("compressor `{o}` is not supported (only vtkZLibDataCompressor)"),
            ))
        }
    };
    let settings = Settings {
        big_endian,
        header64,
        zlib,
    };
    let poly = root
        .child("PolyData")
        .ok_or_else(|| Error::parse(name, rloc.clone(), "no <PolyData> element"))?;
    let mut mesh = TriMesh::default();
    let mut n_pieces = 0;
    for (p, piece) in poly.children_named("Piece").enumerate() {
        n_pieces += 1;
        let ctx = Ctx {
            name,
            settings,
            appended: appended.as_ref(),
            file_len: bytes.len(),
        };
        let part = read_piece(&ctx, piece, p)?;
        let base = mesh.vertices.len();
        if base + part.vertices.len() > u32::MAX as usize {
            return Err(Error::parse(name, format!("Piece {p}"), "too many points"));
        }
        mesh.vertices.extend(part.vertices);
        mesh.triangles.extend(
            part.triangles
                .into_iter()
                .map(|t| t.map(|k| k + base as u32)),
        );
    }
    if n_pieces == 0 {
        return Err(Error::parse(
            name,
            format!("line {}, <PolyData>", poly.line),
            "no <Piece> element",
        ));
    }
    Ok(mesh)
}

struct Ctx<'a> {
    name: &'a Path,
    settings: Settings,
    appended: Option<&'a Appended<'a>>,
    file_len: usize,
}

fn count_attr(ctx: &Ctx, piece: &Elem, key: &str, loc: &str, required: bool) -> Result<usize> {
    match piece.attr(key) {
        None if !required => Ok(0),
        None => Err(Error::parse(
            ctx.name,
            loc,
            format!("missing attribute {key}"),
        )),
        Some(v) => v.trim().parse::<usize>().map_err(|_| {
            Error::parse(
                ctx.name,
                loc,
                format!("{key}=\"{v}\" is not a non-negative integer"),
            )
        }),
    }
}

/// The `<Points>` of a piece: `n_points` finite 3-D points.
fn read_points(ctx: &Ctx, piece: &Elem, p: usize, n_points: usize) -> Result<Vec<Point3<f64>>> {
    let name = ctx.name;
    let loc = format!("line {}, Piece {p}", piece.line);
    let mut vertices = Vec::new();
    let pts = piece
        .child("Points")
        .ok_or_else(|| Error::parse(name, loc.clone(), "no <Points> element"))?;
    let da = pts.child("DataArray").ok_or_else(|| {
        Error::parse(
            name,
            format!("line {}, Piece {p} Points", pts.line),
            "no <DataArray> in <Points>",
        )
    })?;
    let aloc = format!("line {}, Piece {p} Points DataArray", da.line);
    let ncomp = da.attr("NumberOfComponents").unwrap_or("1");
    if ncomp.trim() != "3" {
        return Err(Error::parse(
            name,
            aloc,
            format!("NumberOfComponents=\"{ncomp}\", expected 3"),
        ));
    }
    let vals = read_array(ctx, da, &aloc, Some(3 * n_points))?;
    let vals = vals.into_f64();
    vertices.reserve(n_points);
    for (i, c) in vals.chunks_exact(3).enumerate() {
        let pt = Point3::new(c[0], c[1], c[2]);
        if !pt.coords.iter().all(|x| x.is_finite()) {
            return Err(Error::parse(
                name,
                aloc,
                format!(
                    "point {i} has a non-finite coordinate ({}, {}, {})",
                    c[0], c[1], c[2]
                ),
            ));
        }
        vertices.push(pt);
    }
    Ok(vertices)
}

fn read_piece(ctx: &Ctx, piece: &Elem, p: usize) -> Result<TriMesh> {
    let name = ctx.name;
    let loc = format!("line {}, Piece {p}", piece.line);
    let n_points = count_attr(ctx, piece, "NumberOfPoints", &loc, true)?;
    let n_polys = count_attr(ctx, piece, "NumberOfPolys", &loc, false)?;
    let n_strips = count_attr(ctx, piece, "NumberOfStrips", &loc, false)?;
    // A point needs at least a few bytes in any encoding: refuse absurd
    // declarations before allocating anything from them.
    for (k, n) in [
        ("NumberOfPoints", n_points),
        ("NumberOfPolys", n_polys),
        ("NumberOfStrips", n_strips),
    ] {
        if n > ctx.file_len {
            return Err(Error::parse(
                name,
                loc.clone(),
                format!("{k}={n} cannot fit in a file of {} bytes", ctx.file_len),
            ));
        }
    }
    let vertices = if n_points > 0 {
        read_points(ctx, piece, p, n_points)?
    } else {
        Vec::new()
    };
    let mut triangles = Vec::new();
    for (section, n_cells, strips) in [("Polys", n_polys, false), ("Strips", n_strips, true)] {
        if n_cells == 0 {
            continue;
        }
        let sec = piece.child(section).ok_or_else(|| {
            Error::parse(
                name,
                loc.clone(),
                format!("Number{section}={n_cells} but no <{section}> element"),
            )
        })?;
        let get = |arr: &str| -> Result<Vec<i64>> {
            let da = sec
                .children_named("DataArray")
                .find(|d| d.attr("Name") == Some(arr))
                .ok_or_else(|| {
                    Error::parse(
                        name,
                        format!("line {}, Piece {p} {section}", sec.line),
                        format!("no DataArray Name=\"{arr}\""),
                    )
                })?;
            let aloc = format!("line {}, Piece {p} {section} {arr}", da.line);
            let expected = if arr == "offsets" {
                Some(n_cells)
            } else {
                None
            };
            read_array(ctx, da, &aloc, expected)?.into_i64(name, &aloc)
        };
        let conn = get("connectivity")?;
        let offs = get("offsets")?;
        let cloc = format!("line {}, Piece {p} {section}", sec.line);
        let mut start = 0usize;
        for (c, &end) in offs.iter().enumerate() {
            let end_u = usize::try_from(end)
                .ok()
                .filter(|&e| e >= start && e <= conn.len());
            let Some(end_u) = end_u else {
                return Err(Error::parse(
                    name,
                    cloc,
                    format!(
                        "cell {c}: offset {end} is out of order or past the {} connectivity entries",
                        conn.len()
                    ),
                ));
            };
            let cell = &conn[start..end_u];
            let idx = |k: usize| -> Result<u32> {
                let v = cell[k];
                if v < 0 || v as u64 >= n_points as u64 {
                    Err(Error::parse(
                        name,
                        cloc.clone(),
                        format!("cell {c}: point index {v} is outside 0..{n_points}"),
                    ))
                } else {
                    Ok(v as u32)
                }
            };
            if cell.len() < 3 {
                return Err(Error::parse(
                    name,
                    cloc,
                    format!("cell {c} has {} points, at least 3 expected", cell.len()),
                ));
            }
            if strips {
                for j in 0..cell.len() - 2 {
                    let (a, b, d) = (idx(j)?, idx(j + 1)?, idx(j + 2)?);
                    triangles.push(if j % 2 == 0 { [a, b, d] } else { [b, a, d] });
                }
            } else {
                let a = idx(0)?;
                for j in 1..cell.len() - 1 {
                    triangles.push([a, idx(j)?, idx(j + 1)?]);
                }
            }
            start = end_u;
        }
        if start != conn.len() {
            return Err(Error::parse(
                name,
                cloc,
                format!(
                    "the last offset is {start} but connectivity has {} entries",
                    conn.len()
                ),
            ));
        }
    }
    Ok(TriMesh {
        vertices,
        triangles,
    })
}

enum Values {
    F(Vec<f64>),
    I(Vec<i64>),
}

impl Values {
    fn into_f64(self) -> Vec<f64> {
        match self {
            Values::F(v) => v,
            Values::I(v) => v.into_iter().map(|x| x as f64).collect(),
        }
    }
    fn into_i64(self, name: &Path, loc: &str) -> Result<Vec<i64>> {
        match self {
            Values::I(v) => Ok(v),
            Values::F(_) => Err(Error::parse(
                name,
                loc,
                "cell arrays must have an integer type, not a float type",
            )),
        }
    }
}

fn read_array(ctx: &Ctx, da: &Elem, loc: &str, expected: Option<usize>) -> Result<Values> {
    let name = ctx.name;
    let ty_s = da.attr("type").unwrap_or("");
    let ty = NumType::parse(ty_s).ok_or_else(|| {
        Error::parse(
            name,
            loc,
            format!("type=\"{ty_s}\" is not a VTK numeric type (Float32, Float64, Int32, ...)"),
        )
    })?;
    let format = da.attr("format").unwrap_or("");
    let values = match format {
        "ascii" => parse_ascii(&da.text, ty, name, loc)?,
        "binary" => {
            let s = &ctx.settings;
            let (header, data) = split_base64(da.text.as_bytes(), s, name, loc)?;
            let raw = decode_blob(&header, &data, s, ty, expected, name, loc)?;
            from_raw(&raw, ty, s.big_endian)
        }
        "appended" => {
            let app = ctx.appended.ok_or_else(|| {
                Error::parse(
                    name,
                    loc,
                    "format=\"appended\" but the file has no <AppendedData>",
                )
            })?;
            let off_s = da.attr("offset").unwrap_or("");
            let off: usize = off_s.trim().parse().map_err(|_| {
                Error::parse(
                    name,
                    loc,
                    format!("offset=\"{off_s}\" is not a non-negative integer"),
                )
            })?;
            let rest = app.data.get(off..).ok_or_else(|| {
                Error::parse(
                    name,
                    loc,
                    format!(
                        "offset {off} is past the {} bytes of AppendedData",
                        app.data.len()
                    ),
                )
            })?;
            let s = &ctx.settings;
            let (header, data) = if app.base64 {
                split_base64(rest, s, name, loc)?
            } else {
                split_raw(rest, s, name, loc)?
            };
            let raw = decode_blob(&header, &data, s, ty, expected, name, loc)?;
            from_raw(&raw, ty, s.big_endian)
        }
        o => {
            return Err(Error::parse(
                name,
                loc,
                format!("format=\"{o}\", expected ascii, binary or appended"),
            ))
        }
    };
    if let Some(n) = expected {
        let got = match &values {
            Values::F(v) => v.len(),
            Values::I(v) => v.len(),
        };
        if got != n {
            return Err(Error::parse(
                name,
                loc,
                format!("has {got} values, expected {n} from the Piece's declared counts"),
            ));
        }
    }
    Ok(values)
}

fn parse_ascii(text: &str, ty: NumType, name: &Path, loc: &str) -> Result<Values> {
    let bad = |k: usize, t: &str, what: &str| {
        let shown: String = t.chars().take(24).collect();
        Error::parse(name, loc, format!("value {k} `{shown}` is not {what}"))
    };
    if ty.is_float() {
        text.split_ascii_whitespace()
            .enumerate()
            .map(|(k, t)| t.parse::<f64>().map_err(|_| bad(k, t, "a number")))
            .collect::<Result<Vec<_>>>()
            .map(Values::F)
    } else {
        text.split_ascii_whitespace()
            .enumerate()
            .map(|(k, t)| t.parse::<i64>().map_err(|_| bad(k, t, "an integer")))
            .collect::<Result<Vec<_>>>()
            .map(Values::I)
    }
}

fn word(bytes: &[u8], i: usize, s: &Settings) -> Option<u64> {
    if s.header64 {
        let b: [u8; 8] = bytes.get(8 * i..8 * i + 8)?.try_into().ok()?;
        Some(if s.big_endian {
            u64::from_be_bytes(b)
        } else {
            u64::from_le_bytes(b)
        })
    } else {
        let b: [u8; 4] = bytes.get(4 * i..4 * i + 4)?.try_into().ok()?;
        Some(if s.big_endian {
            u32::from_be_bytes(b)
        } else {
            u32::from_le_bytes(b)
        } as u64)
    }
}

fn header_words(s: &Settings) -> usize {
    if s.header64 {
        8
    } else {
        4
    }
}

fn b64(text: &[u8], name: &Path, loc: &str) -> Result<Vec<u8>> {
    base64::engine::general_purpose::STANDARD
        .decode(text)
        .map_err(|e| Error::parse(name, loc, format!("invalid base64 data: {e}")))
}

/// Header size in bytes, given the start of the (decoded) header.
fn header_len(
    first_words: &[u8],
    avail: usize,
    s: &Settings,
    name: &Path,
    loc: &str,
) -> Result<usize> {
    let w = header_words(s);
    if !s.zlib {
        return Ok(w);
    }
    let nb = word(first_words, 0, s).ok_or_else(|| {
        Error::parse(
            name,
            loc,
            "binary data too short for the compression header",
        )
    })?;
    // Each block needs at least one byte of data.
    if nb > avail as u64 {
        return Err(Error::parse(
            name,
            loc,
            format!("compression header declares {nb} blocks, more than the data can hold"),
        ));
    }
    Ok((3 + nb as usize) * w)
}

/// Bytes of (possibly compressed) payload that follow a decoded header.
fn payload_len(header: &[u8], s: &Settings, name: &Path, loc: &str) -> Result<u64> {
    let get = |i: usize| {
        word(header, i, s).ok_or_else(|| Error::parse(name, loc, "truncated binary header"))
    };
    if !s.zlib {
        return get(0);
    }
    let nb = get(0)? as usize;
    let mut sum: u64 = 0;
    for i in 0..nb {
        sum = sum.saturating_add(get(3 + i)?);
    }
    Ok(sum)
}

/// Split base64 text into the decoded header and the decoded payload. The
/// header is normally encoded on its own (so it may end in `=` padding);
/// encoders that encode header and data as one stream are accepted too.
/// Only the characters that belong to this array are decoded, so the text
/// may continue with further arrays (appended data).
fn split_base64(text: &[u8], s: &Settings, name: &Path, loc: &str) -> Result<(Vec<u8>, Vec<u8>)> {
    // Whitespace is skipped; only as many characters as needed are taken
    // (linear in what this array uses, whatever follows it).
    let compact = |max: usize| -> Vec<u8> {
        text.iter()
            .copied()
            .filter(|b| !b.is_ascii_whitespace())
            .take(max)
            .collect()
    };
    let w = header_words(s);
    // The first three words (12 or 24 bytes, a multiple of 3) decode on
    // their own whichever way the header was encoded.
    let first_chars = if s.zlib { 4 * w } else { w.div_ceil(3) * 4 };
    let t = compact(first_chars);
    let first = t
        .get(..first_chars)
        .ok_or_else(|| Error::parse(name, loc, "binary data too short for its header"))?;
    let first = b64(first, name, loc)?;
    let hb = header_len(&first, text.len(), s, name, loc)?;
    let hc = hb.div_ceil(3) * 4;
    let short = || {
        Error::parse(
            name,
            loc,
            "binary data is shorter than its header declares (truncated?)",
        )
    };
    let t = compact(hc);
    let head = t.get(..hc).ok_or_else(short)?;
    let separate = hb % 3 == 0 || head.last() == Some(&b'=');
    let mut header = b64(head, name, loc)?;
    header.truncate(hb);
    let n = payload_len(&header, s, name, loc)?;
    if n > text.len() as u64 {
        return Err(short());
    }
    let n = n as usize;
    if separate {
        let dc = n.div_ceil(3) * 4;
        let t = compact(hc + dc);
        let data = t.get(hc..hc + dc).ok_or_else(short)?;
        Ok((header, b64(data, name, loc)?))
    } else {
        let total = (hb + n).div_ceil(3) * 4;
        let t = compact(total);
        let all = b64(t.get(..total).ok_or_else(short)?, name, loc)?;
        let data = all.get(hb..hb + n).ok_or_else(short)?.to_vec();
        Ok((header, data))
    }
}

/// Split raw appended bytes at an array's offset into header and payload.
fn split_raw(rest: &[u8], s: &Settings, name: &Path, loc: &str) -> Result<(Vec<u8>, Vec<u8>)> {
    let hb = header_len(rest, rest.len(), s, name, loc)?;
    let header = rest
        .get(..hb)
        .ok_or_else(|| Error::parse(name, loc, "appended data too short for its header"))?;
    let n = payload_len(header, s, name, loc)?;
    let data = usize::try_from(n)
        .ok()
        .and_then(|n| rest.get(hb..hb.checked_add(n)?))
        .ok_or_else(|| {
            Error::parse(
                name,
                loc,
                format!(
                    "header declares {n} bytes but only {} follow",
                    rest.len() - hb
                ),
            )
        })?;
    Ok((header.to_vec(), data.to_vec()))
}

/// Turn header + data bytes into the raw (uncompressed) array bytes,
/// checking every declared size against what is present.
fn decode_blob(
    header: &[u8],
    data: &[u8],
    s: &Settings,
    ty: NumType,
    expected: Option<usize>,
    name: &Path,
    loc: &str,
) -> Result<Vec<u8>> {
    let need = expected.map(|n| n as u64 * ty.size() as u64);
    let check_total = |total: u64| -> Result<()> {
        if let Some(need) = need {
            if total != need {
                return Err(Error::parse(
                    name,
                    loc,
                    format!(
                        "declares {total} bytes of data, expected {need} ({} values of {} bytes)",
                        need / ty.size() as u64,
                        ty.size()
                    ),
                ));
            }
        }
        if total % ty.size() as u64 != 0 {
            return Err(Error::parse(
                name,
                loc,
                format!(
                    "declares {total} bytes, not a whole number of {}-byte values",
                    ty.size()
                ),
            ));
        }
        Ok(())
    };
    let hdr = |i: usize| {
        word(header, i, s).ok_or_else(|| Error::parse(name, loc, "truncated binary header"))
    };
    if !s.zlib {
        let n = hdr(0)?;
        check_total(n)?;
        if n > data.len() as u64 {
            return Err(Error::parse(
                name,
                loc,
                format!(
                    "header declares {n} bytes but only {} are present",
                    data.len()
                ),
            ));
        }
        return Ok(data[..n as usize].to_vec());
    }
    let nb = hdr(0)?;
    let bs = hdr(1)?;
    let last = hdr(2)?;
    if nb == 0 {
        check_total(0)?;
        return Ok(Vec::new());
    }
    let last = if last == 0 { bs } else { last };
    if last > bs {
        return Err(Error::parse(
            name,
            loc,
            format!("last block size {last} exceeds the block size {bs}"),
        ));
    }
    let total = (nb - 1)
        .checked_mul(bs)
        .and_then(|x| x.checked_add(last))
        .ok_or_else(|| Error::parse(name, loc, "compression header sizes overflow"))?;
    check_total(total)?;
    let mut csizes = Vec::with_capacity(nb as usize);
    let mut csum: u64 = 0;
    for i in 0..nb as usize {
        let c = hdr(3 + i)?;
        csum = csum.saturating_add(c);
        csizes.push(c);
    }
    if csum > data.len() as u64 {
        return Err(Error::parse(
            name,
            loc,
            format!(
                "compressed blocks total {csum} bytes but only {} are present",
                data.len()
            ),
        ));
    }
    if total > csum.saturating_mul(ZLIB_MAX_RATIO) + 64 {
        return Err(Error::parse(
            name,
            loc,
            format!("declares {total} uncompressed bytes from {csum} compressed bytes: impossible for zlib"),
        ));
    }
    let mut out = Vec::with_capacity(total as usize);
    let mut pos = 0usize;
    for (i, &c) in csizes.iter().enumerate() {
        let want = if i as u64 == nb - 1 { last } else { bs };
        let block = &data[pos..pos + c as usize];
        pos += c as usize;
        let before = out.len();
        flate2::read::ZlibDecoder::new(block)
            .take(want + 1)
            .read_to_end(&mut out)
            .map_err(|e| {
                Error::parse(name, loc, format!("zlib block {i} does not inflate: {e}"))
            })?;
        let got = (out.len() - before) as u64;
        if got != want {
            return Err(Error::parse(
                name,
                loc,
                format!("zlib block {i} inflates to {got} bytes, the header says {want}"),
            ));
        }
    }
    Ok(out)
}

fn from_raw(raw: &[u8], ty: NumType, be: bool) -> Values {
    macro_rules! conv {
        ($t:ty, $n:expr, $variant:ident, $cast:ty) => {
            Values::$variant(
                raw.chunks_exact($n)
                    .map(|c| {
                        let mut b = [0u8; $n];
                        b.copy_from_slice(c);
                        (if be {
                            <$t>::from_be_bytes(b)
                        } else {
                            <$t>::from_le_bytes(b)
                        }) as $cast
                    })
                    .collect(),
            )
        };
    }
    match ty {
        NumType::I8 => conv!(i8, 1, I, i64),
        NumType::U8 => conv!(u8, 1, I, i64),
        NumType::I16 => conv!(i16, 2, I, i64),
        NumType::U16 => conv!(u16, 2, I, i64),
        NumType::I32 => conv!(i32, 4, I, i64),
        NumType::U32 => conv!(u32, 4, I, i64),
        NumType::I64 => conv!(i64, 8, I, i64),
        // Values above i64::MAX wrap negative and are then rejected as
        // out-of-range point indices.
        NumType::U64 => conv!(u64, 8, I, i64),
        NumType::F32 => conv!(f32, 4, F, f64),
        NumType::F64 => conv!(f64, 8, F, f64),
    }
}

// ---------------------------------------------------------------------------
// Writing.

/// How array data are stored by the writer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Encoding {
    Ascii,
    Base64,
    Zlib,
}

fn document(mesh: &TriMesh, enc: Encoding) -> String {
    use crate::util::fmt_f64;
    let n = mesh.vertices.len();
    let m = mesh.triangles.len();
    let compressor = if enc == Encoding::Zlib {
        " compressor=\"vtkZLibDataCompressor\""
    } else {
        ""
    };
    let format = if enc == Encoding::Ascii {
        "ascii"
    } else {
        "binary"
    };
    let mut s = format!(
        "<?xml version=\"1.0\"?>\n<VTKFile type=\"PolyData\" version=\"1.0\" \
         byte_order=\"LittleEndian\" header_type=\"UInt64\"{compressor}>\n  <PolyData>\n    \
         <Piece NumberOfPoints=\"{n}\" NumberOfVerts=\"0\" NumberOfLines=\"0\" \
         NumberOfStrips=\"0\" NumberOfPolys=\"{m}\">\n      <Points>\n        <DataArray \
         type=\"Float64\" Name=\"Points\" NumberOfComponents=\"3\" format=\"{format}\">\n"
    );
    let pts: Vec<f64> = mesh.vertices.iter().flat_map(|p| [p.x, p.y, p.z]).collect();
    let conn: Vec<i64> = mesh
        .triangles
        .iter()
        .flat_map(|t| t.map(|k| k as i64))
        .collect();
    let offs: Vec<i64> = (1..=m as i64).map(|k| 3 * k).collect();
    match enc {
        Encoding::Ascii => {
            for p in &mesh.vertices {
                s.push_str(&format!(
                    "          {} {} {}\n",
                    fmt_f64(p.x),
                    fmt_f64(p.y),
                    fmt_f64(p.z)
                ));
            }
        }
        _ => push_blob(&mut s, &f64_bytes(&pts), enc),
    }
    s.push_str("        </DataArray>\n      </Points>\n      <Polys>\n");
    for (nm, vals) in [("connectivity", &conn), ("offsets", &offs)] {
        s.push_str(&format!(
            "        <DataArray type=\"Int64\" Name=\"{nm}\" format=\"{format}\">\n"
        ));
        match enc {
            Encoding::Ascii => {
                for chunk in vals.chunks(if nm == "connectivity" { 3 } else { 12 }) {
                    let line: Vec<String> = chunk.iter().map(|v| v.to_string()).collect();
                    s.push_str(&format!("          {}\n", line.join(" ")));
                }
            }
            _ => push_blob(&mut s, &i64_bytes(vals), enc),
        }
        s.push_str("        </DataArray>\n");
    }
    s.push_str("      </Polys>\n    </Piece>\n  </PolyData>\n</VTKFile>\n");
    s
}

fn f64_bytes(v: &[f64]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

fn i64_bytes(v: &[i64]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

/// Append one base64 blob (UInt64 header encoded separately, as VTK does).
fn push_blob(s: &mut String, raw: &[u8], enc: Encoding) {
    use std::io::Write;
    let e = &base64::engine::general_purpose::STANDARD;
    let (header, data): (Vec<u8>, Vec<u8>) = if enc == Encoding::Zlib {
        let blocks: Vec<&[u8]> = raw.chunks(BLOCK_SIZE).collect();
        let mut comp = Vec::new();
        let mut sizes = Vec::new();
        for b in &blocks {
            let mut z = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::default());
            // Writing into a Vec cannot fail.
            let _ = z.write_all(b);
            let c = z.finish().unwrap_or_default();
            sizes.push(c.len() as u64);
            comp.extend_from_slice(&c);
        }
        let last = blocks.last().map_or(0, |b| b.len());
        let last = if last == BLOCK_SIZE { 0 } else { last };
        let mut h: Vec<u64> = vec![blocks.len() as u64, BLOCK_SIZE as u64, last as u64];
        h.extend(sizes);
        (h.iter().flat_map(|x| x.to_le_bytes()).collect(), comp)
    } else {
        ((raw.len() as u64).to_le_bytes().to_vec(), raw.to_vec())
    };
    s.push_str("          ");
    s.push_str(&e.encode(header));
    s.push_str(&e.encode(data));
    s.push('\n');
}

/// VTP with ASCII arrays (Float64 points, shortest round-trip numbers).
pub fn to_ascii(mesh: &TriMesh) -> String {
    document(mesh, Encoding::Ascii)
}

/// VTP with inline base64 binary arrays (Float64 points, Int64 cells,
/// UInt64 headers), zlib-compressed in 32 KiB blocks when `compress`.
pub fn to_binary(mesh: &TriMesh, compress: bool) -> String {
    document(
        mesh,
        if compress {
            Encoding::Zlib
        } else {
            Encoding::Base64
        },
    )
}

/// Write an ASCII VTP atomically.
pub fn write(path: &Path, mesh: &TriMesh) -> Result<()> {
    crate::util::write_atomic(path, to_ascii(mesh).as_bytes())
}

/// Write a binary (base64, optionally zlib-compressed) VTP atomically.
pub fn write_binary(path: &Path, mesh: &TriMesh, compress: bool) -> Result<()> {
    crate::util::write_atomic(path, to_binary(mesh, compress).as_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn mesh() -> TriMesh {
        // A quad split in two plus a third triangle, odd coordinates.
        TriMesh::new(
            vec![
                Point3::new(0.1, 0.2, 0.3),
                Point3::new(1.0 / 3.0, -2e-9, 7.5),
                Point3::new(-1e-300, 5.0, std::f64::consts::PI),
                Point3::new(0.0, 0.0, -0.7),
            ],
            vec![[0, 1, 2], [0, 2, 3], [3, 2, 1]],
        )
        .unwrap()
    }

    #[test]
    fn all_encodings_round_trip_bit_exact() {
        let m = mesh();
        for text in [to_ascii(&m), to_binary(&m, false), to_binary(&m, true)] {
            let r = read_bytes(text.as_bytes(), Path::new("m.vtp")).unwrap();
            assert_eq!(r, m, "{text}");
        }
    }

    #[test]
    fn big_mesh_uses_several_zlib_blocks() {
        let n = 5000;
        let vertices: Vec<_> = (0..n)
            .map(|i| Point3::new(i as f64 * 1e-3, (i as f64).sin(), (i as f64).cos()))
            .collect();
        let triangles: Vec<[u32; 3]> = (0..n as u32 - 2).map(|i| [i, i + 1, i + 2]).collect();
        let m = TriMesh::new(vertices, triangles).unwrap();
        let text = to_binary(&m, true);
        assert_eq!(read_bytes(text.as_bytes(), Path::new("b.vtp")).unwrap(), m);
    }

    #[test]
    fn strips_and_polygons() {
        let text = r#"<VTKFile type="PolyData" version="0.1">
<PolyData><Piece NumberOfPoints="5" NumberOfPolys="1" NumberOfStrips="1">
<Points><DataArray type="Float32" NumberOfComponents="3" format="ascii">
0 0 0  1 0 0  1 1 0  0 1 0  2 0 0</DataArray></Points>
<PointData Normals="n"><DataArray type="Float32" Name="n" NumberOfComponents="3" format="ascii">0 0 1</DataArray></PointData>
<Polys><DataArray type="Int32" Name="connectivity" format="ascii">0 1 2 3</DataArray>
<DataArray type="Int32" Name="offsets" format="ascii">4</DataArray></Polys>
<Strips><DataArray type="Int32" Name="connectivity" format="ascii">0 1 3 2 4</DataArray>
<DataArray type="Int32" Name="offsets" format="ascii">5</DataArray></Strips>
</Piece></PolyData></VTKFile>"#;
        let m = read_bytes(text.as_bytes(), Path::new("s.vtp")).unwrap();
        assert_eq!(
            m.triangles,
            vec![[0, 1, 2], [0, 2, 3], [0, 1, 3], [3, 1, 2], [3, 2, 4]]
        );
    }

    #[test]
    fn appended_raw_and_base64() {
        let m = mesh();
        let pts: Vec<f64> = m.vertices.iter().flat_map(|p| [p.x, p.y, p.z]).collect();
        let conn: Vec<i32> = m.triangles.iter().flatten().map(|&k| k as i32).collect();
        let offs: Vec<i32> = vec![3, 6, 9];
        let blob = |raw: Vec<u8>| {
            let mut b = (raw.len() as u32).to_le_bytes().to_vec();
            b.extend(raw);
            b
        };
        let a = blob(f64_bytes(&pts));
        let b = blob(conn.iter().flat_map(|x| x.to_le_bytes()).collect());
        let c = blob(offs.iter().flat_map(|x| x.to_le_bytes()).collect());
        let head = |o: [usize; 3], enc: &str| {
            format!(
                r#"<VTKFile type="PolyData" byte_order="LittleEndian">
<PolyData><Piece NumberOfPoints="4" NumberOfPolys="3">
<Points><DataArray type="Float64" NumberOfComponents="3" format="appended" offset="{}"/></Points>
<Polys><DataArray type="Int32" Name="connectivity" format="appended" offset="{}"/>
<DataArray type="Int32" Name="offsets" format="appended" offset="{}"/></Polys>
</Piece></PolyData>
<AppendedData encoding="{enc}">
_"#,
                o[0], o[1], o[2]
            )
        };
        // raw
        let mut raw = head([0, a.len(), a.len() + b.len()], "raw").into_bytes();
        raw.extend(&a);
        raw.extend(&b);
        raw.extend(&c);
        raw.extend(b"\n</AppendedData>\n</VTKFile>\n");
        assert_eq!(read_bytes(&raw, Path::new("r.vtp")).unwrap(), m);
        // base64, each blob encoded on its own (header + data together)
        let e = &base64::engine::general_purpose::STANDARD;
        let (ea, eb, ec) = (e.encode(&a), e.encode(&b), e.encode(&c));
        let mut t = head([0, ea.len(), ea.len() + eb.len()], "base64");
        t.push_str(&ea);
        t.push_str(&eb);
        t.push_str(&ec);
        t.push_str("\n</AppendedData>\n</VTKFile>\n");
        assert_eq!(read_bytes(t.as_bytes(), Path::new("b.vtp")).unwrap(), m);
    }

    #[test]
    fn huge_declared_counts_are_refused_without_allocating() {
        let t = r#"<VTKFile type="PolyData"><PolyData><Piece NumberOfPoints="999999999999" NumberOfPolys="0">
</Piece></PolyData></VTKFile>"#;
        let e = read_bytes(t.as_bytes(), Path::new("h.vtp"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("h.vtp") && e.contains("cannot fit"), "{e}");
        // A zlib header promising 2^40 bytes from a few compressed bytes.
        let mut h: Vec<u8> = Vec::new();
        for w in [1u32, u32::MAX, u32::MAX, 4] {
            h.extend(w.to_le_bytes());
        }
        let e64 = base64::engine::general_purpose::STANDARD;
        let blob = format!("{}{}", e64.encode(&h), e64.encode([0u8; 4]));
        let t = format!(
            r#"<VTKFile type="PolyData" compressor="vtkZLibDataCompressor"><PolyData><Piece NumberOfPoints="1">
<Points><DataArray type="Float32" NumberOfComponents="3" format="binary">{blob}</DataArray></Points>
</Piece></PolyData></VTKFile>"#
        );
        let e = read_bytes(t.as_bytes(), Path::new("z.vtp"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("z.vtp") && e.contains("declares"), "{e}");
    }
}
