//! Parametric model families: a parameter vector (positive values, fitted
//! on a log scale within bounds) mapped onto a solver [`System`] — modified
//! force laws and/or joint frames — with the derivative of the static
//! residual with respect to the parameters.
//!
//! [`ModelFamily`] is the reusable abstraction (calibration uses it for the
//! stiffness parameterisations; `diagnose` extends it with candidate
//! effects). [`StiffnessFamily`] implements the linear-bushing
//! parameterisations of the thesis: one value per DoF shared by all levels
//! (uniform), a base value times fixed level ratios (ratio), and
//! independent per-level values (per-level).

use crate::calibrate::experiment::DOF_NAMES;
use crate::error::{Error, Result};
use crate::solver::{System, Workspace};
use nalgebra::DMatrix;
use serde::Serialize;
use std::collections::BTreeMap;

/// One parameter of a family.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ParamInfo {
    /// Unique name, e.g. `rx` (uniform), `rx_base` (ratio), `L4_L5.rz` (per level).
    pub name: String,
    /// Unit of the value, e.g. `N*m/rad`.
    pub unit: String,
    /// Lower bound (> 0).
    pub lower: f64,
    /// Upper bound.
    pub upper: f64,
    /// Value of the nominal model (may lie outside the bounds).
    pub nominal: f64,
}

/// A family of models indexed by a positive parameter vector.
pub trait ModelFamily: Send + Sync {
    /// A short description (e.g. `uniform`, `per-level`).
    fn label(&self) -> String;
    /// The parameters, in vector order.
    fn params(&self) -> &[ParamInfo];
    /// Put parameter values `p` (natural units) into `sys`. Must be cheap
    /// (called at every residual evaluation) and must not depend on
    /// anything `apply` changed before (the same `p` gives the same system).
    fn apply(&self, p: &[f64], sys: &mut System) -> Result<()>;
    /// `d tau / d p` at `q` (`n_dofs x n_params`), `sys` having `p` applied.
    /// The default is central finite differences through `apply` (exact
    /// families override it); `sys` is restored before returning.
    fn dtau_dp(
        &self,
        p: &[f64],
        sys: &mut System,
        q: &[f64],
        loads: &crate::solver::LoadSet,
        ws: &mut Workspace,
        out: &mut DMatrix<f64>,
    ) -> Result<()> {
        let mut pp = p.to_vec();
        for j in 0..p.len() {
            let h = 1e-6 * p[j].abs().max(1e-12);
            pp[j] = p[j] + h;
            self.apply(&pp, sys)?;
            let plus = sys.static_residual(q, loads, ws)?.to_vec();
            pp[j] = p[j] - h;
            self.apply(&pp, sys)?;
            let minus = sys.static_residual(q, loads, ws)?;
            for (i, (a, b)) in plus.iter().zip(minus).enumerate() {
                out[(i, j)] = (a - b) / (2.0 * h);
            }
            pp[j] = p[j];
        }
        self.apply(p, sys)
    }
}

/// Literature bounds of thesis Table 3.3 (rotations N*m/rad about X, Y, Z;
/// translations N/m along X, Y, Z), deflection order rx..tz.
pub const LITERATURE_BOUNDS: [(f64, f64); 6] = [
    (9.0, 249.0),             // right-left (lateral) bending
    (43.0, 1250.0),           // axial rotation
    (12.0, 750.0),            // flexion-extension
    (31_600.0, 857_000.0),    // anterior-posterior translation
    (108_000.0, 3_330_000.0), // inferior-superior translation
    (53_000.0, 584_000.0),    // right-left translation
];

/// Unit of stiffness DoF `d`.
pub fn stiffness_unit(d: usize) -> &'static str {
    if d < 3 {
        "N*m/rad"
    } else {
        "N/m"
    }
}

/// An intervertebral level: a linear bushing between an adjacent pair.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Level {
    /// Level name: the bushing name without a `_bushing` suffix (e.g. `L4_L5`).
    pub name: String,
    /// Bushing index in the system.
    pub bushing: usize,
    /// Cranial body (system index).
    pub upper: usize,
    /// Caudal body (system index).
    pub lower: usize,
    /// Names of the two bodies.
    pub upper_name: String,
    pub lower_name: String,
}

/// Normalised level key for matching tables: upper case, no `_`/`-`/space
/// (`T12_L1`, `t12l1` and `T12-L1` all match).
pub fn level_key(name: &str) -> String {
    name.chars()
        .filter(|c| !matches!(c, '_' | '-' | ' '))
        .flat_map(|c| c.to_uppercase())
        .collect()
}

/// The levels of `sys` on the paths between `fixed` and each of `loaded`
/// (system body indices), cranial to caudal order of the bushing list.
/// A level is a bushing whose two bodies are a parent-child pair of the tree.
pub fn find_levels(sys: &System, fixed: usize, loaded: &[usize]) -> Vec<Level> {
    let mut on_path = vec![false; sys.n_bodies()];
    for &b in loaded {
        // bodies from b up to (excluding) the common ancestor with fixed
        let mut up_fixed = Vec::new();
        let mut cur = Some(fixed);
        while let Some(c) = cur {
            up_fixed.push(c);
            cur = sys.parent_of(c);
        }
        let mut cur = Some(b);
        while let Some(c) = cur {
            if up_fixed.contains(&c) {
                for &f in &up_fixed {
                    if f == c {
                        break;
                    }
                    on_path[f] = true;
                }
                on_path[c] = true;
                break;
            }
            on_path[c] = true;
            cur = sys.parent_of(c);
        }
    }
    let names: Vec<&str> = sys.body_names().collect();
    let mut out = Vec::new();
    for (i, bname) in sys.bushing_names().enumerate() {
        let Some((Some(b1), Some(b2))) = sys.bushing_bodies(i) else {
            continue;
        };
        let (upper, lower) = if sys.parent_of(b2) == Some(b1) {
            (b2, b1)
        } else if sys.parent_of(b1) == Some(b2) {
            (b1, b2)
        } else {
            continue;
        };
        if !(on_path[upper] && on_path[lower]) {
            continue;
        }
        let name = bname.strip_suffix("_bushing").unwrap_or(bname).to_string();
        out.push(Level {
            name,
            bushing: i,
            upper,
            lower,
            upper_name: names.get(upper).copied().unwrap_or("").to_string(),
            lower_name: names.get(lower).copied().unwrap_or("").to_string(),
        });
    }
    out
}

/// How stiffness values are tied to parameters.
#[derive(Debug, Clone, PartialEq)]
pub enum Parameterisation {
    /// One value per DoF for all levels.
    Uniform,
    /// A base value per DoF times a fixed ratio per level and DoF (keys are
    /// [`level_key`]s; values any positive scale, only ratios matter).
    Ratio(BTreeMap<String, [Option<f64>; 6]>),
    /// Independent values per level and DoF.
    PerLevel,
}

/// Linear-bushing stiffness parameterisations over a set of levels.
#[derive(Debug, Clone)]
pub struct StiffnessFamily {
    label: String,
    params: Vec<ParamInfo>,
    /// Nominal diagonal stiffness of every bushing of the system (NaN for non-linear laws).
    nominal: Vec<[f64; 6]>,
    /// First column of each bushing in `System::dtau_dstiffness`, and the total.
    col_offset: Vec<usize>,
    n_cols: usize,
    /// Per parameter: (bushing, dof, factor) with `k = factor * p`.
    map: Vec<Vec<(usize, usize, f64)>>,
    /// The levels the family acts on.
    pub levels: Vec<Level>,
    /// The stiffness DoFs that are parameters.
    pub dofs: Vec<usize>,
}

fn geomean(v: &[f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    (v.iter().map(|x| x.ln()).sum::<f64>() / v.len() as f64).exp()
}

impl StiffnessFamily {
    /// Build over `levels` of `sys` for the stiffness DoFs `dofs` (0..6).
    /// Bounds are the literature ranges ([`LITERATURE_BOUNDS`]).
    pub fn new(
        sys: &System,
        levels: Vec<Level>,
        dofs: &[usize],
        kind: &Parameterisation,
    ) -> Result<StiffnessFamily> {
        if levels.is_empty() {
            return Err(Error::invalid(
                "calibration",
                "no intervertebral level (a BushingForce between an adjacent pair of bodies) lies between the fixed body and the loaded bodies",
            ));
        }
        // nominal diagonal stiffness of every bushing (non-linear laws: none),
        // and each bushing's first column in `System::dtau_dstiffness`
        let mut nominal = Vec::new();
        let mut linear = Vec::new();
        let mut col_offset = Vec::new();
        let mut col = 0;
        for i in 0..sys.bushing_names().count() {
            let Some(m) = sys.bushing_model(i) else {
                continue;
            };
            let p = m.stiffness_params();
            col_offset.push(col);
            col += p.len();
            let is_linear = matches!(m, crate::solver::BushingModel::Linear { .. });
            linear.push(is_linear);
            nominal.push(if is_linear {
                std::array::from_fn(|d| p.get(d).copied().unwrap_or(0.0))
            } else {
                [f64::NAN; 6]
            });
        }
        for l in &levels {
            if !linear.get(l.bushing).copied().unwrap_or(false) {
                return Err(Error::invalid(
                    format!("level {}", l.name),
                    "its bushing is not a linear BushingForce: calibration parameterises linear stiffness only (non-linear and coupled forms are not calibrated yet)",
                ));
            }
        }
        for l in &levels {
            let k = nominal.get(l.bushing).copied().unwrap_or([0.0; 6]);
            for &d in dofs {
                if k[d].is_nan() || k[d] <= 0.0 {
                    return Err(Error::invalid(
                        format!("level {}", l.name),
                        format!(
                            "nominal {} stiffness is {} {}: a calibrated stiffness must start from a positive value",
                            DOF_NAMES[d], k[d], stiffness_unit(d)
                        ),
                    ));
                }
            }
        }
        let mut params = Vec::new();
        let mut map = Vec::new();
        let label;
        match kind {
            Parameterisation::Uniform => {
                label = "uniform".to_string();
                for &d in dofs {
                    let vals: Vec<f64> = levels.iter().map(|l| nominal[l.bushing][d]).collect();
                    params.push(ParamInfo {
                        name: DOF_NAMES[d].to_string(),
                        unit: stiffness_unit(d).into(),
                        lower: LITERATURE_BOUNDS[d].0,
                        upper: LITERATURE_BOUNDS[d].1,
                        nominal: geomean(&vals),
                    });
                    map.push(levels.iter().map(|l| (l.bushing, d, 1.0)).collect());
                }
            }
            Parameterisation::Ratio(table) => {
                label = "ratio".to_string();
                for &d in dofs {
                    let mut raw = Vec::new();
                    for l in &levels {
                        let Some(row) = table.get(&level_key(&l.name)) else {
                            return Err(Error::invalid(
                                "ratio table",
                                format!(
                                    "no row for level '{}' (table levels: {})",
                                    l.name,
                                    table.keys().cloned().collect::<Vec<_>>().join(", ")
                                ),
                            ));
                        };
                        let Some(v) = row[d] else {
                            return Err(Error::invalid(
                                "ratio table",
                                format!("level '{}' has no {} value", l.name, DOF_NAMES[d]),
                            ));
                        };
                        if !(v > 0.0 && v.is_finite()) {
                            return Err(Error::invalid(
                                "ratio table",
                                format!(
                                    "level '{}' {}: ratio must be positive, got {v}",
                                    l.name, DOF_NAMES[d]
                                ),
                            ));
                        }
                        raw.push(v);
                    }
                    let g = geomean(&raw);
                    let factors: Vec<f64> = raw.iter().map(|v| v / g).collect();
                    let base: Vec<f64> = levels
                        .iter()
                        .zip(&factors)
                        .map(|(l, f)| nominal[l.bushing][d] / f)
                        .collect();
                    params.push(ParamInfo {
                        name: format!("{}_base", DOF_NAMES[d]),
                        unit: stiffness_unit(d).into(),
                        lower: LITERATURE_BOUNDS[d].0,
                        upper: LITERATURE_BOUNDS[d].1,
                        nominal: geomean(&base),
                    });
                    map.push(
                        levels
                            .iter()
                            .zip(&factors)
                            .map(|(l, f)| (l.bushing, d, *f))
                            .collect(),
                    );
                }
            }
            Parameterisation::PerLevel => {
                label = "per-level".to_string();
                for l in &levels {
                    for &d in dofs {
                        params.push(ParamInfo {
                            name: format!("{}.{}", l.name, DOF_NAMES[d]),
                            unit: stiffness_unit(d).into(),
                            lower: LITERATURE_BOUNDS[d].0,
                            upper: LITERATURE_BOUNDS[d].1,
                            nominal: nominal[l.bushing][d],
                        });
                        map.push(vec![(l.bushing, d, 1.0)]);
                    }
                }
            }
        }
        Ok(StiffnessFamily {
            label,
            params,
            nominal,
            col_offset,
            n_cols: col,
            map,
            levels,
            dofs: dofs.to_vec(),
        })
    }

    /// Diagonal stiffness of every bushing for parameters `p`.
    pub fn bushing_stiffness(&self, p: &[f64]) -> Vec<[f64; 6]> {
        let mut k = self.nominal.clone();
        for (j, entries) in self.map.iter().enumerate() {
            let v = p.get(j).copied().unwrap_or(f64::NAN);
            for &(b, d, f) in entries {
                if let Some(kb) = k.get_mut(b) {
                    kb[d] = f * v;
                }
            }
        }
        k
    }

    /// The family's label (`uniform`, `ratio`, `per-level`).
    pub fn label_str(&self) -> &str {
        &self.label
    }

    /// The parameters (same as [`ModelFamily::params`]).
    pub fn params_info(&self) -> &[ParamInfo] {
        &self.params
    }

    /// Nominal parameter values.
    pub fn params_nominal(&self) -> Vec<f64> {
        self.params.iter().map(|p| p.nominal).collect()
    }

    /// Override the bounds of parameters on stiffness DoF `d`.
    pub fn set_bounds(&mut self, d: usize, lower: f64, upper: f64) {
        for (j, entries) in self.map.iter().enumerate() {
            if entries.first().map(|e| e.1) == Some(d) {
                self.params[j].lower = lower;
                self.params[j].upper = upper;
            }
        }
    }
}

impl ModelFamily for StiffnessFamily {
    fn label(&self) -> String {
        self.label.clone()
    }
    fn params(&self) -> &[ParamInfo] {
        &self.params
    }
    fn apply(&self, p: &[f64], sys: &mut System) -> Result<()> {
        if p.len() != self.params.len() {
            return Err(Error::invalid(
                "calibration",
                format!("expected {} parameters, got {}", self.params.len(), p.len()),
            ));
        }
        let k = self.bushing_stiffness(p);
        let mut touched: Vec<usize> = self.map.iter().flatten().map(|e| e.0).collect();
        touched.sort_unstable();
        touched.dedup();
        for b in touched {
            if let Some(kb) = k.get(b) {
                sys.set_bushing_stiffness(b, *kb)?;
            }
        }
        Ok(())
    }
    /// Exact: the residual is linear in every stiffness (through the
    /// deflection), so `d tau / d p_j = sum factor * d tau / d k`.
    fn dtau_dp(
        &self,
        _p: &[f64],
        sys: &mut System,
        q: &[f64],
        _loads: &crate::solver::LoadSet,
        ws: &mut Workspace,
        out: &mut DMatrix<f64>,
    ) -> Result<()> {
        let mut dk = DMatrix::zeros(sys.n_dofs(), self.n_cols);
        sys.dtau_dstiffness(q, ws, &mut dk)?;
        out.fill(0.0);
        for (j, entries) in self.map.iter().enumerate() {
            for &(b, d, f) in entries {
                let col = self.col_offset.get(b).copied().unwrap_or(0) + d;
                for i in 0..sys.n_dofs() {
                    out[(i, j)] += f * dk[(i, col)];
                }
            }
        }
        Ok(())
    }
}

/// A level-ratio table: [`level_key`] -> values per DoF (rx..tz).
pub type RatioTable = BTreeMap<String, [Option<f64>; 6]>;

#[derive(Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct RatioLevelToml {
    name: String,
    rx: Option<f64>,
    ry: Option<f64>,
    rz: Option<f64>,
    tx: Option<f64>,
    ty: Option<f64>,
    tz: Option<f64>,
}

#[derive(Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct RatioToml {
    #[serde(default)]
    #[allow(dead_code)]
    source: Option<String>,
    #[serde(default)]
    #[allow(dead_code)]
    unit: Option<String>,
    level: Vec<RatioLevelToml>,
}

/// Read a level-ratio table: TOML (`[[level]]` tables with `name` and any of
/// `rx .. tz`) or CSV with a header `level,rx,ry,rz[,tx,ty,tz]`. Values must
/// be positive; levels must be unique.
pub fn read_ratio_table(path: &std::path::Path) -> Result<RatioTable> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    let mut out = RatioTable::new();
    let mut put = |name: &str, vals: [Option<f64>; 6], at: String| -> Result<()> {
        for (d, v) in vals.iter().enumerate() {
            if let Some(v) = v {
                if !(v.is_finite() && *v > 0.0) {
                    return Err(Error::parse(
                        path,
                        at.clone(),
                        format!(
                            "{} of level '{name}' must be a positive number, got {v}",
                            DOF_NAMES[d]
                        ),
                    ));
                }
            }
        }
        if out.insert(level_key(name), vals).is_some() {
            return Err(Error::parse(
                path,
                at,
                format!("level '{name}' appears twice"),
            ));
        }
        Ok(())
    };
    let is_toml = path
        .extension()
        .map(|e| e.eq_ignore_ascii_case("toml"))
        .unwrap_or(false);
    if is_toml {
        let t: RatioToml = toml::from_str(&text).map_err(|e| {
            let location = match e.span() {
                Some(s) => format!(
                    "line {}",
                    text[..s.start.min(text.len())].lines().count().max(1)
                ),
                None => "file".to_string(),
            };
            Error::parse(path, location, e.message().to_string())
        })?;
        for (i, l) in t.level.iter().enumerate() {
            put(
                &l.name,
                [l.rx, l.ry, l.rz, l.tx, l.ty, l.tz],
                format!("[[level]] #{}", i + 1),
            )?;
        }
    } else {
        let mut rdr = csv::ReaderBuilder::new()
            .trim(csv::Trim::All)
            .from_reader(text.as_bytes());
        let headers = rdr
            .headers()
            .map_err(|e| Error::parse(path, "line 1", e.to_string()))?
            .clone();
        let col = |n: &str| headers.iter().position(|h| h == n);
        let Some(lc) = col("level") else {
            return Err(Error::parse(
                path,
                "line 1",
                "missing column 'level' (expected level,rx,ry,rz)",
            ));
        };
        let cols: Vec<Option<usize>> = DOF_NAMES.iter().map(|d| col(d)).collect();
        if cols.iter().all(|c| c.is_none()) {
            return Err(Error::parse(
                path,
                "line 1",
                "no DoF column (rx, ry, rz, tx, ty, tz)",
            ));
        }
        for rec in rdr.records() {
            let rec = rec.map_err(|e| Error::parse(path, "file", e.to_string()))?;
            let line = rec.position().map(|p| p.line()).unwrap_or(0);
            let at = format!("line {line}");
            let name = rec.get(lc).unwrap_or("").to_string();
            let mut vals = [None; 6];
            for (d, c) in cols.iter().enumerate() {
                let Some(c) = c else { continue };
                let s = rec.get(*c).unwrap_or("");
                if s.is_empty() {
                    continue;
                }
                vals[d] = Some(s.parse::<f64>().map_err(|_| {
                    Error::parse(
                        path,
                        at.clone(),
                        format!("column {}: '{s}' is not a number", DOF_NAMES[d]),
                    )
                })?);
            }
            put(&name, vals, at)?;
        }
    }
    if out.is_empty() {
        return Err(Error::parse(path, "file", "no level in the ratio table"));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Regression: the fast-path bushing reads rx, rz wrapped into
    /// (-pi, pi]; d tau / d k must use the same angles, or a Newton solution
    /// 2 pi away (same pose) gives a wrong Jacobian.
    #[test]
    fn dtau_dp_is_the_same_for_coordinates_two_pi_apart() {
        let p = std::path::Path::new("../shared/diagnose-dev/dev-07");
        if !p.exists() {
            eprintln!("SKIP: ../shared/diagnose-dev not found");
            return;
        }
        let exp = crate::calibrate::experiment::Experiment::read(p).unwrap();
        let mut sys = System::new(&exp.spec).unwrap();
        let fixed = sys.body_index("sacrum").unwrap();
        let top = sys.body_index("thoracic12").unwrap();
        let levels = find_levels(&sys, fixed, &[top]);
        let fam =
            StiffnessFamily::new(&sys, levels, &[0, 1, 2], &Parameterisation::PerLevel).unwrap();
        let pv = fam.params_nominal();
        fam.apply(&pv, &mut sys).unwrap();
        let mut ws = Workspace::new(&sys);
        let mut q: Vec<f64> = (0..sys.n_dofs())
            .map(|i| 0.01 * (i as f64 % 5.0 - 2.0))
            .collect();
        let loads = crate::solver::LoadSet::empty();
        let mut a = DMatrix::zeros(sys.n_dofs(), pv.len());
        fam.dtau_dp(&pv, &mut sys, &q, &loads, &mut ws, &mut a)
            .unwrap();
        let rz = sys.dof_of("L3_L4_rz").unwrap();
        q[rz] += 2.0 * std::f64::consts::PI;
        let mut b = DMatrix::zeros(sys.n_dofs(), pv.len());
        fam.dtau_dp(&pv, &mut sys, &q, &loads, &mut ws, &mut b)
            .unwrap();
        assert!((&a - &b).amax() < 1e-12, "{}", (&a - &b).amax());
    }

    #[test]
    fn reads_the_shipped_zhang_template_and_csv() {
        let t =
            read_ratio_table(std::path::Path::new("templates/level_ratios_zhang.toml")).unwrap();
        assert_eq!(t.len(), 6);
        assert_eq!(t["T12L1"][0], Some(36.4));
        assert_eq!(t["L5S1"][2], Some(51.0));
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("r.csv");
        std::fs::write(&p, "level,rx,ry,rz\nL4_L5,1,2,3\nL5-S1,2,,4\n").unwrap();
        let t = read_ratio_table(&p).unwrap();
        assert_eq!(t["L5S1"], [Some(2.0), None, Some(4.0), None, None, None]);
        std::fs::write(&p, "level,rx\nL4_L5,-1\n").unwrap();
        let e = read_ratio_table(&p).unwrap_err().to_string();
        assert!(e.contains("line 2") && e.contains("positive"), "{e}");
        std::fs::write(&p, "level,rx\nL4_L5,1\nl4l5,2\n").unwrap();
        assert!(read_ratio_table(&p)
            .unwrap_err()
            .to_string()
            .contains("twice"));
    }
}
