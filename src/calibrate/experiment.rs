//! The experiment format (`../shared/formats/experiment.md`): load cases
//! (`[[case]]` tables, also used by `osim-spine simulate` as a load file) and
//! whole experiment folders ([`Experiment::read`]: `experiment.toml`,
//! `kinematics.csv` and the nominal model), converted to SI at the edge and
//! validated with messages that name the file and the case, row or element.

use crate::error::{Error, Result};
use crate::osim::Document;
use crate::solver::{Load, LoadFrame, System, SystemSpec};
use crate::util::table::{strip_bom, CsvReader, CsvRecord};
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// Axes a load vector is given in.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum FrameName {
    /// Fixed ground axes.
    Ground,
    /// The loaded body's axes (the load turns with the body).
    Body,
}

impl From<FrameName> for LoadFrame {
    fn from(f: FrameName) -> Self {
        match f {
            FrameName::Ground => LoadFrame::Ground,
            FrameName::Body => LoadFrame::Body,
        }
    }
}

/// Largest moment a load case may apply (N*m, norm).
pub const MAX_MOMENT: f64 = 1e4;

/// Largest force or follower load a load case may apply (N, norm).
pub const MAX_FORCE: f64 = 1e5;

/// One `[[case]]` table.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LoadCase {
    /// Unique id (key of kinematics.csv rows).
    pub id: String,
    /// Body that carries the load.
    pub body: String,
    /// Pure moment (N m).
    #[serde(default)]
    pub moment: [f64; 3],
    /// Axes of `moment`; required when the moment is not zero.
    #[serde(default)]
    pub moment_frame: Option<FrameName>,
    /// Force (N), default zero.
    #[serde(default)]
    pub force: [f64; 3],
    /// Point of application in the body frame (m).
    #[serde(default)]
    pub force_point: [f64; 3],
    /// Axes of `force` (default ground).
    #[serde(default)]
    pub force_frame: Option<FrameName>,
    /// Compressive follower load magnitude (N), default zero.
    #[serde(default)]
    pub follower_load: f64,
}

/// A file of `[[case]]` tables (other top-level tables are ignored, so an
/// `experiment.toml` can be read as a load file too).
#[derive(Debug, Clone, Deserialize)]
struct CaseFile {
    #[serde(default)]
    case: Vec<LoadCase>,
}

impl LoadCase {
    /// Check values; `file` and the case position name the error.
    pub fn validate(&self, file: &Path, index: usize) -> Result<()> {
        let at = format!("[[case]] #{} (id '{}')", index + 1, self.id);
        let err = |m: String| Error::parse(file, at.clone(), m);
        if self.id.trim().is_empty() {
            return Err(err("id must not be empty".into()));
        }
        if self.body.trim().is_empty() {
            return Err(err("body must name the loaded body".into()));
        }
        for (name, v) in [
            ("moment", &self.moment),
            ("force", &self.force),
            ("force_point", &self.force_point),
        ] {
            if v.iter().any(|x| !x.is_finite()) {
                return Err(err(format!("{name} must be three finite numbers")));
            }
        }
        self.check_magnitudes(&err)?;
        if self.moment.iter().any(|&x| x != 0.0) && self.moment_frame.is_none() {
            return Err(err("moment_frame is required with a non-zero moment: \"ground\" (fixed axes) or \"body\" (follows the body)".into()));
        }
        if !self.follower_load.is_finite() || self.follower_load < 0.0 {
            return Err(err(format!(
                "follower_load must be a finite magnitude >= 0 N (compressive), got {}",
                self.follower_load
            )));
        }
        Ok(())
    }

    /// Loads within what a spine (or a rig) can bear: a moment's norm at
    /// most [`MAX_MOMENT`], a force's and the follower load at most
    /// [`MAX_FORCE`]; beyond, the solver would only report a failure to
    /// converge under a wrong cause.
    fn check_magnitudes(&self, err: &impl Fn(String) -> Error) -> Result<()> {
        let norm = |v: &[f64; 3]| Vector3::from(*v).norm();
        for (name, size, max, unit) in [
            ("moment", norm(&self.moment), MAX_MOMENT, "N*m"),
            ("force", norm(&self.force), MAX_FORCE, "N"),
            ("follower_load", self.follower_load, MAX_FORCE, "N"),
        ] {
            if size > max {
                return Err(err(format!(
                    "{name} of magnitude {size:.4e} {unit} is beyond the limit of {max:.0e} {unit} (loads on a spine are below 1e2 N*m and 1e4 N): check the units"
                )));
            }
        }
        Ok(())
    }

    /// The solver loads of this case; `fixed_body` is the body held by the rig
    /// (the other end of the follower load).
    pub fn loads(&self, fixed_body: Option<&str>) -> Result<Vec<Load>> {
        let mut out = Vec::new();
        if self.moment.iter().any(|&x| x != 0.0) {
            out.push(Load::Moment {
                body: self.body.clone(),
                vec: Vector3::from(self.moment),
                frame: self.moment_frame.unwrap_or(FrameName::Ground).into(),
            });
        }
        if self.force.iter().any(|&x| x != 0.0) {
            out.push(Load::Force {
                body: self.body.clone(),
                point_in_body: Vector3::from(self.force_point),
                vec: Vector3::from(self.force),
                frame: self.force_frame.unwrap_or(FrameName::Ground).into(),
            });
        }
        if self.follower_load > 0.0 {
            let Some(fixed) = fixed_body else {
                return Err(Error::invalid(
                    format!("case '{}'", self.id),
                    "a follower load needs the fixed body (give --fixed BODY or weld a body to ground)",
                ));
            };
            out.push(Load::Follower {
                from_body: fixed.to_string(),
                to_body: self.body.clone(),
                magnitude: self.follower_load,
            });
        }
        Ok(out)
    }
}

/// Parse `[[case]]` tables from TOML text; ids must be unique.
pub fn parse_cases(text: &str, file: &Path) -> Result<Vec<LoadCase>> {
    let text = strip_bom(text);
    let parsed: CaseFile = toml::from_str(text).map_err(|e| toml_error(text, file, e))?;
    if parsed.case.is_empty() {
        return Err(Error::parse(
            file,
            "file",
            "no [[case]] table: a load file needs at least one",
        ));
    }
    let mut seen = std::collections::BTreeSet::new();
    for (i, c) in parsed.case.iter().enumerate() {
        c.validate(file, i)?;
        if !seen.insert(c.id.clone()) {
            return Err(Error::parse(
                file,
                format!("[[case]] #{}", i + 1),
                format!("duplicate case id '{}'", c.id),
            ));
        }
    }
    Ok(parsed.case)
}

/// Names of the six measured degrees of freedom, in column order.
pub const DOF_NAMES: [&str; 6] = ["rx", "ry", "rz", "tx", "ty", "tz"];

/// Index (0..6) of a DoF name (`rx` .. `tz`).
pub fn dof_index(name: &str) -> Option<usize> {
    DOF_NAMES.iter().position(|d| *d == name)
}

/// Units of `kinematics.csv` (`[units]`), as factors to SI.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Units {
    /// "deg" or "rad".
    pub angle: &'static str,
    /// "mm" or "m".
    pub length: &'static str,
}

impl Units {
    /// Factor from the file's angle unit to rad.
    pub fn angle_to_si(&self) -> f64 {
        if self.angle == "deg" {
            std::f64::consts::PI / 180.0
        } else {
            1.0
        }
    }
    /// Factor from the file's length unit to m.
    pub fn length_to_si(&self) -> f64 {
        if self.length == "mm" {
            1e-3
        } else {
            1.0
        }
    }
    /// Factor from SI to the file's unit for DoF `d` (0..6).
    pub fn from_si(&self, d: usize) -> f64 {
        if d < 3 {
            1.0 / self.angle_to_si()
        } else {
            1.0 / self.length_to_si()
        }
    }
}

/// One row of `kinematics.csv`, in SI (rad, m).
#[derive(Debug, Clone, PartialEq)]
pub struct Measurement {
    /// Index into [`Experiment::cases`].
    pub case: usize,
    /// Cranial body.
    pub upper: String,
    /// Caudal body.
    pub lower: String,
    /// rx, ry, rz (rad), tx, ty, tz (m); `None` = not measured.
    pub values: [Option<f64>; 6],
    /// Standard deviation of each cell (`sd_rx` .. `sd_tz`, SI); `None` =
    /// not stated.
    pub sd: [Option<f64>; 6],
    /// Line in kinematics.csv (for messages).
    pub line: u64,
}

/// An experiment folder, read and validated.
#[derive(Debug, Clone)]
pub struct Experiment {
    /// The folder.
    pub dir: PathBuf,
    /// A short name (the folder's name).
    pub name: String,
    /// The nominal model file.
    pub model_path: PathBuf,
    /// The nominal model document (for writing calibrated copies).
    pub doc: Document,
    /// Solver description: the fixed body's coordinates locked, gravity as
    /// `[specimen].gravity` says.
    pub spec: SystemSpec,
    /// The body the rig holds.
    pub fixed_body: String,
    /// Gravity on during the test.
    pub gravity: bool,
    /// Units of kinematics.csv.
    pub units: Units,
    /// The load cases, in file order.
    pub cases: Vec<LoadCase>,
    /// The measured rows, in file order.
    pub rows: Vec<Measurement>,
    /// Non-fatal findings (cases without rows, ...).
    pub warnings: Vec<String>,
    /// The `[measurement]` table (stated uncertainty), SI.
    pub measurement: MeasurementInfo,
}

/// The optional `[measurement]` table of `experiment.toml`: the stated
/// uncertainty of the cells that carry no `sd_*` value (SI: rad, m), what
/// the numbers are and over how many specimens they are means.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct MeasurementInfo {
    /// Per-cell SD of the rotations (rad).
    pub rotation_sd: Option<f64>,
    /// Per-cell SD of the translations (m).
    pub translation_sd: Option<f64>,
    /// Free text (e.g. "mean of 10 specimens (Yamamoto et al. 1989)").
    pub source: Option<String>,
    /// The cells are means over this many specimens.
    pub n_specimens: Option<u32>,
}

impl MeasurementInfo {
    /// The stated SD of DoF `d` (SI), when given.
    pub fn sd_of(&self, d: usize) -> Option<f64> {
        if d < 3 {
            self.rotation_sd
        } else {
            self.translation_sd
        }
    }
}

impl Measurement {
    /// The stated SD of DoF `d` (SI): the cell's own `sd_*` value, else the
    /// `[measurement]` one; `None` when neither is given.
    pub fn stated_sd(&self, d: usize, m: &MeasurementInfo) -> Option<f64> {
        self.sd.get(d).copied().flatten().or_else(|| m.sd_of(d))
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct SpecimenToml {
    model: String,
    fixed_body: String,
    gravity: bool,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct UnitsToml {
    angle: String,
    length: String,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct MeasurementToml {
    rotation_sd: Option<f64>,
    translation_sd: Option<f64>,
    source: Option<String>,
    n_specimens: Option<u32>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ExperimentToml {
    specimen: SpecimenToml,
    units: UnitsToml,
    #[serde(default)]
    measurement: Option<MeasurementToml>,
    #[serde(default)]
    case: Vec<LoadCase>,
}

fn toml_error(text: &str, file: &Path, e: toml::de::Error) -> Error {
    let location = match e.span() {
        Some(s) => format!(
            "line {}",
            text.get(..s.start)
                .map(|t| t.matches('\n').count() + 1)
                .unwrap_or(1)
        ),
        None => "file".to_string(),
    };
    Error::parse(file, location, e.message().to_string())
}

/// The content of an `experiment.toml`, parsed and validated as far as it
/// can be without the model ([`parse_experiment_toml`]).
#[derive(Debug, Clone, PartialEq)]
pub struct ExperimentFile {
    /// `[specimen] model`: the nominal model, relative to the file.
    pub model: String,
    /// `[specimen] fixed_body`.
    pub fixed_body: String,
    /// `[specimen] gravity`.
    pub gravity: bool,
    /// `[units]`.
    pub units: Units,
    /// The `[[case]]` tables, in file order (ids unique, values checked).
    pub cases: Vec<LoadCase>,
    /// `[measurement]` (SI; all `None` without the table).
    pub measurement: MeasurementInfo,
}

/// Check and convert the `[measurement]` table to SI: SDs finite and > 0
/// (a stated noise of 0 would make every likelihood infinite), at least
/// one specimen.
fn measurement_info(
    raw: Option<MeasurementToml>,
    units: &Units,
    file: &Path,
) -> Result<MeasurementInfo> {
    let Some(m) = raw else {
        return Ok(MeasurementInfo::default());
    };
    let sd = |v: Option<f64>, key: &str, to_si: f64| -> Result<Option<f64>> {
        match v {
            Some(x) if !(x.is_finite() && x > 0.0) => Err(Error::parse(
                file,
                format!("[measurement] {key}"),
                format!("expected a finite standard deviation > 0, got {x}"),
            )),
            other => Ok(other.map(|x| x * to_si)),
        }
    };
    if m.n_specimens == Some(0) {
        return Err(Error::parse(
            file,
            "[measurement] n_specimens",
            "expected at least 1 specimen, got 0",
        ));
    }
    Ok(MeasurementInfo {
        rotation_sd: sd(m.rotation_sd, "rotation_sd", units.angle_to_si())?,
        translation_sd: sd(m.translation_sd, "translation_sd", units.length_to_si())?,
        source: m.source,
        n_specimens: m.n_specimens,
    })
}

/// Parse the text of an `experiment.toml` (`file` names it in messages):
/// `[specimen]`, `[units]` and at least one `[[case]]`, ids unique. Unit
/// names are matched without regard to case (`"deg"`, `"DEG"`).
pub fn parse_experiment_toml(text: &str, file: &Path) -> Result<ExperimentFile> {
    let text = strip_bom(text);
    let raw: ExperimentToml = toml::from_str(text).map_err(|e| toml_error(text, file, e))?;
    // One of two unit names, matched without regard to case.
    let unit = |value: &str, key: &str, names: [&'static str; 2]| -> Result<&'static str> {
        let v = value.trim().to_ascii_lowercase();
        names.into_iter().find(|n| *n == v).ok_or_else(|| {
            Error::parse(
                file,
                format!("[units] {key}"),
                format!(
                    "expected \"{}\" or \"{}\", got \"{value}\"",
                    names[0], names[1]
                ),
            )
        })
    };
    let units = Units {
        angle: unit(&raw.units.angle, "angle", ["deg", "rad"])?,
        length: unit(&raw.units.length, "length", ["mm", "m"])?,
    };
    if raw.case.is_empty() {
        return Err(Error::parse(
            file,
            "file",
            "no [[case]] table: an experiment needs at least one load case",
        ));
    }
    let mut seen = BTreeSet::new();
    for (i, c) in raw.case.iter().enumerate() {
        c.validate(file, i)?;
        if !seen.insert(c.id.clone()) {
            return Err(Error::parse(
                file,
                format!("[[case]] #{}", i + 1),
                format!("duplicate case id '{}'", c.id),
            ));
        }
    }
    let measurement = measurement_info(raw.measurement, &units, file)?;
    Ok(ExperimentFile {
        model: raw.specimen.model,
        fixed_body: raw.specimen.fixed_body,
        gravity: raw.specimen.gravity,
        units,
        cases: raw.case,
        measurement,
    })
}

impl Experiment {
    /// Read `dir/experiment.toml`, the model it names and `dir/kinematics.csv`.
    pub fn read(dir: impl AsRef<Path>) -> Result<Experiment> {
        let dir = dir.as_ref().to_path_buf();
        let toml_path = dir.join("experiment.toml");
        let text = crate::util::read_text_capped(&toml_path, MAX_FILE_BYTES, "experiment files")?;
        let raw = parse_experiment_toml(&text, &toml_path)?;
        let units = raw.units;
        let model_path = dir.join(&raw.model);
        let doc = Document::read(&model_path)?;
        let model = doc.model()?;
        let mut spec = SystemSpec::from_model(&model)?;
        let bodies: Vec<String> = spec.bodies.iter().map(|b| b.name.clone()).collect();
        let known = |n: &str| bodies.iter().any(|b| b == n);
        let fixed = raw.fixed_body.clone();
        if !known(&fixed) {
            return Err(Error::parse(
                &toml_path,
                "[specimen] fixed_body",
                format!(
                    "no body named '{fixed}' in {} (bodies: {})",
                    model_path.display(),
                    bodies.join(", ")
                ),
            ));
        }
        for (i, c) in raw.cases.iter().enumerate() {
            if !known(&c.body) {
                return Err(Error::parse(
                    &toml_path,
                    format!("[[case]] #{} (id '{}')", i + 1, c.id),
                    format!(
                        "unknown body '{}': not in {} (bodies: {})",
                        c.body,
                        model_path.display(),
                        bodies.join(", ")
                    ),
                ));
            }
            if c.body == fixed {
                return Err(Error::parse(
                    &toml_path,
                    format!("[[case]] #{} (id '{}')", i + 1, c.id),
                    format!("the load is on the fixed body '{fixed}': it cannot move anything"),
                ));
            }
        }
        if !raw.gravity {
            spec.gravity = Vector3::zeros();
        }
        spec = System::with_body_fixed(&spec, &fixed)?;
        // adjacency: upper's joint has lower as parent
        let parent_of: BTreeMap<&str, Option<&str>> = spec
            .joints
            .iter()
            .filter_map(|j| {
                let child = spec.bodies.get(j.child)?.name.as_str();
                let parent = j
                    .parent
                    .and_then(|p| spec.bodies.get(p))
                    .map(|b| b.name.as_str());
                Some((child, parent))
            })
            .collect();
        let csv_path = dir.join("kinematics.csv");
        let csv_text =
            crate::util::read_text_capped(&csv_path, MAX_FILE_BYTES, "experiment files")?;
        let rows = parse_kinematics(&csv_text, &csv_path, &raw.cases, &units, &|u, l| {
            let unknown = |body: &str, column| PairError::UnknownBody {
                body: body.to_string(),
                column,
                known: bodies.join(", "),
            };
            if !known(u) {
                return Err(unknown(u, "upper"));
            }
            if !known(l) {
                return Err(unknown(l, "lower"));
            }
            match parent_of.get(u) {
                Some(Some(p)) if *p == l => Ok(()),
                parent => Err(PairError::NotAdjacent {
                    upper: u.to_string(),
                    lower: l.to_string(),
                    parent: parent.copied().flatten().map(str::to_string),
                }),
            }
        })?;
        let mut warnings = Vec::new();
        let measured: BTreeSet<usize> = rows.iter().map(|r| r.case).collect();
        for (i, c) in raw.cases.iter().enumerate() {
            if !measured.contains(&i) {
                warnings.push(format!(
                    "case '{}' has no row in kinematics.csv: it is not used",
                    c.id
                ));
            }
        }
        let name = dir
            .canonicalize()
            .ok()
            .and_then(|p| p.file_name().map(|n| n.to_string_lossy().into_owned()))
            .unwrap_or_else(|| dir.display().to_string());
        Ok(Experiment {
            dir,
            name,
            model_path,
            doc,
            spec,
            fixed_body: fixed,
            gravity: raw.gravity,
            units,
            cases: raw.cases,
            rows,
            warnings,
            measurement: raw.measurement,
        })
    }

    /// DoFs (0..6) with at least one measured cell.
    pub fn measured_dofs(&self) -> Vec<usize> {
        (0..6)
            .filter(|&d| self.rows.iter().any(|r| r.values[d].is_some()))
            .collect()
    }

    /// The same experiment restricted to the cases whose index `keep` accepts
    /// (rows of the others dropped; case indices renumbered).
    pub fn subset(&self, keep: impl Fn(usize) -> bool) -> Experiment {
        let mut map = vec![None; self.cases.len()];
        let mut cases = Vec::new();
        for (i, c) in self.cases.iter().enumerate() {
            if keep(i) {
                map[i] = Some(cases.len());
                cases.push(c.clone());
            }
        }
        let rows = self
            .rows
            .iter()
            .filter_map(|r| {
                let ci = map.get(r.case).copied().flatten()?;
                Some(Measurement {
                    case: ci,
                    ..r.clone()
                })
            })
            .collect();
        Experiment {
            cases,
            rows,
            warnings: Vec::new(),
            ..self.clone()
        }
    }
}

/// Largest plausible measured angle (rad) and translation (m) for an
/// increment between adjacent vertebrae: beyond these the file's units are
/// almost certainly not what `[units]` says.
const MAX_ANGLE_RAD: f64 = 1.0;
const MAX_TRANSLATION_M: f64 = 0.05;

/// Why a row's `upper`/`lower` pair of body names cannot be measured.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum PairError {
    /// The model has no body of that name.
    #[error("unknown body '{body}' in column {column} (bodies: {known})")]
    UnknownBody {
        /// The name in the file.
        body: String,
        /// `upper` or `lower`.
        column: &'static str,
        /// The model's body names, comma-separated.
        known: String,
    },
    /// `upper`'s joint does not hang it on `lower`.
    #[error("'{upper}' and '{lower}' are not an adjacent pair: {}", match parent {
        Some(p) => format!("the joint of '{upper}' connects it to '{p}'"),
        None => format!("'{upper}' hangs on ground"),
    })]
    NotAdjacent {
        /// The row's upper body.
        upper: String,
        /// The row's lower body.
        lower: String,
        /// The body `upper`'s joint connects it to (None: ground).
        parent: Option<String>,
    },
}

/// Checks an `upper`/`lower` pair of body names against the model (see
/// [`Experiment::read`]).
pub type PairCheck<'a> = dyn Fn(&str, &str) -> std::result::Result<(), PairError> + 'a;

/// Largest experiment file accepted (a study with thousands of rows is < 1 MB).
pub const MAX_FILE_BYTES: u64 = 64 * 1024 * 1024;

/// Parse the text of a `kinematics.csv` (`path` names it in messages).
///
/// Columns are found by name (`case,upper,lower,rx,ry,rz,tx,ty,tz`, any
/// order, names matched without regard to case; other columns are ignored).
/// Optional columns `sd_rx` .. `sd_tz` give each cell's standard deviation
/// in the same units (> 0; empty = unknown).
/// Cells, comments, a byte-order mark and line ends as [`crate::util::table`]
/// reads them (trimmed, may be quoted; `#` lines are comments); an empty
/// cell, or a cell missing at the end of a short row, is "not measured";
/// cells beyond the header must be empty (trailing commas). `cases` are the
/// experiment's load cases, `check_pair` validates each `upper`/`lower`.
pub fn parse_kinematics(
    text: &str,
    path: &Path,
    cases: &[LoadCase],
    units: &Units,
    check_pair: &PairCheck,
) -> Result<Vec<Measurement>> {
    let mut rows = CsvReader::new(text, path).records();
    let Some(headers) = rows.next().transpose()? else {
        return Err(Error::parse(
            path,
            "line 1",
            "missing column 'case' (expected case,upper,lower,rx,ry,rz,tx,ty,tz): no header row",
        ));
    };
    let header_line = headers.line();
    let mut col = [0usize; 9];
    for (k, name) in ["case", "upper", "lower"]
        .iter()
        .chain(DOF_NAMES.iter())
        .enumerate()
    {
        let hits: Vec<usize> = headers
            .cells()
            .enumerate()
            .filter(|(_, h)| h.eq_ignore_ascii_case(name))
            .map(|(i, _)| i)
            .collect();
        match hits.as_slice() {
            [one] => col[k] = *one,
            [] => {
                return Err(headers.error(
                    path,
                    format!(
                        "missing column '{name}' (expected case,upper,lower,rx,ry,rz,tx,ty,tz)"
                    ),
                ))
            }
            _ => return Err(headers.error(path, format!("column '{name}' appears more than once"))),
        }
    }
    let sd_col = sd_columns(&headers, path, header_line)?;
    let case_idx: BTreeMap<&str, usize> = cases
        .iter()
        .enumerate()
        .map(|(i, c)| (c.id.as_str(), i))
        .collect();
    let mut out = Vec::new();
    let mut seen: BTreeMap<(usize, String, String), u64> = BTreeMap::new();
    for rec in rows {
        let rec = rec?;
        let line = rec.line();
        let at = rec.at();
        if rec.all_empty() {
            continue; // a row of empty cells (spreadsheet export)
        }
        if let Some((k, cell)) = rec
            .cells()
            .enumerate()
            .skip(headers.len())
            .find(|(_, c)| !c.is_empty())
        {
            return Err(Error::parse(
                path,
                at,
                format!(
                    "cell {} ('{cell}') is beyond the {} columns of the header",
                    k + 1,
                    headers.len()
                ),
            ));
        }
        let field = |k: usize| rec.cell(col[k]);
        let id = field(0);
        let Some(&ci) = case_idx.get(id) else {
            return Err(Error::parse(
                path,
                at,
                format!("case '{id}' is not a [[case]] of experiment.toml"),
            ));
        };
        let upper = field(1).to_string();
        let lower = field(2).to_string();
        check_pair(&upper, &lower).map_err(|m| Error::parse(path, at.clone(), m.to_string()))?;
        let mut values = [None; 6];
        let mut sd = [None; 6];
        for d in 0..6 {
            values[d] = parse_value(field(3 + d), d, units, path, &at)?;
            let s = sd_col[d].map_or("", |k| rec.cell(k));
            sd[d] = parse_sd(s, d, units, path, &at)?;
        }
        if let Some(prev) = seen.insert((ci, upper.clone(), lower.clone()), line) {
            return Err(Error::parse(
                path,
                at,
                format!(
                    "duplicate row for case '{id}', pair {upper}/{lower} (first on line {prev})"
                ),
            ));
        }
        out.push(Measurement {
            case: ci,
            upper,
            lower,
            values,
            sd,
            line,
        });
    }
    if out.is_empty() {
        return Err(Error::parse(path, "file", "no data rows"));
    }
    Ok(out)
}

/// The optional uncertainty columns `sd_rx` .. `sd_tz` (by name, any case).
fn sd_columns(headers: &CsvRecord, path: &Path, header_line: u64) -> Result<[Option<usize>; 6]> {
    let mut out = [None; 6];
    for (d, slot) in out.iter_mut().enumerate() {
        let name = format!("sd_{}", DOF_NAMES[d]);
        let hits: Vec<usize> = headers
            .cells()
            .enumerate()
            .filter(|(_, h)| h.eq_ignore_ascii_case(&name))
            .map(|(i, _)| i)
            .collect();
        if hits.len() > 1 {
            return Err(Error::parse(
                path,
                format!("line {header_line}"),
                format!("column '{name}' appears more than once"),
            ));
        }
        *slot = hits.first().copied();
    }
    Ok(out)
}

/// A number of column `col` (finite), `None` for an empty cell.
fn parse_number(s: &str, col: &str, path: &Path, at: &str) -> Result<Option<f64>> {
    if s.is_empty() {
        return Ok(None);
    }
    let x: f64 = s.parse().map_err(|_| {
        Error::parse(
            path,
            at,
            format!("column {col}: '{s}' is not a number (leave the cell empty when not measured)"),
        )
    })?;
    if !x.is_finite() {
        return Err(Error::parse(
            path,
            at,
            format!("column {col}: value must be finite"),
        ));
    }
    Ok(Some(x))
}

/// File unit of DoF `d` to SI.
fn to_si(d: usize, units: &Units) -> f64 {
    if d < 3 {
        units.angle_to_si()
    } else {
        units.length_to_si()
    }
}

/// A measured value of DoF `d` in SI, checked against the plausible range.
fn parse_value(s: &str, d: usize, units: &Units, path: &Path, at: &str) -> Result<Option<f64>> {
    let Some(x) = parse_number(s, DOF_NAMES[d], path, at)? else {
        return Ok(None);
    };
    let si = x * to_si(d, units);
    let (limit, unit, other) = if d < 3 {
        (
            MAX_ANGLE_RAD,
            units.angle,
            if units.angle == "rad" { "deg" } else { "?" },
        )
    } else {
        (
            MAX_TRANSLATION_M,
            units.length,
            if units.length == "m" { "mm" } else { "?" },
        )
    };
    if si.abs() > limit {
        return Err(Error::parse(
            path,
            at,
            format!(
                "column {}: {x} {unit} is implausibly large for an increment between adjacent vertebrae \
                 (more than {limit} {}): inconsistent units? ([units] says {unit}{})",
                DOF_NAMES[d],
                if d < 3 { "rad" } else { "m" },
                if other != "?" { format!("; the values look like {other}") } else { String::new() }
            ),
        ));
    }
    Ok(Some(si))
}

/// A stated SD of DoF `d` in SI (`sd_*` column): finite and > 0.
fn parse_sd(s: &str, d: usize, units: &Units, path: &Path, at: &str) -> Result<Option<f64>> {
    let col = format!("sd_{}", DOF_NAMES[d]);
    let Some(x) = parse_number(s, &col, path, at)? else {
        return Ok(None);
    };
    if x <= 0.0 {
        return Err(Error::parse(
            path,
            at,
            format!("column {col}: a standard deviation must be > 0, got {x} (leave the cell empty when unknown)"),
        ));
    }
    Ok(Some(x * to_si(d, units)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_the_documented_example() {
        let text = r#"
[specimen]
model = "specimen.osim"
[[case]]
id = "FE_neg_7.5"
body = "thoracic12"
moment = [0.0, 0.0, -7.5]
moment_frame = "ground"
force = [0.0, 0.0, 0.0]
force_point = [0.0, 0.0, 0.0]
force_frame = "ground"
follower_load = 0.0
[[case]]
id = "fl"
body = "lumbar1"
follower_load = 400.0
"#;
        let cs = parse_cases(text, Path::new("x.toml")).unwrap();
        assert_eq!(cs.len(), 2);
        assert_eq!(cs[0].moment, [0.0, 0.0, -7.5]);
        let l = cs[1].loads(Some("sacrum")).unwrap();
        assert_eq!(
            l,
            vec![Load::Follower {
                from_body: "sacrum".into(),
                to_body: "lumbar1".into(),
                magnitude: 400.0
            }]
        );
        assert!(cs[1].loads(None).is_err());
    }

    #[test]
    fn rejects_bad_cases() {
        let p = Path::new("bad.toml");
        for (text, needle) in [
            (
                "[[case]]\nid='a'\nbody='b'\nmoment=[1,0,0]\n",
                "moment_frame",
            ),
            (
                "[[case]]\nid='a'\nbody='b'\nmoment=[1,0]\nmoment_frame='ground'\n",
                "line",
            ),
            (
                "[[case]]\nid='a'\nbody='b'\nfollower_load=-3\n",
                "follower_load",
            ),
            (
                "[[case]]\nid='a'\nbody='b'\n[[case]]\nid='a'\nbody='c'\n",
                "duplicate",
            ),
            ("[[case]]\nid='a'\nbody='b'\nmomnet=[1,0,0]\n", "momnet"),
            ("x = 1\n", "no [[case]]"),
        ] {
            let e = parse_cases(text, p).unwrap_err().to_string();
            assert!(e.contains(needle) && e.contains("bad.toml"), "{e}");
        }
    }

    const TOML: &str = "[specimen]\nmodel = \"specimen.osim\"\nfixed_body = \"sacrum\"\ngravity = false\n\n[units]\nangle = \"deg\"\nlength = \"mm\"\n\n[[case]]\nid = \"FE_neg_7.5\"\nbody = \"lumbar4\"\nmoment = [0.0, 0.0, -7.5]\nmoment_frame = \"ground\"\n\n[[case]]\nid = \"LB\"\nbody = \"lumbar4\"\nmoment = [7.5, 0.0, 0.0]\nmoment_frame = \"body\"\n";

    fn adjacent(u: &str, l: &str) -> std::result::Result<(), PairError> {
        match (u, l) {
            ("lumbar5", "sacrum") | ("lumbar4", "lumbar5") => Ok(()),
            _ => Err(PairError::NotAdjacent {
                upper: u.into(),
                lower: l.into(),
                parent: None,
            }),
        }
    }

    fn kin(text: &str) -> Result<Vec<Measurement>> {
        let e = parse_experiment_toml(TOML, Path::new("experiment.toml")).unwrap();
        parse_kinematics(
            text,
            Path::new("kinematics.csv"),
            &e.cases,
            &e.units,
            &adjacent,
        )
    }

    #[test]
    fn experiment_toml_follows_the_format() {
        let e = parse_experiment_toml(TOML, Path::new("experiment.toml")).unwrap();
        assert_eq!(e.model, "specimen.osim");
        assert_eq!(e.fixed_body, "sacrum");
        assert!(!e.gravity);
        assert_eq!((e.units.angle, e.units.length), ("deg", "mm"));
        assert_eq!(e.cases.len(), 2);
        assert_eq!(e.cases[1].moment_frame, Some(FrameName::Body));
        // optional keys default to zero / ground
        assert_eq!(e.cases[0].force, [0.0; 3]);
        assert_eq!(e.cases[0].follower_load, 0.0);
        // a byte-order mark and CRLF line ends; unit names in any case
        let crlf = format!(
            "\u{feff}{}",
            TOML.replace('\n', "\r\n").replace("\"deg\"", "\"DEG\"")
        );
        let e2 = parse_experiment_toml(&crlf, Path::new("experiment.toml")).unwrap();
        assert_eq!(e2.cases, e.cases);
        assert_eq!(e2.units.angle, "deg");
        // errors name the file and where
        let p = Path::new("experiment.toml");
        for (text, needles) in [
            (
                TOML.replace("angle = \"deg\"", "angle = \"grad\""),
                vec!["[units] angle", "\"deg\" or \"rad\""],
            ),
            (
                TOML.replace("length = \"mm\"", "length = \"cm\""),
                vec!["[units] length"],
            ),
            (
                TOML.replace("[units]\nangle = \"deg\"\nlength = \"mm\"\n", ""),
                vec!["units"],
            ),
            (TOML.replace("gravity = false\n", ""), vec!["gravity"]),
            (
                TOML.replace("moment_frame = \"body\"", "moment_frame = \"local\""),
                vec!["line 20", "local"],
            ),
            (
                TOML.replace("id = \"LB\"", "id = \"FE_neg_7.5\""),
                vec!["[[case]] #2", "duplicate case id"],
            ),
            (
                TOML.split("[[case]]").next().unwrap().to_string(),
                vec!["no [[case]]"],
            ),
        ] {
            let e = parse_experiment_toml(&text, p).unwrap_err().to_string();
            assert!(e.contains("experiment.toml"), "{e}");
            for n in needles {
                assert!(e.contains(n), "`{n}` not in: {e}");
            }
        }
    }

    #[test]
    fn uncertainty_columns_and_measurement_table_are_read_in_si() {
        let d2r = std::f64::consts::PI / 180.0;
        let rows = kin("case,upper,lower,rx,ry,rz,tx,ty,tz,SD_RX,sd_ry,sd_rz,sd_tx\nFE_neg_7.5,lumbar5,sacrum,1,2,3,,,,0.5,,1.5,\n").unwrap();
        assert!((rows[0].sd[0].unwrap() - 0.5 * d2r).abs() < 1e-15);
        assert_eq!(rows[0].sd[1], None);
        assert!((rows[0].sd[2].unwrap() - 1.5 * d2r).abs() < 1e-15);
        assert_eq!(rows[0].sd[3..], [None, None, None]);
        // without sd columns nothing is stated
        let rows = kin("case,upper,lower,rx,ry,rz,tx,ty,tz\nLB,lumbar5,sacrum,1,2,3\n").unwrap();
        assert_eq!(rows[0].sd, [None; 6]);
        for (text, needle) in [
            (
                "case,upper,lower,rx,ry,rz,tx,ty,tz,sd_rz\nLB,lumbar5,sacrum,1,2,3,,,,0\n",
                "must be > 0",
            ),
            (
                "case,upper,lower,rx,ry,rz,tx,ty,tz,sd_rz\nLB,lumbar5,sacrum,1,2,3,,,,-1\n",
                "must be > 0",
            ),
            (
                "case,upper,lower,rx,ry,rz,tx,ty,tz,sd_rz\nLB,lumbar5,sacrum,1,2,3,,,,x\n",
                "column sd_rz",
            ),
            (
                "case,upper,lower,rx,ry,rz,tx,ty,tz,sd_rz,sd_rz\n",
                "more than once",
            ),
        ] {
            let e = kin(text).unwrap_err().to_string();
            assert!(e.contains(needle) && e.contains("kinematics.csv"), "{e}");
        }
        // [measurement]: SDs in the file's units, converted to SI
        let t = TOML.replace(
            "[units]",
            "[measurement]\nrotation_sd = 0.2\ntranslation_sd = 0.05\nsource = \"mean of 10\"\nn_specimens = 10\n\n[units]",
        );
        let e = parse_experiment_toml(&t, Path::new("experiment.toml")).unwrap();
        let m = &e.measurement;
        assert!((m.rotation_sd.unwrap() - 0.2 * d2r).abs() < 1e-15);
        assert!((m.translation_sd.unwrap() - 0.05e-3).abs() < 1e-15);
        assert_eq!(
            (m.source.as_deref(), m.n_specimens),
            (Some("mean of 10"), Some(10))
        );
        let row = Measurement {
            case: 0,
            upper: "a".into(),
            lower: "b".into(),
            values: [None; 6],
            sd: [Some(1.0), None, None, None, None, None],
            line: 2,
        };
        assert_eq!(row.stated_sd(0, m), Some(1.0));
        assert_eq!(row.stated_sd(1, m), m.rotation_sd);
        assert_eq!(row.stated_sd(4, m), m.translation_sd);
        assert_eq!(row.stated_sd(4, &MeasurementInfo::default()), None);
        for (bad, needle) in [
            ("rotation_sd = 0.0", "[measurement] rotation_sd"),
            ("translation_sd = -1.0", "[measurement] translation_sd"),
            ("n_specimens = 0", "[measurement] n_specimens"),
            ("rotaton_sd = 1.0", "rotaton_sd"),
        ] {
            let t = TOML.replace("[units]", &format!("[measurement]\n{bad}\n\n[units]"));
            let e = parse_experiment_toml(&t, Path::new("experiment.toml"))
                .unwrap_err()
                .to_string();
            assert!(e.contains(needle), "{e}");
        }
    }

    #[test]
    fn kinematics_csv_variants() {
        let d2r = std::f64::consts::PI / 180.0;
        // the documented layout
        let rows = kin("case,upper,lower,rx,ry,rz,tx,ty,tz\nFE_neg_7.5,lumbar5,sacrum,-0.0213,0.0011,-5.871,0.412,-0.035,0.020\n").unwrap();
        assert_eq!(rows.len(), 1);
        assert!((rows[0].values[2].unwrap() - (-5.871 * d2r)).abs() < 1e-15);
        assert!((rows[0].values[3].unwrap() - 0.412e-3).abs() < 1e-15);
        assert_eq!(rows[0].line, 2);
        // BOM, CRLF, upper-case and reordered columns, an extra column,
        // quoted cells, a comment, blank translation cells, a short row
        // (translations left out), trailing commas, an all-empty row
        let text = "\u{feff}# rig 2\r\nUpper,LOWER,Case,RX,ry,rz,tx,ty,tz,note\r\n\"lumbar5\",sacrum,\"FE_neg_7.5\",1,2,3,,,,ok\r\nlumbar4,lumbar5,FE_neg_7.5,4,5,6\r\n,,,,,,,,,\r\nlumbar5,sacrum,LB,7,8,9,1,2,3,,,\r\n";
        let rows = kin(text).unwrap();
        assert_eq!(rows.len(), 3);
        assert_eq!(
            (rows[0].upper.as_str(), rows[0].lower.as_str()),
            ("lumbar5", "sacrum")
        );
        // a quoted note holding commas stays one (ignored) cell; a bad cell
        // names its line of the file (BOM, comment, CRLF, blank line counted)
        let text = "\u{feff}# rig\r\ncase,upper,lower,rx,ry,rz,tx,ty,tz,note\r\n\r\nLB,lumbar5,sacrum,1,2,3,,,,\"a, b, c\"\r\nFE_neg_7.5,lumbar5,sacrum,\"4,5\",6,7\r\n";
        let e = kin(text).unwrap_err().to_string();
        assert!(
            e.contains("kinematics.csv: line 5: column rx: '4,5' is not a number"),
            "{e}"
        );
        let q = kin(&text.replace("\"4,5\"", "4.5")).unwrap();
        assert_eq!((q.len(), q[0].line, q[1].line), (2, 4, 5));
        assert!((q[1].values[0].unwrap() - 4.5 * d2r).abs() < 1e-15);
        assert_eq!(rows[0].case, 0);
        assert_eq!(rows[2].case, 1);
        for (r, want) in rows
            .iter()
            .zip([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0], [7.0, 8.0, 9.0]])
        {
            for (v, w) in r.values.iter().zip(want) {
                assert!((v.unwrap() - w * d2r).abs() < 1e-15);
            }
        }
        assert_eq!(rows[0].values[3..], [None, None, None]);
        assert_eq!(rows[1].values[3..], [None, None, None]);
        assert!((rows[2].values[5].unwrap() - 3e-3).abs() < 1e-15);
        assert_eq!(rows[2].line, 6);
        // errors name the file, the line and what was expected
        for (text, needles) in [
            (
                "case,upper,lower,rx,ry,rz,tx,ty\n",
                vec!["line 1", "missing column 'tz'"],
            ),
            (
                "case,upper,lower,rx,ry,rz,tx,ty,tz,RX\n",
                vec!["column 'rx' appears more than once"],
            ),
            (
                "case,upper,lower,rx,ry,rz,tx,ty,tz\nLB,lumbar5,sacrum,1,2,3,,,,5\n",
                vec!["line 2", "beyond the 9 columns"],
            ),
            (
                "case,upper,lower,rx,ry,rz,tx,ty,tz\nLB,lumbar5,sacrum,NaN,2,3\n",
                vec!["line 2", "column rx", "finite"],
            ),
            (
                "case,upper,lower,rx,ry,rz,tx,ty,tz\nLB,lumbar5,sacrum,1;5,2,3\n",
                vec!["line 2", "column rx", "'1;5' is not a number"],
            ),
            (
                "case,upper,lower,rx,ry,rz,tx,ty,tz\nXX,lumbar5,sacrum,1,2,3\n",
                vec!["line 2", "case 'XX'"],
            ),
            (
                "case,upper,lower,rx,ry,rz,tx,ty,tz\nLB,sacrum,lumbar5,1,2,3\n",
                vec!["line 2", "not an adjacent pair"],
            ),
            (
                "case,upper,lower,rx,ry,rz,tx,ty,tz\nLB,lumbar5,sacrum,1\nLB,lumbar5,sacrum,2\n",
                vec!["line 3", "duplicate row", "line 2"],
            ),
            ("case,upper,lower,rx,ry,rz,tx,ty,tz\n", vec!["no data rows"]),
            ("", vec!["missing column 'case'"]),
        ] {
            let e = kin(text).unwrap_err().to_string();
            assert!(e.contains("kinematics.csv"), "{e}");
            for n in needles {
                assert!(e.contains(n), "`{n}` not in: {e}");
            }
        }
    }
}
