//! Coronal radiograph landmarks (`../shared/formats/radiograph.md`): the
//! 2-D endplate points of a frontal film (standing, supine, side-bending),
//! the sacrum and the femoral heads, read into a [`Radiograph`] and written
//! back (`osim-spine flexibility`'s predicted films).
//!
//! Reading (everything checked, errors name the file and line):
//! - `# units:` `mm` or `m`; when absent, detected from the film's extent
//!   (a spine film spans 50 mm-5 m in mm, 0.05-5 in m; anything between is
//!   refused as ambiguous) and said in [`Radiograph::notes`];
//! - `# projection:` required: `orthographic`, or `perspective
//!   source_to_image_mm=D source_to_patient_mm=d` (D > d > 0);
//! - `# axes:` `u towards the patient's left` (or `right`: mirrored on
//!   reading), `v cranial` (or `caudal`: flipped); absent: the format's
//!   axes, noted;
//! - rows `name,u,v` after the header `name,u,v`: vertebral landmarks
//!   `<LEVEL>_<CODE>` (T1..L5, any code of `landmarks.md`), the sacrum's
//!   (`S1_SR`, `S1_SL`, `S1_SEC`, ...) and the femoral heads `FH_R`,
//!   `FH_L`; an unknown name or a duplicate is an error;
//! - at most [`MAX_FILM_BYTES`] bytes and [`MAX_FILM_POINTS`] points.
//!
//! Coordinates are kept as on the film, in metres, in the format's axes;
//! dividing by the [`Projection::magnification`] brings them to the
//! patient's scale.

use super::io::parse_number;
use super::{Code, LandmarkId, Level, Units};
use crate::error::{Error, Result};
use crate::util::table::{comment_value, CsvReader};
use nalgebra::Vector2;
use std::collections::BTreeMap;
use std::fmt;
use std::path::{Path, PathBuf};

/// Largest film file accepted (a full film is ~4 kB).
pub const MAX_FILM_BYTES: u64 = 1024 * 1024;
/// Most points a film may hold (17 vertebrae x 14 codes, sacrum, hips).
pub const MAX_FILM_POINTS: usize = 17 * 14 + 7 + 2;

/// Side of a paired structure.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Side {
    /// The patient's right.
    Right,
    /// The patient's left.
    Left,
}

/// A point a frontal film shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum FilmPoint {
    /// A vertebral or sacral landmark (`T7_SR`, `S1_SEC`).
    Landmark(LandmarkId),
    /// A femoral head centre (`FH_R`, `FH_L`).
    FemoralHead(Side),
}

impl FilmPoint {
    /// Parse a film name (exact spelling, upper case).
    pub fn parse(name: &str) -> Option<FilmPoint> {
        match name {
            "FH_R" => return Some(FilmPoint::FemoralHead(Side::Right)),
            "FH_L" => return Some(FilmPoint::FemoralHead(Side::Left)),
            _ => {}
        }
        let (id, canonical) = LandmarkId::parse_name(name)?;
        (canonical && id.level.allowed(id.code)).then_some(FilmPoint::Landmark(id))
    }

    /// On the pelvis (the sacrum or a femoral head): what places a film.
    pub fn is_pelvic(self) -> bool {
        match self {
            FilmPoint::Landmark(id) => id.level.is_sacrum(),
            FilmPoint::FemoralHead(_) => true,
        }
    }

    /// The vertebra (T1..L5) the point is on, if any.
    pub fn vertebra(self) -> Option<Level> {
        match self {
            FilmPoint::Landmark(id) if !id.level.is_sacrum() => Some(id.level),
            _ => None,
        }
    }

    /// The pelvic points a film is placed on, in order.
    pub const PELVIC: [FilmPoint; 5] = [
        FilmPoint::Landmark(LandmarkId {
            level: Level::S1,
            code: Code::SR,
        }),
        FilmPoint::Landmark(LandmarkId {
            level: Level::S1,
            code: Code::SL,
        }),
        FilmPoint::Landmark(LandmarkId {
            level: Level::S1,
            code: Code::SEC,
        }),
        FilmPoint::FemoralHead(Side::Right),
        FilmPoint::FemoralHead(Side::Left),
    ];
}

impl fmt::Display for FilmPoint {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            FilmPoint::Landmark(id) => write!(f, "{id}"),
            FilmPoint::FemoralHead(Side::Right) => f.write_str("FH_R"),
            FilmPoint::FemoralHead(Side::Left) => f.write_str("FH_L"),
        }
    }
}

/// How the film was projected.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Projection {
    /// EOS-like: the image is the patient's frontal plane at scale 1.
    Orthographic,
    /// A point source: distances in metres.
    Perspective {
        /// Distance from the source to the image plane (m).
        source_to_image: f64,
        /// Distance from the source to the patient's frontal plane (m).
        source_to_patient: f64,
    },
}

impl Projection {
    /// Image size over patient size at the patient's plane (1 for orthographic).
    pub fn magnification(self) -> f64 {
        match self {
            Projection::Orthographic => 1.0,
            Projection::Perspective {
                source_to_image,
                source_to_patient,
            } => source_to_image / source_to_patient,
        }
    }

    /// The header line's value (`orthographic`, `perspective ...`).
    pub fn header(self) -> String {
        match self {
            Projection::Orthographic => "orthographic".into(),
            Projection::Perspective {
                source_to_image,
                source_to_patient,
            } => format!(
                "perspective source_to_image_mm={} source_to_patient_mm={}",
                crate::util::fmt_f64(source_to_image * 1e3),
                crate::util::fmt_f64(source_to_patient * 1e3)
            ),
        }
    }
}

/// A film's landmarks.
#[derive(Debug, Clone, PartialEq)]
pub struct Radiograph {
    /// The file read or to be written.
    pub path: PathBuf,
    /// The `# film:` text, if any.
    pub film: Option<String>,
    /// How the film was projected.
    pub projection: Projection,
    /// Units of the file (declared or detected).
    pub units: Units,
    /// Points on the film (m, the format's axes: `u` towards the patient's
    /// left, `v` cranial), with their 1-based line.
    pub points: BTreeMap<FilmPoint, (Vector2<f64>, usize)>,
    /// What the reader decided (detected units, default axes, mirrored axes).
    pub notes: Vec<String>,
}

impl Radiograph {
    /// The point `p` on the film (m), if given.
    pub fn get(&self, p: FilmPoint) -> Option<Vector2<f64>> {
        self.points.get(&p).map(|x| x.0)
    }

    /// Vertebrae with at least one point, cranial to caudal.
    pub fn vertebrae(&self) -> Vec<Level> {
        let mut v: Vec<Level> = self.points.keys().filter_map(|p| p.vertebra()).collect();
        v.dedup();
        v
    }

    /// The file stem (`film_left` for `film_left.csv`).
    pub fn stem(&self) -> String {
        self.path
            .file_stem()
            .map(|s| s.to_string_lossy().to_string())
            .unwrap_or_else(|| "film".into())
    }
}

/// Read a film (see the module docs).
pub fn read(path: &Path) -> Result<Radiograph> {
    let text = crate::util::read_text_capped(path, MAX_FILM_BYTES, "radiograph files")?;
    parse(&text, path)
}

/// The `#` header of a film.
#[derive(Default)]
struct Header {
    units: Option<Units>,
    projection: Option<Projection>,
    /// Signs applied to (u, v) to reach the format's axes; None: not stated.
    axes: Option<(f64, f64)>,
    film: Option<String>,
}

impl Header {
    fn read(&mut self, line: &str, line_no: usize, path: &Path) -> Result<()> {
        let err = |msg: String| Error::parse(path, format!("line {line_no}"), msg);
        if let Some(v) = comment_value(line, "units") {
            self.units = Some(
                Units::parse_label(v)
                    .ok_or_else(|| err(format!("`# units: {v}`: expected `mm` or `m`")))?,
            );
        } else if let Some(v) = comment_value(line, "projection") {
            self.projection = Some(parse_projection(v, &err)?);
        } else if let Some(v) = comment_value(line, "axes") {
            self.axes = Some(parse_axes(v, &err)?);
        } else if let Some(v) = comment_value(line, "film") {
            self.film = Some(v.to_string());
        }
        Ok(())
    }
}

fn parse_projection(v: &str, err: &dyn Fn(String) -> Error) -> Result<Projection> {
    let mut words = v.split_whitespace();
    let expected = "expected `orthographic` or `perspective source_to_image_mm=D source_to_patient_mm=d` (D > d > 0)";
    match words.next().map(str::to_ascii_lowercase).as_deref() {
        Some("orthographic") if words.next().is_none() => Ok(Projection::Orthographic),
        Some("perspective") => {
            let (mut sid, mut sod) = (None, None);
            for w in words {
                let (k, x) = w.split_once('=').ok_or_else(|| {
                    err(format!(
                        "`# projection: {v}`: `{w}` is not key=value; {expected}"
                    ))
                })?;
                let x: f64 = x
                    .parse()
                    .ok()
                    .filter(|x: &f64| x.is_finite() && *x > 0.0)
                    .ok_or_else(|| {
                        err(format!(
                            "`# projection: {v}`: `{w}` needs a positive number of mm"
                        ))
                    })?;
                match k {
                    "source_to_image_mm" => sid = Some(x * 1e-3),
                    "source_to_patient_mm" => sod = Some(x * 1e-3),
                    _ => {
                        return Err(err(format!(
                            "`# projection: {v}`: unknown key `{k}`; {expected}"
                        )))
                    }
                }
            }
            match (sid, sod) {
                (Some(a), Some(b)) if a > b => Ok(Projection::Perspective {
                    source_to_image: a,
                    source_to_patient: b,
                }),
                _ => Err(err(format!("`# projection: {v}`: {expected}"))),
            }
        }
        _ => Err(err(format!("`# projection: {v}`: {expected}"))),
    }
}

/// Signs that bring the stated axes to the format's (`u` left, `v` cranial).
fn parse_axes(v: &str, err: &dyn Fn(String) -> Error) -> Result<(f64, f64)> {
    let (mut su, mut sv) = (1.0, 1.0);
    for part in v.split(',') {
        let p = part.trim().to_ascii_lowercase();
        let sign = |pos: &str, neg: &str| {
            if p.contains(pos) {
                Ok(1.0)
            } else if p.contains(neg) {
                Ok(-1.0)
            } else {
                Err(err(format!(
                    "`# axes: {v}`: `{}` must say `{pos}` or `{neg}` (expected `u towards the patient's left, v cranial`)",
                    part.trim()
                )))
            }
        };
        if p.starts_with('u') {
            su = sign("left", "right")?;
        } else if p.starts_with('v') {
            sv = sign("cranial", "caudal")?;
        } else {
            return Err(err(format!(
                "`# axes: {v}`: expected `u towards the patient's left, v cranial`"
            )));
        }
    }
    Ok((su, sv))
}

/// Parse a film's text (see the module docs).
pub fn parse(text: &str, path: &Path) -> Result<Radiograph> {
    let mut header = Header::default();
    let mut seen_columns = false;
    let mut raw: BTreeMap<FilmPoint, (Vector2<f64>, usize)> = BTreeMap::new();
    for item in CsvReader::new(text, path) {
        let Some(rec) = item?.record_or(|c| header.read(&c.text, c.line as usize, path))? else {
            continue;
        };
        let line_no = rec.line() as usize;
        let err = |msg: String| rec.error(path, msg);
        let fields = rec.cells_trimmed(3);
        if !seen_columns {
            let lower: Vec<String> = fields.iter().map(|f| f.to_ascii_lowercase()).collect();
            if lower != ["name", "u", "v"] {
                return Err(err(format!(
                    "expected the header `name,u,v`, found `{}`",
                    rec.source()
                )));
            }
            seen_columns = true;
            continue;
        }
        if fields.len() != 3 {
            return Err(err(format!(
                "expected 3 comma-separated fields `name,u,v`, found {}",
                fields.len()
            )));
        }
        let point = FilmPoint::parse(fields[0]).ok_or_else(|| {
            err(format!(
                "`{}` is not a film landmark: expected `<LEVEL>_<CODE>` (T1..L5 with a code of landmarks.md, e.g. `T7_SR`), `S1_SR`/`S1_SL`/`S1_SEC` or `FH_R`/`FH_L`",
                fields[0]
            ))
        })?;
        let u = parse_number(fields[1], path, line_no, "u")?;
        let v = parse_number(fields[2], path, line_no, "v")?;
        if let Some((_, first)) = raw.get(&point) {
            return Err(err(format!(
                "`{point}` is given twice (first on line {first})"
            )));
        }
        if raw.len() >= MAX_FILM_POINTS {
            return Err(err(format!(
                "more than {MAX_FILM_POINTS} points: not a film of one spine"
            )));
        }
        raw.insert(point, (Vector2::new(u, v), line_no));
    }
    if !seen_columns {
        return Err(Error::parse(
            path,
            "file",
            "empty: expected `# units:`, `# projection:` lines, the header `name,u,v` and one landmark per row",
        ));
    }
    if raw.is_empty() {
        return Err(Error::parse(
            path,
            "file",
            "no landmark rows after the header",
        ));
    }
    finish(header, raw, path)
}

/// Units (declared or detected), projection and axes applied.
fn finish(
    header: Header,
    mut points: BTreeMap<FilmPoint, (Vector2<f64>, usize)>,
    path: &Path,
) -> Result<Radiograph> {
    let mut notes = Vec::new();
    let projection = header.projection.ok_or_else(|| {
        Error::parse(
            path,
            "header",
            "no `# projection:` line: expected `# projection: orthographic` or `# projection: perspective source_to_image_mm=D source_to_patient_mm=d`",
        )
    })?;
    let units = match header.units {
        Some(u) => u,
        None => {
            let u = detect_units(&points, path)?;
            notes.push(format!(
                "no `# units:` line: {} detected from the film's extent",
                match u {
                    Units::Millimetre => "mm",
                    Units::Metre => "m",
                }
            ));
            u
        }
    };
    let scale = match units {
        Units::Millimetre => 1e-3,
        Units::Metre => 1.0,
    };
    let (su, sv) = match header.axes {
        Some(s) => s,
        None => {
            notes.push(
                "no `# axes:` line: u towards the patient's left, v cranial (the format's axes)"
                    .into(),
            );
            (1.0, 1.0)
        }
    };
    if su < 0.0 {
        notes.push("`u` towards the patient's right: mirrored on reading".into());
    }
    if sv < 0.0 {
        notes.push("`v` caudal: flipped on reading".into());
    }
    for (p, _) in points.values_mut() {
        *p = Vector2::new(su * p.x, sv * p.y) * scale;
    }
    Ok(Radiograph {
        path: path.to_path_buf(),
        film: header.film,
        projection,
        units,
        points,
        notes,
    })
}

/// Units from the film's largest extent: a spine film spans 50 mm to 5 m
/// in mm, 0.05 to 5 in m.
fn detect_units(points: &BTreeMap<FilmPoint, (Vector2<f64>, usize)>, path: &Path) -> Result<Units> {
    let pts: Vec<Vector2<f64>> = points.values().map(|p| p.0).collect();
    let mut span: f64 = 0.0;
    for (i, a) in pts.iter().enumerate() {
        for b in &pts[i + 1..] {
            span = span.max((a - b).norm());
        }
    }
    if (50.0..=5000.0).contains(&span) {
        Ok(Units::Millimetre)
    } else if (0.05..=5.0).contains(&span) {
        Ok(Units::Metre)
    } else {
        Err(Error::parse(
            path,
            "header",
            format!("no `# units:` line and the film's extent ({span}) fits neither mm nor m: add `# units: mm` or `# units: m`"),
        ))
    }
}

/// A film as text in the format (mm, the format's axes), points in order.
/// `film` is the `# film:` text; `comments` are extra `#` lines.
pub fn write_csv(
    points: &BTreeMap<FilmPoint, Vector2<f64>>,
    projection: Projection,
    film: &str,
    comments: &[String],
) -> String {
    let mut s = String::from("# coronal radiograph landmarks (see radiograph.md)\n");
    s.push_str("# units: mm\n");
    s.push_str(&format!("# projection: {}\n", projection.header()));
    s.push_str("# axes: u towards the patient's left, v cranial\n");
    s.push_str(&format!("# film: {}\n", film.replace('\n', " ")));
    for c in comments {
        s.push_str(&format!("# {}\n", c.replace('\n', " ")));
    }
    s.push_str("name,u,v\n");
    for (p, x) in points {
        s.push_str(&format!("{p},{:.4},{:.4}\n", x.x * 1e3, x.y * 1e3));
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn p(text: &str) -> Result<Radiograph> {
        parse(text, Path::new("film.csv"))
    }

    #[test]
    fn reads_the_format_and_round_trips() {
        let t = "# units: mm\n# projection: orthographic\n# axes: u towards the patient's left, v cranial\n# film: left\nname,u,v\nT1_SR,10,20\nFH_L,100.5,-3\nS1_SEC,1,2\n";
        let r = p(t).unwrap();
        assert_eq!(r.points.len(), 3);
        assert_eq!(
            r.get(FilmPoint::FemoralHead(Side::Left)),
            Some(Vector2::new(0.1005, -0.003))
        );
        assert_eq!(r.vertebrae(), vec![Level::T1]);
        let pts = r.points.iter().map(|(k, v)| (*k, v.0)).collect();
        let back = p(&write_csv(&pts, r.projection, "left", &[])).unwrap();
        for (k, v) in &r.points {
            assert!((back.points[k].0 - v.0).norm() < 1e-9);
        }
    }

    #[test]
    fn mirrored_axes_and_metres() {
        let t = "# units: m\n# projection: perspective source_to_image_mm=1800 source_to_patient_mm=1600\n# axes: u towards the patient's right, v cranial\nname,u,v\nFH_R,0.1,0.2\n";
        let r = p(t).unwrap();
        assert_eq!(
            r.get(FilmPoint::FemoralHead(Side::Right)),
            Some(Vector2::new(-0.1, 0.2))
        );
        assert!((r.projection.magnification() - 1.125).abs() < 1e-12);
    }

    #[test]
    fn refuses_bad_films() {
        let head = "# units: mm\n# projection: orthographic\nname,u,v\n";
        for (body, needle) in [
            ("C7_SR,1,2\n", "not a film landmark"),
            ("T1_SR,1,2\nT1_SR,1,2\n", "given twice"),
            ("T1_SR,1,nan\n", "finite"),
            ("T1_SR,1\n", "3 comma-separated"),
            ("S1_IEC,1,2\n", "not a film landmark"),
        ] {
            let e = p(&format!("{head}{body}")).unwrap_err().to_string();
            assert!(e.contains(needle), "{body}: {e}");
        }
        let e = p("# units: mm\nname,u,v\nT1_SR,1,2\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("projection"), "{e}");
        let e = p("# projection: orthographic\nname,u,v\nT1_SR,1,2\nT1_SL,11,2\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("fits neither"), "{e}");
        let e = p("# units: mm\n# projection: perspective source_to_image_mm=1000 source_to_patient_mm=1600\nname,u,v\nT1_SR,1,2\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("D > d"), "{e}");
    }

    #[test]
    fn bom_crlf_quotes_and_the_line_of_a_bad_cell() {
        let t = "\u{feff}# units: mm\r\n# projection: orthographic\r\n\r\nname,u,v\r\n\"T1_SR\",\"10\",20\r\nFH_L,100,-3\r\n";
        let r = p(t).unwrap();
        let got = r.get(FilmPoint::parse("T1_SR").unwrap()).unwrap();
        assert!((got - Vector2::new(0.01, 0.02)).norm() < 1e-15, "{got}");
        // `"12,5"` is one cell (a decimal comma), refused on line 6
        let bad = t.replace("FH_L,100,", "FH_L,\"12,5\",");
        let e = p(&bad).unwrap_err().to_string();
        assert!(
            e.contains("film.csv: line 6: column `u`: expected a number, found `12,5`"),
            "{e}"
        );
    }
}
