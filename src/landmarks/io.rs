//! Landmark file readers (CSV, TRC, JSON) and the CSV writer.
//!
//! Readers produce [`RawLandmarks`]: the points exactly as written (file
//! units, file frame, names as spelled, duplicates kept, line numbers), plus
//! the header's declared units and frame. [`RawLandmarks::to_set`] then
//! detects units and frame from the anatomy ([`super::detect`]) and builds a
//! validated [`LandmarkSet`] (metres, OpenSim frame), refusing anything
//! ambiguous; `osim-spine check` works on the raw form to report every
//! problem rather than the first.
//!
//! Format decisions (extending `../shared/formats/landmarks.md`):
//! - CSV: `# units:` / `# frame:` header comments; optional leading
//!   `operator,repetition` columns (repeated palpations); a single-palpation
//!   file may also carry `# operator:` / `# repetition:` comments.
//! - TRC: units from the header's `Units` column; no frame (detected); the
//!   i-th marker name owns data columns `2+3i..2+3i+2` as in OpenSim;
//!   markers without a `<LEVEL>_` prefix (skin or model markers) are
//!   skipped and named in the notes. With
//!   several frames the landmark is the **mean over the frames** where it is
//!   present (palpations are static); frames that disagree by more than
//!   5 mm are refused as not static.
//! - JSON: `{"units", "frame", "landmarks": {name: [x, y, z]}}`, optional
//!   `operator`, `repetition`; other top-level keys (metadata) are ignored
//!   and named in the notes; duplicate names are detected (not silently
//!   merged).
//! - Every reader accepts a UTF-8 byte-order mark and CRLF line ends; CSV
//!   is split by [`crate::util::table`] (cells may be quoted, and a quoted
//!   cell may hold commas); rows may end with empty cells (trailing commas).
//! - Files larger than [`MAX_FILE_BYTES`] are refused before reading.

pub use super::raw::{FileFormat, Palpation, RawLandmarks, RawPoint};
use super::{Frame, LandmarkId, LandmarkSet, Units};
use crate::error::{Error, Result};
use crate::util::table::{comment_value, strip_bom, unquote, CsvReader};
use crate::util::{fmt_f64, write_atomic};
use std::path::Path;

/// Largest landmark file accepted (a 17-level set is ~10 kB; a 1000-palpation
/// study ~10 MB).
pub const MAX_FILE_BYTES: u64 = 32 * 1024 * 1024;

fn format_of(path: &Path) -> Result<FileFormat> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase());
    match ext.as_deref() {
        Some("csv") | Some("txt") => Ok(FileFormat::Csv),
        Some("trc") => Ok(FileFormat::Trc),
        Some("json") => Ok(FileFormat::Json),
        _ => Err(Error::parse(
            path,
            "file name",
            "unknown extension: expected .csv, .trc or .json",
        )),
    }
}

/// Read one landmark set (one palpation). A CSV with `operator,repetition`
/// columns holding more than one palpation is refused here: use
/// [`read_palpations`].
pub fn read_path(path: &Path) -> Result<RawLandmarks> {
    let mut all = read_palpations(path)?;
    if all.len() != 1 {
        return Err(Error::parse(
            path,
            "file",
            format!(
                "holds {} palpations (operator,repetition columns); expected one landmark set",
                all.len()
            ),
        ));
    }
    Ok(all.remove(0).raw)
}

/// Read a file holding one or more palpations. Files without operator and
/// repetition information give operator `"1"`, repetition `1`.
pub fn read_palpations(path: &Path) -> Result<Vec<Palpation>> {
    let fmt = format_of(path)?;
    let text = crate::util::read_text_capped(path, MAX_FILE_BYTES, "landmark files")?;
    match fmt {
        FileFormat::Csv => parse_csv(&text, path),
        FileFormat::Trc => Ok(vec![Palpation {
            operator: "1".into(),
            repetition: 1,
            raw: parse_trc(&text, path)?,
        }]),
        FileFormat::Json => parse_json(&text, path),
    }
}

/// Load and validate a landmark set (see [`RawLandmarks::to_set`]).
pub fn load(path: &Path) -> Result<LandmarkSet> {
    read_path(path)?.to_set()
}

pub(crate) fn parse_number(s: &str, path: &Path, line: usize, col: &str) -> Result<f64> {
    let t = unquote(s);
    let v: f64 = t.parse().map_err(|_| {
        Error::parse(
            path,
            format!("line {line}"),
            format!("column `{col}`: expected a number, found `{t}`"),
        )
    })?;
    if !v.is_finite() {
        return Err(Error::parse(
            path,
            format!("line {line}"),
            format!("column `{col}`: expected a finite number, found `{t}`"),
        ));
    }
    Ok(v)
}

/// The `#` header lines of a landmark CSV seen so far.
#[derive(Default)]
struct CsvHeader {
    units: Option<Units>,
    frame: Option<Frame>,
    operator: Option<String>,
    repetition: Option<u32>,
}

impl CsvHeader {
    /// Take one `# key: value` line (other comments are ignored).
    fn read(&mut self, line: &str, line_no: usize, path: &Path) -> Result<()> {
        let err = |msg: String| Error::parse(path, format!("line {line_no}"), msg);
        if let Some(v) = comment_value(line, "units") {
            self.units = Some(
                Units::parse_label(v)
                    .ok_or_else(|| err(format!("`# units: {v}`: expected `mm` or `m`")))?,
            );
        } else if let Some(v) = comment_value(line, "frame") {
            self.frame = Some(Frame::parse_label(v).ok_or_else(|| {
                err(format!(
                    "`# frame: {v}`: expected `LPS`, `RAS` or `opensim`"
                ))
            })?);
        } else if let Some(v) = comment_value(line, "operator") {
            self.operator = Some(v.to_string());
        } else if let Some(v) = comment_value(line, "repetition") {
            self.repetition =
                Some(v.parse().map_err(|_| {
                    err(format!("`# repetition: {v}`: expected a positive integer"))
                })?);
        }
        Ok(())
    }
}

/// The CSV columns: operator/repetition columns, a `body` column, and the
/// number of fields.
#[derive(Debug, Clone, Copy)]
struct CsvColumns {
    with_op: bool,
    with_body: bool,
    n: usize,
}

/// The column header.
fn csv_columns(fields: &[&str], line: &str, line_no: usize, path: &Path) -> Result<CsvColumns> {
    let lower: Vec<String> = fields.iter().map(|f| f.to_ascii_lowercase()).collect();
    let lower: Vec<&str> = lower.iter().map(String::as_str).collect();
    let cols = |with_op, with_body, n| {
        Ok(CsvColumns {
            with_op,
            with_body,
            n,
        })
    };
    match lower.as_slice() {
        ["name", "x", "y", "z"] => cols(false, false, 4),
        ["operator", "repetition", "name", "x", "y", "z"] => cols(true, false, 6),
        ["name", "body", "x", "y", "z"] => cols(false, true, 5),
        _ => Err(Error::parse(
            path,
            format!("line {line_no}"),
            format!(
                "expected the header `name,x,y,z`, `operator,repetition,name,x,y,z` or `name,body,x,y,z` (coordinates in that body's frame), found `{line}`"
            ),
        )),
    }
}

/// One landmark row: its palpation (operator, repetition) and the point.
fn csv_row(
    fields: &[&str],
    cols: CsvColumns,
    header: &CsvHeader,
    line_no: usize,
    path: &Path,
) -> Result<((String, u32), RawPoint)> {
    let err = |msg: String| Error::parse(path, format!("line {line_no}"), msg);
    let (key, rest) = if cols.with_op {
        let rep: u32 = fields[1].parse().map_err(|_| {
            err(format!(
                "column `repetition`: expected a positive integer, found `{}`",
                fields[1]
            ))
        })?;
        if fields[0].is_empty() {
            return Err(err("column `operator`: empty".into()));
        }
        ((fields[0].to_string(), rep), &fields[2..])
    } else {
        let operator = header.operator.clone().unwrap_or_else(|| "1".into());
        ((operator, header.repetition.unwrap_or(1)), fields)
    };
    let name = rest[0].to_string();
    if name.is_empty() {
        return Err(err("column `name`: empty landmark name".into()));
    }
    let (body, rest) = if cols.with_body {
        if rest[1].is_empty() {
            return Err(err("column `body`: empty body name".into()));
        }
        (Some(rest[1].to_string()), &rest[1..])
    } else {
        (None, rest)
    };
    let x = parse_number(rest[1], path, line_no, "x")?;
    let y = parse_number(rest[2], path, line_no, "y")?;
    let z = parse_number(rest[3], path, line_no, "z")?;
    let parsed = LandmarkId::parse_name(&name);
    let point = RawPoint {
        id: parsed.map(|p| p.0),
        canonical: parsed.map(|p| p.1).unwrap_or(false),
        name,
        xyz: [x, y, z],
        line: Some(line_no),
        body,
    };
    Ok((key, point))
}

/// Parse a landmark CSV (see the module docs).
pub fn parse_csv(text: &str, path: &Path) -> Result<Vec<Palpation>> {
    let mut header = CsvHeader::default();
    let mut columns: Option<CsvColumns> = None;
    // Palpations in order of first appearance.
    let mut groups: Vec<((String, u32), Vec<RawPoint>)> = Vec::new();
    for item in CsvReader::new(text, path) {
        let Some(rec) = item?.record_or(|c| header.read(&c.text, c.line as usize, path))? else {
            continue;
        };
        let line_no = rec.line() as usize;
        // Trailing empty cells (spreadsheet exports write `a,b,c,`) are not fields.
        let fields = rec.cells_trimmed(columns.map(|c| c.n).unwrap_or(1));
        let Some(cols) = columns else {
            columns = Some(csv_columns(&fields, rec.source(), line_no, path)?);
            continue;
        };
        if fields.len() != cols.n {
            return Err(rec.error(
                path,
                format!(
                    "expected {} comma-separated fields, found {}",
                    cols.n,
                    fields.len()
                ),
            ));
        }
        let (key, point) = csv_row(&fields, cols, &header, line_no, path)?;
        match groups.iter_mut().find(|(k, _)| *k == key) {
            Some((_, v)) => v.push(point),
            None => groups.push((key, vec![point])),
        }
    }
    if columns.is_none() {
        return Err(Error::parse(
            path,
            "file",
            "empty: expected a header line `name,x,y,z` and one landmark per row",
        ));
    }
    if groups.is_empty() {
        return Err(Error::parse(
            path,
            "file",
            "no landmark rows after the header",
        ));
    }
    Ok(groups
        .into_iter()
        .map(|((operator, repetition), points)| Palpation {
            operator,
            repetition,
            raw: RawLandmarks {
                path: path.to_path_buf(),
                format: FileFormat::Csv,
                declared_units: header.units,
                declared_frame: header.frame,
                points,
                notes: Vec::new(),
            },
        })
        .collect())
}

/// Largest `NumMarkers` / `NumFrames` a TRC header may claim.
pub const MAX_TRC_COUNT: u64 = 1_000_000;

/// The header counts (`NumMarkers`, `NumFrames`, `OrigNumFrames`), when
/// present, must be whole numbers no larger than [`MAX_TRC_COUNT`].
fn check_trc_counts(keys: &[String], vals: &[String], path: &Path) -> Result<()> {
    for (k, v) in keys.iter().zip(vals) {
        if !matches!(k.as_str(), "NumMarkers" | "NumFrames" | "OrigNumFrames") {
            continue;
        }
        match v.parse::<u64>() {
            Ok(n) if n <= MAX_TRC_COUNT => {}
            _ => {
                return Err(Error::parse(
                    path,
                    "line 3",
                    format!("TRC {k} `{v}`: expected a whole number up to {MAX_TRC_COUNT}"),
                ))
            }
        }
    }
    Ok(())
}

/// Parse an OpenSim TRC marker file (see the module docs).
pub fn parse_trc(text: &str, path: &Path) -> Result<RawLandmarks> {
    let lines: Vec<&str> = strip_bom(text).lines().collect();
    let at = |i: usize| -> Result<&str> {
        lines.get(i).copied().ok_or_else(|| {
            Error::parse(
                path,
                format!("line {}", i + 1),
                "TRC header ends early: expected 5 header lines (PathFileType, keys, values, marker names, X1 Y1 Z1...)",
            )
        })
    };
    if !at(0)?.trim_start().starts_with("PathFileType") {
        return Err(Error::parse(path, "line 1", "TRC: expected `PathFileType`"));
    }
    let (keys, vals) = (trc_cells(at(1)?), trc_cells(at(2)?));
    check_trc_counts(&keys, &vals, path)?;
    let units = trc_units(&keys, &vals, path)?;
    let (markers, ignored) = trc_markers(at(3)?, path)?;
    let (stats, n_frames) = trc_frames(&lines, &markers, path)?;
    let scale_mm = units.to_metres() * 1e3;
    let (points, max_spread) = trc_points(&markers, &stats, n_frames, scale_mm, path)?;
    let mut notes = Vec::new();
    if !ignored.is_empty() {
        notes.push(format!(
            "TRC: {} marker(s) without a <LEVEL>_ prefix ignored: {}",
            ignored.len(),
            ignored.join(", ")
        ));
    }
    if n_frames > 1 {
        notes.push(format!(
            "TRC: {n_frames} frames averaged per marker (largest spread {max_spread:.2} mm)"
        ));
    }
    Ok(RawLandmarks {
        path: path.to_path_buf(),
        format: FileFormat::Trc,
        declared_units: Some(units),
        declared_frame: None,
        points,
        notes,
    })
}

/// Header keys and values are tab-separated; a header written with spaces
/// only (no tab on the line) is split on whitespace.
fn trc_cells(l: &str) -> Vec<String> {
    if l.contains('\t') {
        l.split('\t').map(|c| c.trim().to_string()).collect()
    } else {
        l.split_whitespace().map(str::to_string).collect()
    }
}

/// The header's `Units` (required: mm or m).
fn trc_units(keys: &[String], vals: &[String], path: &Path) -> Result<Units> {
    let units_idx = keys.iter().position(|k| k.eq_ignore_ascii_case("Units"));
    match units_idx.and_then(|k| vals.get(k)) {
        Some(u) => Units::parse_label(u).ok_or_else(|| {
            Error::parse(
                path,
                "line 3",
                format!("TRC Units `{u}`: expected `mm` or `m`"),
            )
        }),
        None => Err(Error::parse(
            path,
            "line 2",
            "TRC: no `Units` column in the header",
        )),
    }
}

/// The landmark markers of the names line, each with its first data
/// column, and the other markers' names (ignored).
#[allow(clippy::type_complexity)]
fn trc_markers(names_line: &str, path: &Path) -> Result<(Vec<(usize, String)>, Vec<String>)> {
    let cols: Vec<&str> = names_line.split('\t').collect();
    if cols.len() < 3 || !cols[0].trim().eq_ignore_ascii_case("Frame#") {
        return Err(Error::parse(
            path,
            "line 4",
            "TRC: expected `Frame#<TAB>Time<TAB>marker names`",
        ));
    }
    // As OpenSim reads it: the i-th non-empty name after `Frame#` and `Time`
    // owns data columns 2 + 3i .. 2 + 3i + 2, whether the names are padded
    // with two empty cells (as OpenSim writes them) or not.
    let mut markers: Vec<(usize, String)> = Vec::new(); // (first column, name)
    let mut ignored: Vec<String> = Vec::new();
    for s in cols.iter().skip(2) {
        let s = s.trim();
        if s.is_empty() {
            continue;
        }
        let column = 2 + 3 * (markers.len() + ignored.len());
        // A marker file may carry other markers (skin markers, model
        // markers): names without a vertebral level prefix are not
        // landmarks and are skipped; `L3_SECC` (a level, a bad code) stays
        // and is reported as an unknown landmark name.
        let has_level = s
            .split_once('_')
            .is_some_and(|(l, _)| l.parse::<super::Level>().is_ok());
        if has_level {
            markers.push((column, s.to_string()));
        } else {
            ignored.push(s.to_string());
        }
    }
    if markers.is_empty() {
        return Err(Error::parse(
            path,
            "line 4",
            "TRC: no landmark markers (names <LEVEL>_<CODE>)",
        ));
    }
    Ok((markers, ignored))
}

/// One marker over the frames: sum, extent, count and first line.
#[derive(Clone)]
struct TrcStats {
    sum: [f64; 3],
    min: [f64; 3],
    max: [f64; 3],
    count: usize,
    first_line: Option<usize>,
}

/// Read the data frames (line 6 on): per marker, the frames where it is
/// present (empty or NaN cells: occluded), and the number of frames.
fn trc_frames(
    lines: &[&str],
    markers: &[(usize, String)],
    path: &Path,
) -> Result<(Vec<TrcStats>, usize)> {
    let empty = TrcStats {
        sum: [0.0; 3],
        min: [f64::INFINITY; 3],
        max: [f64::NEG_INFINITY; 3],
        count: 0,
        first_line: None,
    };
    let mut stats = vec![empty; markers.len()];
    let mut n_frames = 0usize;
    for (i, l) in lines.iter().enumerate().skip(5) {
        let line_no = i + 1;
        if l.trim().is_empty() {
            continue;
        }
        n_frames += 1;
        let f: Vec<&str> = l.split('\t').collect();
        for (st, (c, name)) in stats.iter_mut().zip(markers) {
            let cell = |k: usize| f.get(c + k).map(|s| s.trim()).unwrap_or("");
            let (sx, sy, sz) = (cell(0), cell(1), cell(2));
            if sx.is_empty() && sy.is_empty() && sz.is_empty() {
                continue; // marker missing in this frame
            }
            let mut v = [0.0; 3];
            for (k, s) in [sx, sy, sz].iter().enumerate() {
                let col = format!("{name} {}", ["X", "Y", "Z"][k]);
                let x = parse_number(s, path, line_no, &col);
                // OpenSim writes NaN for occluded markers: treat as missing.
                if s.eq_ignore_ascii_case("nan") {
                    v = [f64::NAN; 3];
                    break;
                }
                v[k] = x?;
            }
            if v[0].is_nan() {
                continue;
            }
            st.count += 1;
            st.first_line.get_or_insert(line_no);
            for k in 0..3 {
                st.sum[k] += v[k];
                st.min[k] = st.min[k].min(v[k]);
                st.max[k] = st.max[k].max(v[k]);
            }
        }
    }
    if n_frames == 0 {
        return Err(Error::parse(path, "line 6", "TRC: no data frames"));
    }
    Ok((stats, n_frames))
}

/// Each present marker's mean over the frames; a marker moving more than
/// 5 mm is refused (a landmark set is static). Also the largest spread (mm).
fn trc_points(
    markers: &[(usize, String)],
    stats: &[TrcStats],
    n_frames: usize,
    scale_mm: f64,
    path: &Path,
) -> Result<(Vec<RawPoint>, f64)> {
    let mut points = Vec::new();
    let mut max_spread = 0.0f64;
    for ((_, name), st) in markers.iter().zip(stats) {
        if st.count == 0 {
            continue;
        }
        let spread = (0..3).map(|k| st.max[k] - st.min[k]).fold(0.0, f64::max) * scale_mm;
        max_spread = max_spread.max(spread);
        if spread > 5.0 {
            return Err(Error::parse(
                path,
                format!("marker `{name}`"),
                format!(
                    "moves by {spread:.1} mm across the {n_frames} frames; a landmark set must be static (extract one frame)"
                ),
            ));
        }
        let n = st.count as f64;
        let parsed = LandmarkId::parse_name(name);
        points.push(RawPoint {
            name: name.clone(),
            id: parsed.map(|p| p.0),
            canonical: parsed.map(|p| p.1).unwrap_or(false),
            xyz: [st.sum[0] / n, st.sum[1] / n, st.sum[2] / n],
            line: st.first_line,
            body: None,
        });
    }
    Ok((points, max_spread))
}

/// Ordered JSON object entries, duplicates kept.
struct Entries(Vec<(String, serde_json::Value)>);

impl<'de> serde::Deserialize<'de> for Entries {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        struct V;
        impl<'de> serde::de::Visitor<'de> for V {
            type Value = Entries;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("an object {name: [x, y, z], ...}")
            }
            fn visit_map<A: serde::de::MapAccess<'de>>(
                self,
                mut map: A,
            ) -> std::result::Result<Entries, A::Error> {
                let mut v = Vec::new();
                while let Some((k, val)) = map.next_entry::<String, serde_json::Value>()? {
                    v.push((k, val));
                }
                Ok(Entries(v))
            }
        }
        d.deserialize_map(V)
    }
}

#[derive(serde::Deserialize)]
struct JsonFile {
    units: Option<String>,
    frame: Option<String>,
    operator: Option<String>,
    repetition: Option<u32>,
    landmarks: Entries,
    /// Other top-level keys (metadata such as a subject id): ignored, named
    /// in the notes.
    #[serde(flatten)]
    other: std::collections::BTreeMap<String, serde_json::Value>,
}

fn line_of(text: &str, needle: &str) -> Option<usize> {
    let pos = text.find(&format!("\"{needle}\""))?;
    Some(text[..pos].matches('\n').count() + 1)
}

/// Parse a JSON landmark file.
pub fn parse_json(text: &str, path: &Path) -> Result<Vec<Palpation>> {
    let text = strip_bom(text);
    if text.trim().is_empty() {
        return Err(Error::parse(
            path,
            "file",
            "empty: expected {\"units\", \"frame\", \"landmarks\": {name: [x, y, z]}}",
        ));
    }
    let f: JsonFile = serde_json::from_str(text).map_err(|e| {
        Error::parse(
            path,
            format!("line {} column {}", e.line(), e.column()),
            e.to_string(),
        )
    })?;
    let units =
        match &f.units {
            Some(u) => Some(Units::parse_label(u).ok_or_else(|| {
                Error::parse(path, "units", format!("`{u}`: expected `mm` or `m`"))
            })?),
            None => None,
        };
    let frame = match &f.frame {
        Some(u) => Some(Frame::parse_label(u).ok_or_else(|| {
            Error::parse(
                path,
                "frame",
                format!("`{u}`: expected `LPS`, `RAS` or `opensim`"),
            )
        })?),
        None => None,
    };
    let mut points = Vec::new();
    for (name, val) in f.landmarks.0 {
        let arr = val.as_array().filter(|a| a.len() == 3).ok_or_else(|| {
            Error::parse(
                path,
                format!("landmarks.{name}"),
                format!("expected [x, y, z], found {val}"),
            )
        })?;
        let mut xyz = [0.0; 3];
        for (k, v) in arr.iter().enumerate() {
            xyz[k] = v.as_f64().filter(|x| x.is_finite()).ok_or_else(|| {
                Error::parse(
                    path,
                    format!("landmarks.{name}"),
                    format!("coordinate {k}: expected a finite number, found {v}"),
                )
            })?;
        }
        let parsed = LandmarkId::parse_name(&name);
        points.push(RawPoint {
            line: line_of(text, &name),
            id: parsed.map(|p| p.0),
            canonical: parsed.map(|p| p.1).unwrap_or(false),
            name,
            xyz,
            body: None,
        });
    }
    if points.is_empty() {
        return Err(Error::parse(path, "landmarks", "no landmarks"));
    }
    let mut notes = Vec::new();
    if !f.other.is_empty() {
        let keys: Vec<&str> = f.other.keys().map(String::as_str).collect();
        notes.push(format!("JSON: ignored top-level keys {}", keys.join(", ")));
    }
    Ok(vec![Palpation {
        operator: f.operator.unwrap_or_else(|| "1".into()),
        repetition: f.repetition.unwrap_or(1),
        raw: RawLandmarks {
            path: path.to_path_buf(),
            format: FileFormat::Json,
            declared_units: units,
            declared_frame: frame,
            points,
            notes,
        },
    }])
}

/// Render a set as CSV text in the given units and frame (the project's own
/// fixtures). Rows in id order; numbers in shortest round-trip form.
pub fn csv_string(set: &LandmarkSet, units: Units, frame: Frame) -> String {
    let back = frame.to_opensim().transpose();
    let s = 1.0 / units.to_metres();
    let mut out = format!("# units: {units}\n# frame: {frame}\nname,x,y,z\n");
    for (id, p) in &set.points {
        let v = back * p.coords * s;
        out.push_str(&format!(
            "{id},{},{},{}\n",
            fmt_f64(v.x),
            fmt_f64(v.y),
            fmt_f64(v.z)
        ));
    }
    out
}

/// Write a set as CSV (atomically).
pub fn write_csv(set: &LandmarkSet, path: &Path, units: Units, frame: Frame) -> Result<()> {
    write_atomic(path, csv_string(set, units, frame).as_bytes())
}
