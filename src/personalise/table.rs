//! Stiffness tables: the TOML and CSV formats of `docs/stiffness-table.md`,
//! read into [`Table`] (SI units, unit headers checked and converted) and
//! written back from per-level laws ([`LevelLaw`]) by `--list`.
//!
//! A table has an optional `[all]` row (values for every level, `*` in CSV)
//! and `[[level]]` rows. Rows give a form (`linear`, `nonlinear`,
//! `coupled`, `expression`), stiffness, ratio and damping per DoF (`rx ry rz
//! tx ty tz`), curves, a 6x6 matrix or six expressions. Values are checked
//! here as far as they can be without the model (units, DoF names, numbers);
//! [`super::resolve`] merges rows with the model and validates the laws.

use crate::error::{Error, Result};
use crate::osim::function::{CubicSpline, Function};
use crate::osim::physics::MAX_STIFFNESS;
use crate::solver::spec::DOF_NAMES;
use crate::solver::Curve;
use crate::util::table::{strip_bom, CsvReader, CsvRecord};
use serde::Deserialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Form of a level's law.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Form {
    /// Diagonal linear stiffness: OpenSim BushingForce.
    Linear,
    /// A curve per DoF: FunctionBasedBushingForce (ExpressionBasedBushingForce
    /// when a curve is a sinh).
    Nonlinear,
    /// Symmetric positive-definite 6x6 stiffness: ExpressionBasedBushingForce.
    Coupled,
    /// Six Lepton expressions: ExpressionBasedBushingForce.
    Expression,
}

impl Form {
    /// The form's name in tables (`linear`, `nonlinear`, `coupled`, `expression`).
    pub fn name(self) -> &'static str {
        match self {
            Form::Linear => "linear",
            Form::Nonlinear => "nonlinear",
            Form::Coupled => "coupled",
            Form::Expression => "expression",
        }
    }
    fn parse(s: &str) -> Option<Form> {
        Some(match s {
            "linear" => Form::Linear,
            "nonlinear" => Form::Nonlinear,
            "coupled" => Form::Coupled,
            "expression" => Form::Expression,
            _ => return None,
        })
    }
}

/// Interpolation of a curve given as points.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Interp {
    /// PiecewiseLinearFunction (linear extrapolation with the end slopes).
    Linear,
    /// SimmSpline (OpenSim's natural cubic spline).
    Spline,
}

/// A curve through points `x`, `y` (the table's `points` kind): OpenSim's
/// PiecewiseLinearFunction or, interpolated by a spline, its SimmSpline.
/// Points a spline cannot go through (not as many values as knots, fewer
/// than two) are kept as a PiecewiseLinearFunction, for the validation to
/// refuse ([`super::resolve`]).
pub fn points_curve(x: Vec<f64>, y: Vec<f64>, interp: Interp) -> Curve {
    Curve::Function(
        if interp == Interp::Spline && x.len() == y.len() && x.len() >= 2 {
            Function::Spline {
                class: "SimmSpline".into(),
                spline: CubicSpline::new(x, y),
            }
        } else {
            Function::PiecewiseLinear { x, y }
        },
    )
}

/// The points of a `points` curve ([`points_curve`]): `x`, `y` and the
/// interpolation; `None` for other curves.
pub fn curve_points(c: &Curve) -> Option<(&[f64], &[f64], Interp)> {
    match c {
        Curve::Function(Function::PiecewiseLinear { x, y }) => Some((x, y, Interp::Linear)),
        Curve::Function(Function::Spline { spline, .. }) => {
            Some((&spline.x, &spline.y, Interp::Spline))
        }
        _ => None,
    }
}

/// The complete law of one level, SI units, as written into / read from a model.
/// (The coupled variant is larger than the others; laws are few, so it is not boxed.)
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, PartialEq)]
pub enum LevelLaw {
    /// Diagonal linear stiffness: `f = -(K q + C q')` element by element.
    Linear {
        /// Stiffness per DoF, rx..tz (N m/rad, then N/m).
        k: [f64; 6],
        /// Damping per DoF, rx..tz (N m s/rad, then N s/m).
        c: [f64; 6],
    },
    /// A curve per DoF: `f_i = -g_i(q_i) - c_i q_i'`.
    Nonlinear {
        /// Curve per DoF, rx..tz.
        curves: Box<[Curve; 6]>,
        /// Damping per DoF, rx..tz (N m s/rad, then N s/m).
        c: [f64; 6],
    },
    /// Coupled linear stiffness: `f = -K q - C q'`.
    Coupled {
        /// Symmetric positive-definite 6x6 stiffness, rows and columns rx..tz (SI).
        k: [[f64; 6]; 6],
        /// Damping per DoF, rx..tz (N m s/rad, then N s/m).
        c: [f64; 6],
    },
    /// Six Lepton expressions of the deflections.
    Expression {
        /// Expression per DoF, rx..tz.
        exprs: Box<[String; 6]>,
        /// Damping per DoF, rx..tz (N m s/rad, then N s/m).
        c: [f64; 6],
    },
}

impl LevelLaw {
    /// The law's form.
    pub fn form(&self) -> Form {
        match self {
            LevelLaw::Linear { .. } => Form::Linear,
            LevelLaw::Nonlinear { .. } => Form::Nonlinear,
            LevelLaw::Coupled { .. } => Form::Coupled,
            LevelLaw::Expression { .. } => Form::Expression,
        }
    }
    /// Damping per DoF, rx..tz (N m s/rad, then N s/m).
    pub fn damping(&self) -> [f64; 6] {
        match self {
            LevelLaw::Linear { c, .. }
            | LevelLaw::Nonlinear { c, .. }
            | LevelLaw::Coupled { c, .. }
            | LevelLaw::Expression { c, .. } => *c,
        }
    }
}

/// One row of a table (`[all]` or a `[[level]]`), SI units, unresolved.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Row {
    /// Level name (`*` for the `[all]` row).
    pub name: String,
    /// Where the row is, for messages: `[[level]] #3 'L4_L5'`, `line 5 'L4_L5'`.
    pub location: String,
    /// Form given by the row, if any.
    pub form: Option<Form>,
    /// Linear stiffness per DoF, rx..tz (N m/rad, then N/m).
    pub stiffness: [Option<f64>; 6],
    /// Ratio applied to the stiffness per DoF (dimensionless, > 0).
    pub ratio: [Option<f64>; 6],
    /// Damping per DoF, rx..tz (N m s/rad, then N s/m).
    pub damping: [Option<f64>; 6],
    /// Curve per DoF (nonlinear form).
    pub curves: [Option<Curve>; 6],
    /// 6x6 stiffness, rows and columns rx..tz (coupled form, SI).
    pub matrix: Option<[[f64; 6]; 6]>,
    /// Lepton expression per DoF, rx..tz (expression form).
    pub expressions: Option<[String; 6]>,
}

/// A parsed table.
#[derive(Debug, Clone, PartialEq)]
pub struct Table {
    /// The file it came from (for messages).
    pub path: PathBuf,
    /// The `[all]` row (CSV: level `*`).
    pub all: Option<Row>,
    /// Level rows in file order.
    pub levels: Vec<Row>,
}

/// Unit factors to SI of one quantity: (accepted spelling, factor).
const ROT_STIFF: &[(&str, f64)] = &[("N*m/rad", 1.0), ("N*m/deg", 180.0 / std::f64::consts::PI)];
const TRANS_STIFF: &[(&str, f64)] = &[("N/m", 1.0), ("N/mm", 1000.0)];
const ROT_DAMP: &[(&str, f64)] = &[
    ("N*m*s/rad", 1.0),
    ("N*m*s/deg", 180.0 / std::f64::consts::PI),
];
const TRANS_DAMP: &[(&str, f64)] = &[("N*s/m", 1.0), ("N*s/mm", 1000.0)];

fn unit_factor(
    path: &Path,
    key: &str,
    given: Option<&str>,
    accepted: &[(&str, f64)],
) -> Result<f64> {
    let list = accepted
        .iter()
        .map(|(u, _)| format!("\"{u}\""))
        .collect::<Vec<_>>()
        .join(", ");
    let Some(u) = given else {
        return Err(Error::parse(
            path,
            "[units]",
            format!(
                "missing unit `{key}` (accepted: {list}); the units of every table must be stated"
            ),
        ));
    };
    let norm: String = u.chars().filter(|c| !c.is_whitespace()).collect();
    accepted
        .iter()
        .find(|(s, _)| *s == norm)
        .map(|(_, f)| *f)
        .ok_or_else(|| {
            Error::parse(
                path,
                "[units]",
                format!("unit `{key}` = \"{u}\" is not accepted (accepted: {list})"),
            )
        })
}

/// Unit factors of a table (stiffness and damping, rotational and translational).
#[derive(Debug, Clone, Copy)]
struct Units {
    stiff: [f64; 6],
    damp: [f64; 6],
    /// All units are SI (required by curves, matrices and expressions).
    si: bool,
}

fn dof_index(name: &str) -> Option<usize> {
    DOF_NAMES.iter().position(|d| *d == name)
}

// ---------------------------------------------------------------- TOML

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct TomlFile {
    #[serde(default)]
    format: Option<String>,
    #[serde(default)]
    units: Option<TomlUnits>,
    #[serde(default)]
    all: Option<TomlRow>,
    #[serde(default)]
    level: Vec<TomlRow>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct TomlUnits {
    rotational: Option<String>,
    translational: Option<String>,
    rot_damping: Option<String>,
    trans_damping: Option<String>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct TomlRow {
    name: Option<String>,
    form: Option<String>,
    stiffness: Option<BTreeMap<String, f64>>,
    ratio: Option<BTreeMap<String, f64>>,
    damping: Option<BTreeMap<String, f64>>,
    #[serde(default)]
    curve: Vec<TomlCurve>,
    matrix: Option<Vec<Vec<f64>>>,
    expressions: Option<BTreeMap<String, String>>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct TomlCurve {
    dof: String,
    kind: String,
    k: Option<f64>,
    c: Option<f64>,
    a: Option<f64>,
    k_neg: Option<f64>,
    k_pos: Option<f64>,
    x: Option<Vec<f64>>,
    y: Option<Vec<f64>>,
    interp: Option<String>,
    coefficients: Option<Vec<f64>>,
}

fn dof_map(
    path: &Path,
    loc: &str,
    what: &str,
    m: &Option<BTreeMap<String, f64>>,
    factor: Option<&[f64; 6]>,
) -> Result<[Option<f64>; 6]> {
    let mut out = [None; 6];
    if let Some(m) = m {
        for (k, v) in m {
            let i = dof_index(k).ok_or_else(|| {
                Error::parse(
                    path,
                    loc,
                    format!("{what}: unknown DoF '{k}' (DoFs: {})", DOF_NAMES.join(", ")),
                )
            })?;
            let si = v * factor.map(|f| f[i]).unwrap_or(1.0);
            if !si.is_finite() || si.abs() > MAX_STIFFNESS {
                return Err(Error::parse(
                    path,
                    loc,
                    format!("{what}.{k} = {v:e} is not finite or beyond +-{MAX_STIFFNESS:e} (SI)"),
                ));
            }
            out[i] = Some(si);
        }
    }
    Ok(out)
}

fn toml_curve(path: &Path, loc: &str, c: &TomlCurve) -> Result<(usize, Curve)> {
    let i = dof_index(&c.dof).ok_or_else(|| {
        Error::parse(
            path,
            loc,
            format!(
                "curve: unknown DoF '{}' (DoFs: {})",
                c.dof,
                DOF_NAMES.join(", ")
            ),
        )
    })?;
    let cl = format!("{loc} curve {}", c.dof);
    let need = |v: Option<f64>, key: &str| -> Result<f64> {
        v.ok_or_else(|| Error::parse(path, &cl, format!("a '{}' curve needs `{key}`", c.kind)))
    };
    // keys each kind takes (others are errors: they would be silently ignored)
    let given: Vec<&str> = [
        ("k", c.k.is_some()),
        ("c", c.c.is_some()),
        ("a", c.a.is_some()),
        ("k_neg", c.k_neg.is_some()),
        ("k_pos", c.k_pos.is_some()),
        ("x", c.x.is_some()),
        ("y", c.y.is_some()),
        ("interp", c.interp.is_some()),
        ("coefficients", c.coefficients.is_some()),
    ]
    .iter()
    .filter(|(_, g)| *g)
    .map(|(k, _)| *k)
    .collect();
    let allowed: &[&str] = match c.kind.as_str() {
        "linear" => &["k"],
        "cubic" => &["k", "c"],
        "sinh" => &["k", "a"],
        "bilinear" => &["k_neg", "k_pos"],
        "points" => &["x", "y", "interp"],
        "polynomial" => &["coefficients"],
        other => {
            return Err(Error::parse(
                path,
                &cl,
                format!("unknown curve kind '{other}' (kinds: linear, cubic, sinh, bilinear, points, polynomial)"),
            ))
        }
    };
    if let Some(extra) = given.iter().find(|k| !allowed.contains(k)) {
        return Err(Error::parse(
            path,
            &cl,
            format!(
                "`{extra}` does not belong to a '{}' curve (it takes {})",
                c.kind,
                allowed.join(", ")
            ),
        ));
    }
    let spec = match c.kind.as_str() {
        "linear" => Curve::Linear { k: need(c.k, "k")? },
        "cubic" => Curve::Cubic {
            k: need(c.k, "k")?,
            c: need(c.c, "c")?,
        },
        "sinh" => Curve::Sinh {
            k: need(c.k, "k")?,
            a: need(c.a, "a")?,
        },
        "bilinear" => Curve::Bilinear {
            k_neg: need(c.k_neg, "k_neg")?,
            k_pos: need(c.k_pos, "k_pos")?,
        },
        "points" => {
            let interp = match c.interp.as_deref() {
                None | Some("linear") => Interp::Linear,
                Some("spline") => Interp::Spline,
                Some(o) => {
                    return Err(Error::parse(
                        path,
                        &cl,
                        format!("interp '{o}' is not 'linear' or 'spline'"),
                    ))
                }
            };
            let (Some(x), Some(y)) = (&c.x, &c.y) else {
                return Err(Error::parse(
                    path,
                    &cl,
                    "a 'points' curve needs `x` and `y`",
                ));
            };
            points_curve(x.clone(), y.clone(), interp)
        }
        _ => Curve::Function(Function::Polynomial(c.coefficients.clone().ok_or_else(
            || Error::parse(path, &cl, "a 'polynomial' curve needs `coefficients`"),
        )?)),
    };
    Ok((i, spec))
}

fn toml_row(path: &Path, loc: String, r: &TomlRow, units: &Units) -> Result<Row> {
    let form = match &r.form {
        None => None,
        Some(f) => Some(Form::parse(f).ok_or_else(|| {
            Error::parse(
                path,
                &loc,
                format!("unknown form '{f}' (forms: linear, nonlinear, coupled, expression)"),
            )
        })?),
    };
    let mut row = Row {
        name: r.name.clone().unwrap_or_default(),
        location: loc.clone(),
        form,
        stiffness: dof_map(path, &loc, "stiffness", &r.stiffness, Some(&units.stiff))?,
        ratio: dof_map(path, &loc, "ratio", &r.ratio, None)?,
        damping: dof_map(path, &loc, "damping", &r.damping, Some(&units.damp))?,
        ..Row::default()
    };
    let non_si = |what: &str| -> Result<()> {
        if units.si {
            Ok(())
        } else {
            Err(Error::parse(
                path,
                &loc,
                format!("{what} must be given in SI units (N*m/rad, N/m, N*m*s/rad, N*s/m)"),
            ))
        }
    };
    for c in &r.curve {
        non_si("curves")?;
        let (i, spec) = toml_curve(path, &loc, c)?;
        if row.curves[i].is_some() {
            return Err(Error::parse(
                path,
                &loc,
                format!("two curves for DoF {}", DOF_NAMES[i]),
            ));
        }
        row.curves[i] = Some(spec);
    }
    if let Some(m) = &r.matrix {
        non_si("a coupled matrix")?;
        if m.len() != 6 || m.iter().any(|row| row.len() != 6) {
            return Err(Error::parse(
                path,
                &loc,
                "matrix must be 6 rows of 6 numbers (rx ry rz tx ty tz)",
            ));
        }
        let mut k = [[0.0; 6]; 6];
        for (i, rr) in m.iter().enumerate() {
            for (j, v) in rr.iter().enumerate() {
                if !v.is_finite() || v.abs() > MAX_STIFFNESS {
                    return Err(Error::parse(
                        path,
                        &loc,
                        format!("matrix[{i}][{j}] is not finite or beyond +-{MAX_STIFFNESS:e}"),
                    ));
                }
                k[i][j] = *v;
            }
        }
        row.matrix = Some(k);
    }
    if let Some(e) = &r.expressions {
        non_si("expressions")?;
        let mut out: [Option<String>; 6] = Default::default();
        for (k, v) in e {
            let i = dof_index(k).ok_or_else(|| {
                Error::parse(
                    path,
                    &loc,
                    format!(
                        "expressions: unknown DoF '{k}' (DoFs: {})",
                        DOF_NAMES.join(", ")
                    ),
                )
            })?;
            out[i] = Some(v.clone());
        }
        let mut all: [String; 6] = Default::default();
        for (i, o) in out.into_iter().enumerate() {
            all[i] = o.ok_or_else(|| {
                Error::parse(
                    path,
                    &loc,
                    format!("expressions: missing DoF {}", DOF_NAMES[i]),
                )
            })?;
        }
        row.expressions = Some(all);
    }
    Ok(row)
}

/// Parse a TOML table (`path` names it in messages).
pub fn parse_toml(text: &str, path: &Path) -> Result<Table> {
    let text = strip_bom(text);
    let f: TomlFile = toml::from_str(text)
        .map_err(|e| Error::parse(path, "TOML", e.to_string().trim_end().to_string()))?;
    if let Some(fmt) = &f.format {
        if fmt != FORMAT_TAG {
            return Err(Error::parse(
                path,
                "format",
                format!("unknown format '{fmt}' (expected \"{FORMAT_TAG}\")"),
            ));
        }
    }
    let Some(u) = &f.units else {
        return Err(Error::parse(
            path,
            "[units]",
            "missing the [units] header (rotational, translational, rot_damping, trans_damping)",
        ));
    };
    let r = unit_factor(path, "rotational", u.rotational.as_deref(), ROT_STIFF)?;
    let t = unit_factor(
        path,
        "translational",
        u.translational.as_deref(),
        TRANS_STIFF,
    )?;
    let rd = unit_factor(path, "rot_damping", u.rot_damping.as_deref(), ROT_DAMP)?;
    let td = unit_factor(
        path,
        "trans_damping",
        u.trans_damping.as_deref(),
        TRANS_DAMP,
    )?;
    let units = Units {
        stiff: [r, r, r, t, t, t],
        damp: [rd, rd, rd, td, td, td],
        si: r == 1.0 && t == 1.0 && rd == 1.0 && td == 1.0,
    };
    let all = match &f.all {
        None => None,
        Some(a) => {
            if a.name.is_some() {
                return Err(Error::parse(path, "[all]", "the [all] row takes no `name`"));
            }
            let mut row = toml_row(path, "[all]".into(), a, &units)?;
            row.name = "*".into();
            Some(row)
        }
    };
    let mut levels = Vec::with_capacity(f.level.len());
    for (i, l) in f.level.iter().enumerate() {
        let Some(name) = &l.name else {
            return Err(Error::parse(
                path,
                format!("[[level]] #{}", i + 1),
                "missing `name`",
            ));
        };
        let loc = format!("[[level]] #{} '{name}'", i + 1);
        levels.push(toml_row(path, loc, l, &units)?);
    }
    Ok(Table {
        path: path.to_path_buf(),
        all,
        levels,
    })
}

// ---------------------------------------------------------------- CSV

/// Parse a CSV table: a header row `level, <column> [<unit>], ...` with
/// stiffness columns `rx .. tz`, damping columns `c_rx .. c_tz` and ratio
/// columns `ratio_rx .. ratio_tz` (unit `1`), then one row per level (`*`:
/// every level). Empty cells are "not given". Linear form only.
pub fn parse_csv(text: &str, path: &Path) -> Result<Table> {
    let mut records = CsvReader::new(text, path).records();
    // The header row: what each column holds, in which unit.
    let Some(header) = records.next().transpose()? else {
        return Err(Error::parse(path, "line 1", "empty table (no header row)"));
    };
    let hline = header.line();
    let cols = csv_columns(&header, hline, path)?;
    // One row per level; the `*` row (at most one) is `[all]`.
    let mut all = None;
    let mut levels = Vec::new();
    for rec in records {
        let rec = rec?;
        rec.check_width(&header, path)?;
        let mut row = csv_row(&rec, rec.line(), &cols, path)?;
        if row.name == "*" {
            if all.is_some() {
                return Err(Error::parse(path, &row.location, "a second `*` row"));
            }
            row.form = None;
            all = Some(row);
        } else {
            levels.push(row);
        }
    }
    Ok(Table {
        path: path.to_path_buf(),
        all,
        levels,
    })
}

/// What a CSV column holds.
#[derive(Debug, Clone, Copy)]
enum CsvKind {
    Stiffness,
    Damping,
    Ratio,
}

/// A value column of a CSV table: kind, DoF and factor to SI.
type CsvColumn = (CsvKind, usize, f64);

/// The columns of the header row at line `hline` (`None` for `level`):
/// known names, each once, with an accepted unit.
fn csv_columns(header: &CsvRecord, hline: u64, path: &Path) -> Result<Vec<Option<CsvColumn>>> {
    let mut cols: Vec<Option<CsvColumn>> = Vec::new();
    let mut seen = std::collections::BTreeSet::new();
    for (ci, h) in header.cells().enumerate() {
        let loc = format!("line {hline}, column {}", ci + 1);
        if ci == 0 {
            if h != "level" {
                return Err(Error::parse(
                    path,
                    loc,
                    format!("first column must be `level`, found '{h}'"),
                ));
            }
            cols.push(None);
            continue;
        }
        let (name, unit) = match (h.find('['), h.ends_with(']')) {
            (Some(o), true) => (h[..o].trim(), Some(h[o + 1..h.len() - 1].trim())),
            _ => (h.trim(), None),
        };
        let (kind, dof) = if let Some(d) = name.strip_prefix("c_") {
            (CsvKind::Damping, d)
        } else if let Some(d) = name.strip_prefix("ratio_") {
            (CsvKind::Ratio, d)
        } else {
            (CsvKind::Stiffness, name)
        };
        let i = dof_index(dof).ok_or_else(|| {
            Error::parse(
                path,
                &loc,
                format!(
                    "unknown column '{name}' (columns: rx..tz, c_rx..c_tz, ratio_rx..ratio_tz)"
                ),
            )
        })?;
        if !seen.insert(name.to_string()) {
            return Err(Error::parse(
                path,
                &loc,
                format!("column '{name}' given twice"),
            ));
        }
        let Some(unit) = unit else {
            return Err(Error::parse(
                path,
                &loc,
                format!("column '{name}' has no unit: write it as `{name} [unit]`"),
            ));
        };
        let factor = csv_unit_factor(kind, i, name, unit, &loc, path)?;
        cols.push(Some((kind, i, factor)));
    }
    Ok(cols)
}

/// Factor to SI of column `name` (kind `kind`, DoF `i`) in `unit`.
fn csv_unit_factor(
    kind: CsvKind,
    i: usize,
    name: &str,
    unit: &str,
    loc: &str,
    path: &Path,
) -> Result<f64> {
    let (table, accepted) = match kind {
        CsvKind::Ratio => {
            if unit != "1" {
                return Err(Error::parse(
                    path,
                    loc,
                    format!("ratio column '{name}' must have unit [1]"),
                ));
            }
            return Ok(1.0);
        }
        CsvKind::Damping if i < 3 => (ROT_DAMP, "N*m*s/rad, N*m*s/deg"),
        CsvKind::Damping => (TRANS_DAMP, "N*s/m, N*s/mm"),
        CsvKind::Stiffness if i < 3 => (ROT_STIFF, "N*m/rad, N*m/deg"),
        CsvKind::Stiffness => (TRANS_STIFF, "N/m, N/mm"),
    };
    unit_factor(path, name, Some(unit), table).map_err(|_| {
        Error::parse(
            path,
            loc,
            format!("column '{name}': unit [{unit}] is not accepted (accepted: {accepted})"),
        )
    })
}

/// The level row of record `rec` at `line`: its name and the non-empty
/// cells of the value columns, converted to SI.
fn csv_row(rec: &CsvRecord, line: u64, cols: &[Option<CsvColumn>], path: &Path) -> Result<Row> {
    let name = rec.cell(0).to_string();
    if name.is_empty() {
        return Err(Error::parse(
            path,
            format!("line {line}"),
            "empty level name",
        ));
    }
    let loc = format!("line {line} '{name}'");
    let mut row = Row {
        name,
        location: loc.clone(),
        form: Some(Form::Linear),
        ..Row::default()
    };
    for (ci, cell) in rec.cells().enumerate().skip(1) {
        let Some(Some((kind, i, f))) = cols.get(ci) else {
            continue;
        };
        if cell.is_empty() {
            continue;
        }
        let v: f64 = cell.parse().map_err(|_| {
            Error::parse(
                path,
                &loc,
                format!("column {}: '{cell}' is not a number", ci + 1),
            )
        })?;
        if !v.is_finite() || v.abs() > MAX_STIFFNESS {
            return Err(Error::parse(
                path,
                &loc,
                format!(
                    "column {}: not finite or beyond +-{MAX_STIFFNESS:e}",
                    ci + 1
                ),
            ));
        }
        match kind {
            CsvKind::Stiffness => row.stiffness[*i] = Some(v * f),
            CsvKind::Damping => row.damping[*i] = Some(v * f),
            CsvKind::Ratio => row.ratio[*i] = Some(v),
        }
    }
    Ok(row)
}

/// Read a table file: `.csv` as CSV, anything else as TOML.
pub fn read_table(path: &Path) -> Result<Table> {
    let text = crate::util::read_text_capped(
        path,
        crate::util::input::MAX_TABLE_BYTES,
        "stiffness tables",
    )?;
    if is_csv(path) {
        parse_csv(&text, path)
    } else {
        parse_toml(&text, path)
    }
}

/// Whether a path names a CSV table (by extension).
pub fn is_csv(path: &Path) -> bool {
    path.extension()
        .map(|e| e.eq_ignore_ascii_case("csv"))
        .unwrap_or(false)
}

// ---------------------------------------------------------------- writers

/// The `format` tag of TOML tables.
const FORMAT_TAG: &str = "osim-spine stiffness table 1";

/// A number as TOML/CSV text: shortest round-trip form, always a float literal.
pub fn num(x: f64) -> String {
    if x == 0.0 {
        return "0.0".into();
    }
    format!("{x:?}")
}

fn dof_line(key: &str, v: &[f64; 6]) -> String {
    let parts: Vec<String> = DOF_NAMES
        .iter()
        .zip(v)
        .map(|(d, x)| format!("{d} = {}", num(*x)))
        .collect();
    format!("{key} = {{ {} }}\n", parts.join(", "))
}

fn toml_str(s: &str) -> String {
    // basic TOML string with escapes
    let mut o = String::from("\"");
    for ch in s.chars() {
        match ch {
            '"' => o.push_str("\\\""),
            '\\' => o.push_str("\\\\"),
            '\n' => o.push_str("\\n"),
            '\t' => o.push_str("\\t"),
            c if (c as u32) < 0x20 => o.push_str(&format!("\\u{:04X}", c as u32)),
            c => o.push(c),
        }
    }
    o.push('"');
    o
}

fn nums(v: &[f64]) -> String {
    format!(
        "[{}]",
        v.iter().map(|x| num(*x)).collect::<Vec<_>>().join(", ")
    )
}

/// Write per-level laws as a TOML table (SI units), in the given order.
pub fn write_toml(model_name: &str, levels: &[(String, LevelLaw)]) -> String {
    let rows: Vec<(String, LevelLaw, Option<[f64; 6]>)> = levels
        .iter()
        .map(|(n, l)| (n.clone(), l.clone(), None))
        .collect();
    toml_text(
        &[format!(
            "Stiffness table listed by osim-spine from {model_name}"
        )],
        &rows,
    )
}

/// Write per-level laws as a TOML table whose linear levels carry a ratio:
/// the table gives `stiffness` (the law's) times `ratio` (written for the
/// DoFs whose ratio is not 1; the `base x ratio` form of
/// `docs/stiffness-table.md`). `comments` become the leading `#` lines.
pub fn write_toml_ratios(comments: &[String], levels: &[(String, LevelLaw, [f64; 6])]) -> String {
    let rows: Vec<(String, LevelLaw, Option<[f64; 6]>)> = levels
        .iter()
        .map(|(n, l, r)| (n.clone(), l.clone(), Some(*r)))
        .collect();
    toml_text(comments, &rows)
}

/// The `ratio = { .. }` line of the DoFs whose ratio is not 1 (empty when all are).
fn ratio_line(r: &[f64; 6]) -> String {
    let parts: Vec<String> = DOF_NAMES
        .iter()
        .zip(r)
        .filter(|(_, x)| **x != 1.0)
        .map(|(d, x)| format!("{d} = {}", num(*x)))
        .collect();
    if parts.is_empty() {
        String::new()
    } else {
        format!("ratio = {{ {} }}\n", parts.join(", "))
    }
}

fn toml_text(comments: &[String], levels: &[(String, LevelLaw, Option<[f64; 6]>)]) -> String {
    let mut s = String::new();
    for c in comments {
        s.push_str(&format!("# {}\n", c.replace('\n', " ")));
    }
    s.push_str(&format!("format = {}\n\n", toml_str(FORMAT_TAG)));
    s.push_str("[units]\nrotational = \"N*m/rad\"\ntranslational = \"N/m\"\nrot_damping = \"N*m*s/rad\"\ntrans_damping = \"N*s/m\"\n");
    for (name, law, ratio) in levels {
        s.push_str("\n[[level]]\n");
        s.push_str(&format!("name = {}\n", toml_str(name)));
        s.push_str(&format!("form = \"{}\"\n", law.form().name()));
        match law {
            LevelLaw::Linear { k, c } => {
                s.push_str(&dof_line("stiffness", k));
                if let Some(r) = ratio {
                    s.push_str(&ratio_line(r));
                }
                s.push_str(&dof_line("damping", c));
            }
            LevelLaw::Coupled { k, c } => {
                s.push_str("matrix = [\n");
                for r in k {
                    s.push_str(&format!("  {},\n", nums(r)));
                }
                s.push_str("]\n");
                s.push_str(&dof_line("damping", c));
            }
            LevelLaw::Expression { exprs, c } => {
                let parts: Vec<String> = DOF_NAMES
                    .iter()
                    .zip(exprs.iter())
                    .map(|(d, e)| format!("{d} = {}", toml_str(e)))
                    .collect();
                s.push_str(&format!("expressions = {{ {} }}\n", parts.join(", ")));
                s.push_str(&dof_line("damping", c));
            }
            LevelLaw::Nonlinear { curves, c } => {
                s.push_str(&dof_line("damping", c));
                for (d, cv) in DOF_NAMES.iter().zip(curves.iter()) {
                    s.push_str("[[level.curve]]\n");
                    s.push_str(&format!("dof = \"{d}\"\n"));
                    match cv {
                        Curve::Linear { k } => {
                            s.push_str(&format!("kind = \"linear\"\nk = {}\n", num(*k)))
                        }
                        Curve::Cubic { k, c } => s.push_str(&format!(
                            "kind = \"cubic\"\nk = {}\nc = {}\n",
                            num(*k),
                            num(*c)
                        )),
                        Curve::Sinh { k, a } => s.push_str(&format!(
                            "kind = \"sinh\"\nk = {}\na = {}\n",
                            num(*k),
                            num(*a)
                        )),
                        Curve::Bilinear { k_neg, k_pos } => s.push_str(&format!(
                            "kind = \"bilinear\"\nk_neg = {}\nk_pos = {}\n",
                            num(*k_neg),
                            num(*k_pos)
                        )),
                        Curve::Function(Function::Polynomial(coefficients)) => {
                            s.push_str(&format!(
                                "kind = \"polynomial\"\ncoefficients = {}\n",
                                nums(coefficients)
                            ))
                        }
                        Curve::Function(f) => match curve_points(cv) {
                            Some((x, y, interp)) => s.push_str(&format!(
                                "kind = \"points\"\ninterp = \"{}\"\nx = {}\ny = {}\n",
                                match interp {
                                    Interp::Linear => "linear",
                                    Interp::Spline => "spline",
                                },
                                nums(x),
                                nums(y)
                            )),
                            // not reached: models' and tables' curves are stated by a kind
                            None => s.push_str(&format!("# not a curve a table states: {f:?}\n")),
                        },
                    }
                }
            }
        }
    }
    s
}

/// Write linear laws as a CSV table (SI units). Errors when a level is not linear.
pub fn write_csv(levels: &[(String, LevelLaw)]) -> Result<String> {
    let mut s = String::from("level");
    for d in DOF_NAMES {
        let u = if d.starts_with('r') { "N*m/rad" } else { "N/m" };
        s.push_str(&format!(",{d} [{u}]"));
    }
    for d in DOF_NAMES {
        let u = if d.starts_with('r') {
            "N*m*s/rad"
        } else {
            "N*s/m"
        };
        s.push_str(&format!(",c_{d} [{u}]"));
    }
    s.push('\n');
    for (name, law) in levels {
        let LevelLaw::Linear { k, c } = law else {
            return Err(Error::invalid(
                format!("level '{name}'"),
                format!(
                    "its bushing has the {} form, which CSV tables cannot hold: list as TOML",
                    law.form().name()
                ),
            ));
        };
        if name.contains([',', '"', '\n', '#']) || name == "*" {
            return Err(Error::invalid(
                format!("level '{name}'"),
                "this level name cannot be written to a CSV table: list as TOML",
            ));
        }
        s.push_str(name);
        for v in k.iter().chain(c.iter()) {
            s.push(',');
            s.push_str(&num(*v));
        }
        s.push('\n');
    }
    Ok(s)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbers_are_toml_floats_and_round_trip() {
        for x in [291.0, 68.8, 1e20, 1e-7, -3.5, 0.0, 2.3] {
            let t = num(x);
            let v: toml::Table = toml::from_str(&format!("v = {t}")).unwrap();
            assert_eq!(v["v"].as_float().unwrap(), x, "{t}");
        }
    }

    #[test]
    fn csv_with_bom_and_comments_names_the_right_line() {
        let head = "level,rx [N*m/rad],tx [N/mm]\n";
        let t = format!("\u{feff}# thesis Table 5.1\n{head}# lumbar\nL5_S1,68.8,149\n");
        let tab = parse_csv(&t, Path::new("t.csv")).unwrap();
        assert_eq!(tab.levels[0].name, "L5_S1");
        assert_eq!(tab.levels[0].stiffness[3], Some(149000.0));
        // line 5 of the file, after two comment lines
        let bad = format!("# a\n{head}# b\nL5_S1,68.8,149\nL4_L5,x,149\n");
        let e = parse_csv(&bad, Path::new("t.csv")).unwrap_err().to_string();
        assert!(e.contains("line 5"), "{e}");
        // CRLF, a blank line, a quoted cell: `"68,8"` is one cell (not a
        // fourth column), refused as a number on its own line
        let crlf =
            format!("\u{feff}# a\r\n{head}\r\n\"L4_L5\",\"68,8\",149\r\n").replace("]\n", "]\r\n");
        let e = parse_csv(&crlf, Path::new("t.csv"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("t.csv: line 4 'L4_L5': column 2: '68,8' is not a number"),
            "{e}"
        );
        // a row of another width than the header names its line
        let e = parse_csv(
            &format!("{head}L5_S1,68.8,149\nL4_L5,1\n"),
            Path::new("t.csv"),
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("t.csv: line 3: 2 cells, but the header row (line 1) has 3"),
            "{e}"
        );
    }

    #[test]
    fn units_convert_to_si() {
        let t = "[units]\nrotational = \"N*m/deg\"\ntranslational = \"N/mm\"\nrot_damping = \"N*m*s/rad\"\ntrans_damping = \"N*s/m\"\n[[level]]\nname = \"A\"\nstiffness = { rx = 1.0, tx = 2 }\n";
        let tab = parse_toml(t, Path::new("t.toml")).unwrap();
        let r = &tab.levels[0];
        assert!((r.stiffness[0].unwrap() - 180.0 / std::f64::consts::PI).abs() < 1e-12);
        assert_eq!(r.stiffness[3], Some(2000.0));
    }

    #[test]
    fn missing_and_unknown_units_are_rejected() {
        let e = parse_toml("[[level]]\nname = \"A\"\n", Path::new("t.toml")).unwrap_err();
        assert!(e.to_string().contains("[units]"), "{e}");
        let e = parse_toml(
            "[units]\nrotational = \"N*m/rad\"\ntranslational = \"lbf/in\"\nrot_damping = \"N*m*s/rad\"\ntrans_damping = \"N*s/m\"\n",
            Path::new("t.toml"),
        )
        .unwrap_err();
        assert!(e.to_string().contains("lbf/in"), "{e}");
        let e = parse_csv("level,rx\nA,1\n", Path::new("t.csv")).unwrap_err();
        assert!(e.to_string().contains("no unit"), "{e}");
    }
}
