//! Intervertebral stiffness: tables (uniform, per level, base x ratio),
//! forms (linear, non-linear per DoF, coupled 6x6, expressions) and their
//! writing into / reading from .osim models (`osim-spine stiffness`).
//!
//! | file | what lives there |
//! |---|---|
//! | `table` | the TOML/CSV table formats: [`Table`] (read, units to SI) and the `--list` writers |
//! | `mod` (here) | levels of a model ([`levels`]), reading a bushing's law ([`read_law`]), merging a table with a model and validating ([`resolve`]), writing laws into the document ([`apply`]) |
//!
//! **Levels.** Every BushingForce, FunctionBasedBushingForce and
//! ExpressionBasedBushingForce of the ForceSet is a level. Its name is the
//! bushing's name without a trailing `_bushing` (`L5_S1_bushing` -> `L5_S1`,
//! `sacrum_L5_bushing` -> `sacrum_L5`), else the bushing's name. A table row
//! may also name a level by its anatomical alias `<upper>_<lower>` built from
//! the two bodies the bushing connects (`sacrum`/`sacrumv`/`S1` -> `S1`,
//! `lumbarN`/`LN` -> `LN`, `thoracicN`/`thoracicN_s`/`TN` -> `TN`,
//! `cervicalN`/`CN` -> `CN`; the cranial one first): `L5_S1`, `T12_L1`.
//!
//! **What is written** (see `docs/stiffness-table.md`):
//! linear -> `BushingForce`; nonlinear -> `FunctionBasedBushingForce`
//! (linear: LinearFunction `k 0`; cubic: PolynomialFunction `c 0 k 0`;
//! bilinear: PiecewiseLinearFunction through (-1, -k_neg), (0, 0), (1, k_pos);
//! points: PiecewiseLinearFunction or SimmSpline; polynomial:
//! PolynomialFunction), or `ExpressionBasedBushingForce` when a curve is a
//! sinh (`k*a*sinh(theta_x/a)`, with linear `k*theta_x`, cubic
//! `k*theta_x+c*theta_x^3`, bilinear `k_neg*min(theta_x,0)+k_pos*max(theta_x,0)`
//! for the other DoFs); coupled -> `ExpressionBasedBushingForce` whose
//! expression `i` is `sum_j K_ij * var_j`; expression -> the six strings.
//! A bushing whose law does not change is left untouched (byte for byte).

pub mod table;

pub use table::{curve_points, points_curve, read_table, Form, Interp, LevelLaw, Row, Table};

use crate::anatomy::{bushing_level_name, BushingLevel};
use crate::error::{Error, Result};
use crate::osim::function::{CubicSpline, Function as OFunction};
use crate::osim::model::{Force, Model};
use crate::osim::props::fmt_numbers;
use crate::osim::xml::{Element, Node};
use crate::osim::Document;
use crate::solver::expr::{Expr, Fn1, Fn2, Op, VARIABLES};
use crate::solver::from_model::{EBBF_EXPRESSIONS, FBBF_FUNCTIONS};
use crate::solver::spec::DOF_NAMES;
use crate::solver::Curve;
use crate::util::fmt_f64;
use std::path::Path;

/// Region rank and number of a vertebral body name (`lumbar5` -> (2, 5)).
fn vertebra(body: &str) -> Option<(u8, u32, String)> {
    let b = body.to_ascii_lowercase();
    if b == "sacrum" || b == "sacrumv" || b == "s1" {
        return Some((3, 1, "S1".into()));
    }
    let b = b.strip_suffix("_s").unwrap_or(&b);
    for (prefixes, rank, letter) in [
        (&["cervical", "c"][..], 0u8, 'C'),
        (&["thoracic", "t"][..], 1, 'T'),
        (&["lumbar", "l"][..], 2, 'L'),
    ] {
        for p in prefixes {
            if let Some(n) = b.strip_prefix(p) {
                if !n.is_empty() && n.len() <= 2 && n.chars().all(|c| c.is_ascii_digit()) {
                    let n: u32 = n.parse().ok()?;
                    return Some((rank, n, format!("{letter}{n}")));
                }
            }
        }
    }
    None
}

/// Anatomical alias `<upper>_<lower>` of a level, when both bodies have
/// vertebral names (cervical ones too: `C7_T1`).
pub fn alias(l: &BushingLevel) -> Option<String> {
    let (r1, n1, s1) = vertebra(&l.upper_body)?;
    let (r2, n2, s2) = vertebra(&l.lower_body)?;
    if (r1, n1) == (r2, n2) {
        return None;
    }
    Some(if (r1, n1) < (r2, n2) {
        format!("{s1}_{s2}")
    } else {
        format!("{s2}_{s1}")
    })
}

/// The levels of a model (one per bushing of its ForceSet), in ForceSet order.
pub fn levels(doc: &Document) -> Result<Vec<BushingLevel>> {
    let model = doc.model()?;
    levels_of(&model)
}

/// The bodies of socket frames 1 and 2, cranial first: by their vertebral
/// names when both have one, else socket 2's (a bushing's frame 1 is on
/// the parent, the caudal body, in the models this tool writes).
fn cranial_first(b1: String, b2: String) -> (String, String) {
    match (vertebra(&b1), vertebra(&b2)) {
        (Some((r1, n1, _)), Some((r2, n2, _))) if (r1, n1) < (r2, n2) => (b1, b2),
        _ => (b2, b1),
    }
}

fn levels_of(model: &Model) -> Result<Vec<BushingLevel>> {
    let mut out: Vec<BushingLevel> = Vec::new();
    for f in &model.forces {
        let (name, s1, s2) = match f {
            Force::Bushing(b) => (&b.name, &b.socket_frame1, &b.socket_frame2),
            Force::OtherBushing(b) => (&b.name, &b.socket_frame1, &b.socket_frame2),
            _ => continue,
        };
        let owner = format!("/forceset/{name}");
        let (b1, _) = model.resolve_frame(&owner, s1)?;
        let (b2, _) = model.resolve_frame(&owner, s2)?;
        let lname = bushing_level_name(name);
        if let Some(o) = out.iter().find(|l| l.name == lname) {
            return Err(Error::invalid(
                model.file.display().to_string(),
                format!(
                    "bushings '{}' and '{name}' have the same level name '{lname}'",
                    o.bushing
                ),
            ));
        }
        let (upper, lower) = cranial_first(b1, b2);
        out.push(BushingLevel::new(name, &upper, &lower));
    }
    Ok(out)
}

// ------------------------------------------------------------ reading laws

fn numbers(e: &Element, prop: &str, n: usize, file: &Path, default: f64) -> Result<Vec<f64>> {
    match e.child_text(prop) {
        None => Ok(vec![default; n]),
        Some(t) => {
            let v: Vec<f64> = t
                .split_whitespace()
                .map(|w| w.parse::<f64>())
                .collect::<std::result::Result<_, _>>()
                .map_err(|_| {
                    Error::parse(
                        file,
                        crate::osim::props::loc(e),
                        format!("<{prop}> is not a list of numbers"),
                    )
                })?;
            if v.len() != n || !v.iter().all(|x| x.is_finite()) {
                return Err(Error::parse(
                    file,
                    crate::osim::props::loc(e),
                    format!("<{prop}> must hold {n} finite numbers"),
                ));
            }
            Ok(v)
        }
    }
}

fn damping_of(e: &Element, file: &Path) -> Result<[f64; 6]> {
    let r = numbers(e, "rotational_damping", 3, file, 0.0)?;
    let t = numbers(e, "translational_damping", 3, file, 0.0)?;
    Ok([r[0], r[1], r[2], t[0], t[1], t[2]])
}

fn curve_of_function(f: &OFunction) -> Option<Curve> {
    Some(match f {
        OFunction::Linear { slope, intercept } if *intercept == 0.0 => Curve::Linear { k: *slope },
        OFunction::Linear { slope, intercept } => {
            Curve::Function(OFunction::Polynomial(vec![*slope, *intercept]))
        }
        OFunction::Constant(c) => Curve::Function(OFunction::Polynomial(vec![*c])),
        OFunction::Polynomial(c) => match c.as_slice() {
            [c3, z2, k, z0] if *z2 == 0.0 && *z0 == 0.0 => Curve::Cubic { k: *k, c: *c3 },
            _ => Curve::Function(OFunction::Polynomial(c.clone())),
        },
        OFunction::PiecewiseLinear { x, y } => {
            if x.as_slice() == [-1.0, 0.0, 1.0] && y.len() == 3 && y[1] == 0.0 {
                Curve::Bilinear {
                    k_neg: -y[0],
                    k_pos: y[2],
                }
            } else {
                points_curve(x.clone(), y.clone(), Interp::Linear)
            }
        }
        OFunction::Spline { spline, .. } => {
            points_curve(spline.x.clone(), spline.y.clone(), Interp::Spline)
        }
        _ => return None,
    })
}

fn num_of(e: &Expr) -> Option<f64> {
    match e {
        Expr::Num(v) => Some(*v),
        Expr::Neg(a) => num_of(a).map(|v| -v),
        _ => None,
    }
}

/// `k*v` -> (k, var)
fn scaled_var(e: &Expr) -> Option<(f64, usize)> {
    match e {
        Expr::Bin(Op::Mul, a, b) => match (num_of(a), b.as_ref()) {
            (Some(k), Expr::Var(i)) => Some((k, *i)),
            _ => None,
        },
        _ => None,
    }
}

/// Recognise the per-DoF expression patterns this module writes.
fn curve_of_expr(e: &Expr, dof: usize) -> Option<Curve> {
    if let Some((k, i)) = scaled_var(e) {
        return (i == dof).then_some(Curve::Linear { k });
    }
    match e {
        // k*a*sinh(v/a)
        Expr::Bin(Op::Mul, ka, s) => {
            let Expr::Bin(Op::Mul, k, a) = ka.as_ref() else {
                return None;
            };
            let Expr::Call1(Fn1::Sinh, arg) = s.as_ref() else {
                return None;
            };
            let Expr::Bin(Op::Div, v, a2) = arg.as_ref() else {
                return None;
            };
            let (k, a, a2) = (num_of(k)?, num_of(a)?, num_of(a2)?);
            (matches!(v.as_ref(), Expr::Var(i) if *i == dof) && a.to_bits() == a2.to_bits())
                .then_some(Curve::Sinh { k, a })
        }
        Expr::Bin(Op::Add, l, r) => {
            // k*v + c*v^3
            if let (Some((k, i)), Expr::Bin(Op::Mul, c, p)) = (scaled_var(l), r.as_ref()) {
                let c = num_of(c)?;
                let Expr::Bin(Op::Pow, v, n) = p.as_ref() else {
                    return None;
                };
                return (i == dof
                    && matches!(v.as_ref(), Expr::Var(j) if *j == dof)
                    && num_of(n) == Some(3.0))
                .then_some(Curve::Cubic { k, c });
            }
            // k_neg*min(v,0) + k_pos*max(v,0)
            let (Expr::Bin(Op::Mul, kn, mn), Expr::Bin(Op::Mul, kp, mx)) = (l.as_ref(), r.as_ref())
            else {
                return None;
            };
            let (Expr::Call2(Fn2::Min, v1, z1), Expr::Call2(Fn2::Max, v2, z2)) =
                (mn.as_ref(), mx.as_ref())
            else {
                return None;
            };
            let ok = matches!(v1.as_ref(), Expr::Var(i) if *i == dof)
                && matches!(v2.as_ref(), Expr::Var(i) if *i == dof)
                && num_of(z1) == Some(0.0)
                && num_of(z2) == Some(0.0);
            ok.then_some(Curve::Bilinear {
                k_neg: num_of(kn)?,
                k_pos: num_of(kp)?,
            })
        }
        _ => None,
    }
}

/// The law of a bushing element (BushingForce, FunctionBasedBushingForce,
/// ExpressionBasedBushingForce) as a table would state it.
pub fn read_law(e: &Element, file: &Path) -> Result<LevelLaw> {
    let here = || format!("{}: {}", file.display(), crate::osim::props::loc(e));
    match e.name.as_str() {
        "BushingForce" => {
            let r = numbers(e, "rotational_stiffness", 3, file, 0.0)?;
            let t = numbers(e, "translational_stiffness", 3, file, 0.0)?;
            Ok(LevelLaw::Linear {
                k: [r[0], r[1], r[2], t[0], t[1], t[2]],
                c: damping_of(e, file)?,
            })
        }
        "FunctionBasedBushingForce" => {
            let mut curves: Vec<Curve> = Vec::with_capacity(6);
            for prop in FBBF_FUNCTIONS {
                let f = match e.child(prop) {
                    Some(p) => OFunction::from_parent(p, file)?,
                    None => OFunction::Constant(0.0),
                };
                curves.push(curve_of_function(&f).ok_or_else(|| {
                    Error::invalid(
                        here(),
                        format!("<{prop}> holds a function a stiffness table cannot state ({f:?})"),
                    )
                })?);
            }
            let curves: [Curve; 6] = curves
                .try_into()
                .map_err(|_| Error::invalid(here(), "six functions expected"))?;
            Ok(LevelLaw::Nonlinear {
                curves: Box::new(curves),
                c: damping_of(e, file)?,
            })
        }
        "ExpressionBasedBushingForce" => {
            let mut texts: Vec<String> = Vec::with_capacity(6);
            let mut exprs: Vec<Expr> = Vec::with_capacity(6);
            for prop in EBBF_EXPRESSIONS {
                let t = e.child_text(prop).unwrap_or_else(|| "0.0".into());
                let x = Expr::parse(&t)
                    .map_err(|m| Error::invalid(here(), format!("<{prop}> '{t}': {m}")))?;
                texts.push(t);
                exprs.push(x);
            }
            let c = damping_of(e, file)?;
            if let Some(rows) = exprs
                .iter()
                .map(|x| x.linear_coefficients())
                .collect::<Option<Vec<_>>>()
            {
                let mut k = [[0.0; 6]; 6];
                for (i, r) in rows.iter().enumerate() {
                    k[i] = *r;
                }
                return Ok(LevelLaw::Coupled { k, c });
            }
            let curves: Option<Vec<Curve>> = exprs
                .iter()
                .enumerate()
                .map(|(i, x)| curve_of_expr(x, i))
                .collect();
            if let Some(cv) = curves {
                if let Ok(arr) = <[Curve; 6]>::try_from(cv) {
                    return Ok(LevelLaw::Nonlinear {
                        curves: Box::new(arr),
                        c,
                    });
                }
            }
            let arr: [String; 6] = texts
                .try_into()
                .map_err(|_| Error::invalid(here(), "six expressions expected"))?;
            Ok(LevelLaw::Expression {
                exprs: Box::new(arr),
                c,
            })
        }
        other => Err(Error::invalid(
            here(),
            format!("{other} is not a bushing class"),
        )),
    }
}

/// Every level of the model with its current law (`--list`).
pub fn list(doc: &Document) -> Result<Vec<(String, LevelLaw)>> {
    let lv = levels(doc)?;
    let mut out = Vec::with_capacity(lv.len());
    for l in &lv {
        let e = doc.component("ForceSet", &l.bushing).ok_or_else(|| {
            Error::invalid(
                doc.path().display().to_string(),
                format!("bushing '{}' not found", l.bushing),
            )
        })?;
        out.push((l.name.clone(), read_law(e, doc.path())?));
    }
    Ok(out)
}

// ------------------------------------------------------------ resolving

/// Sample points for monotonicity checks of polynomial and spline curves:
/// +-1 rad for rotations, +-0.1 m for translations.
fn check_range(dof: usize) -> f64 {
    if dof < 3 {
        1.0
    } else {
        0.1
    }
}

fn validate_curve(c: &Curve, dof: usize, allow_softening: bool, ctx: &str) -> Result<()> {
    let bad = |m: String| Error::invalid(ctx, m);
    let d = DOF_NAMES[dof];
    let pos = |v: f64, what: &str| -> Result<()> {
        if v > 0.0 && v.is_finite() {
            Ok(())
        } else {
            Err(bad(format!("curve {d}: {what} must be positive, got {v}")))
        }
    };
    match c {
        Curve::Linear { k } => pos(*k, "k"),
        Curve::Cubic { k, c } => {
            pos(*k, "k")?;
            if !c.is_finite() {
                return Err(bad(format!("curve {d}: c is not finite")));
            }
            if *c < 0.0 && !allow_softening {
                return Err(bad(format!(
                    "curve {d}: c = {c} < 0 makes k x + c x^3 soften and turn down beyond |x| = {:.4}; pass --allow-softening to accept it",
                    (k / (-3.0 * c)).sqrt()
                )));
            }
            Ok(())
        }
        Curve::Sinh { k, a } => {
            pos(*k, "k")?;
            pos(*a, "a")
        }
        Curve::Bilinear { k_neg, k_pos } => {
            pos(*k_neg, "k_neg")?;
            pos(*k_pos, "k_pos")
        }
        Curve::Function(OFunction::Polynomial(coefficients)) => {
            validate_polynomial(coefficients, dof, allow_softening, ctx)
        }
        Curve::Function(f) => {
            let Some((x, y, interp)) = curve_points(c) else {
                return Err(bad(format!(
                    "curve {d}: not a curve a stiffness table states ({f:?})"
                )));
            };
            if x.len() != y.len() || x.len() < 2 {
                return Err(bad(format!(
                    "curve {d}: points need x and y of the same length, at least 2"
                )));
            }
            if !x.iter().chain(y.iter()).all(|v| v.is_finite()) {
                return Err(bad(format!("curve {d}: points must be finite")));
            }
            if let Some(w) = x.windows(2).position(|w| w[1] <= w[0]) {
                return Err(bad(format!(
                    "curve {d}: x must be strictly increasing (x[{}] = {} >= x[{}] = {})",
                    w,
                    x[w],
                    w + 1,
                    x[w + 1]
                )));
            }
            if !allow_softening {
                if let Some(w) = y.windows(2).position(|w| w[1] <= w[0]) {
                    return Err(bad(format!(
                        "curve {d}: y must increase with x (y[{}] = {} >= y[{}] = {}); pass --allow-softening to accept a non-monotone curve",
                        w, y[w], w + 1, y[w + 1]
                    )));
                }
                if interp == Interp::Spline {
                    let s = CubicSpline::new(x.to_vec(), y.to_vec());
                    let (lo, hi) = (x[0], x[x.len() - 1]);
                    for i in 0..=1000 {
                        let t = lo + (hi - lo) * i as f64 / 1000.0;
                        if s.eval_order(t, 1) <= 0.0 {
                            return Err(bad(format!("curve {d}: the spline through the points is not increasing near x = {t} (overshoot); add points or use interp = \"linear\", or pass --allow-softening")));
                        }
                    }
                }
            }
            Ok(())
        }
    }
}

/// Check a polynomial curve of DoF `dof`: finite coefficients, increasing
/// on the DoF's range unless `allow_softening`.
fn validate_polynomial(
    coefficients: &[f64],
    dof: usize,
    allow_softening: bool,
    ctx: &str,
) -> Result<()> {
    let d = DOF_NAMES[dof];
    let bad = |m: String| Error::invalid(ctx, m);
    if coefficients.is_empty() || !coefficients.iter().all(|v| v.is_finite()) {
        return Err(bad(format!(
            "curve {d}: coefficients must be finite, at least one"
        )));
    }
    if !allow_softening {
        let f = OFunction::Polynomial(coefficients.to_vec());
        let r = check_range(dof);
        for i in 0..=1000 {
            let t = -r + 2.0 * r * i as f64 / 1000.0;
            if f.d1(t) <= 0.0 {
                return Err(bad(format!("curve {d}: the polynomial is not increasing at x = {t} (checked on +-{r}); pass --allow-softening to accept it")));
            }
        }
    }
    Ok(())
}

/// Check a law: positive stiffness and ratios, non-negative damping,
/// monotone curves (unless `allow_softening`), symmetric positive-definite
/// coupled matrices, expressions that parse.
fn validate_law(law: &LevelLaw, allow_softening: bool, ctx: &str) -> Result<()> {
    let bad = |m: String| Error::invalid(ctx, m);
    for (i, c) in law.damping().iter().enumerate() {
        if !(c.is_finite() && *c >= 0.0) {
            return Err(bad(format!(
                "damping {} must be >= 0, got {c}",
                DOF_NAMES[i]
            )));
        }
    }
    match law {
        LevelLaw::Linear { k, .. } => {
            for (i, v) in k.iter().enumerate() {
                if !(v.is_finite() && *v > 0.0) {
                    return Err(bad(format!(
                        "stiffness {} must be positive, got {v}",
                        DOF_NAMES[i]
                    )));
                }
            }
        }
        LevelLaw::Nonlinear { curves, .. } => {
            for (i, c) in curves.iter().enumerate() {
                validate_curve(c, i, allow_softening, ctx)?;
            }
            let has_sinh = curves.iter().any(|c| matches!(c, Curve::Sinh { .. }));
            if has_sinh {
                if let Some(i) = curves.iter().position(|c| matches!(c, Curve::Function(_))) {
                    return Err(bad(format!(
                        "curve {}: a bushing with a sinh curve is written as an ExpressionBasedBushingForce, which cannot hold points or polynomial curves; use linear, cubic, sinh or bilinear curves in this level",
                        DOF_NAMES[i]
                    )));
                }
            }
        }
        LevelLaw::Coupled { k, .. } => {
            let m = nalgebra::Matrix6::from_fn(|i, j| k[i][j]);
            let scale = m.iter().fold(0.0f64, |a, v| a.max(v.abs()));
            for i in 0..6 {
                for j in 0..i {
                    if (m[(i, j)] - m[(j, i)]).abs() > 1e-12 * scale {
                        return Err(bad(format!(
                            "matrix is not symmetric: K[{}][{}] = {} but K[{}][{}] = {}",
                            DOF_NAMES[i],
                            DOF_NAMES[j],
                            m[(i, j)],
                            DOF_NAMES[j],
                            DOF_NAMES[i],
                            m[(j, i)]
                        )));
                    }
                }
            }
            if m.cholesky().is_none() {
                let eig = m.symmetric_eigenvalues();
                let min = eig.iter().fold(f64::INFINITY, |a, v| a.min(*v));
                return Err(bad(format!(
                    "matrix is not positive definite (smallest eigenvalue {min:.6e})"
                )));
            }
        }
        LevelLaw::Expression { exprs, .. } => {
            for (i, e) in exprs.iter().enumerate() {
                Expr::parse(e)
                    .map_err(|m| bad(format!("expression {}: '{e}': {m}", DOF_NAMES[i])))?;
            }
        }
    }
    Ok(())
}

/// A row's value for DoF `i` of a field, falling back to `[all]`.
fn pick<T: Clone>(
    row: Option<&Row>,
    all: Option<&Row>,
    f: impl Fn(&Row) -> Option<T>,
) -> Option<T> {
    row.and_then(&f).or_else(|| all.and_then(&f))
}

/// Merge a table with a model: for every level that a row (or `[all]`)
/// applies to, the new law, validated. Levels without a row (and no
/// `[all]`) are not returned. Errors name the table row.
pub fn resolve(
    table: &Table,
    doc: &Document,
    allow_softening: bool,
) -> Result<Vec<(BushingLevel, LevelLaw)>> {
    let lv = levels(doc)?;
    let tpath = table.path.display().to_string();
    // Each row names one level of the model, and no level twice.
    let row_of = match_rows(table, &lv, doc, &tpath)?;
    let all = table.all.as_ref();
    let mut out = Vec::new();
    for (li, l) in lv.iter().enumerate() {
        let row = row_of[li].map(|r| &table.levels[r]);
        if row.is_none() && all.is_none() {
            continue;
        }
        let loc = format!(
            "{tpath}: {}",
            row.map(|r| r.location.clone())
                .unwrap_or_else(|| "[all]".into())
        );
        let ctx = format!("{loc} (level '{}')", l.name);
        // The bushing's current law fills what the table leaves out.
        let e = doc
            .component("ForceSet", &l.bushing)
            .ok_or_else(|| Error::invalid(&ctx, format!("bushing '{}' not found", l.bushing)))?;
        let current = read_law(e, doc.path()).ok();
        // The new law of the row's form (`[all]` and the current law as fallbacks).
        let form = pick(row, all, |r| r.form).unwrap_or(Form::Linear);
        let law = level_law(form, row, all, current.as_ref(), &ctx)?;
        // Values that the form does not use are mistakes, not silently ignored.
        if row.is_some_and(|r| gives_unused_values(r, form)) {
            return Err(Error::invalid(
                &ctx,
                format!("the row gives values the {} form does not use", form.name()),
            ));
        }
        validate_law(&law, allow_softening, &ctx)?;
        out.push((l.clone(), law));
    }
    Ok(out)
}

/// For each level of `lv`, the index of the table row that names it (by
/// name or alias). A row naming no level, several levels, or a level
/// already named is an error.
fn match_rows(
    table: &Table,
    lv: &[BushingLevel],
    doc: &Document,
    tpath: &str,
) -> Result<Vec<Option<usize>>> {
    let mut row_of: Vec<Option<usize>> = vec![None; lv.len()];
    for (ri, r) in table.levels.iter().enumerate() {
        let hits: Vec<usize> = lv
            .iter()
            .enumerate()
            .filter(|(_, l)| l.name == r.name || alias(l).as_deref() == Some(r.name.as_str()))
            .map(|(i, _)| i)
            .collect();
        match hits.as_slice() {
            [] => {
                let names: Vec<String> = lv
                    .iter()
                    .map(|l| match alias(l) {
                        Some(a) if a != l.name => format!("{} ({a})", l.name),
                        _ => l.name.clone(),
                    })
                    .collect();
                return Err(Error::invalid(
                    format!("{tpath}: {}", r.location),
                    format!(
                        "unknown level '{}' (levels of {}: {})",
                        r.name,
                        doc.path().display(),
                        names.join(", ")
                    ),
                ));
            }
            [i] => {
                if let Some(prev) = row_of[*i] {
                    return Err(Error::invalid(
                        format!("{tpath}: {}", r.location),
                        format!(
                            "level '{}' is already set by {}",
                            lv[*i].name, table.levels[prev].location
                        ),
                    ));
                }
                row_of[*i] = Some(ri);
            }
            many => {
                let names: Vec<&str> = many.iter().map(|i| lv[*i].name.as_str()).collect();
                return Err(Error::invalid(
                    format!("{tpath}: {}", r.location),
                    format!(
                        "'{}' names several levels ({}); use the level names",
                        r.name,
                        names.join(", ")
                    ),
                ));
            }
        }
    }
    Ok(row_of)
}

/// The law of `form` for one level from its row, `[all]` and the current
/// law (damping and linear stiffness default to the current values; ratios
/// apply to the linear form only). `ctx` names the row in errors.
fn level_law(
    form: Form,
    row: Option<&Row>,
    all: Option<&Row>,
    current: Option<&LevelLaw>,
    ctx: &str,
) -> Result<LevelLaw> {
    let mut c = [0.0; 6];
    for (i, ci) in c.iter_mut().enumerate() {
        *ci = match pick(row, all, |r| r.damping[i]) {
            Some(v) => v,
            None => match current {
                Some(cur) => cur.damping()[i],
                None => {
                    return Err(Error::invalid(
                        ctx,
                        format!("no damping for {}", DOF_NAMES[i]),
                    ))
                }
            },
        };
    }
    let ratio: [f64; 6] = std::array::from_fn(|i| pick(row, all, |r| r.ratio[i]).unwrap_or(1.0));
    if form != Form::Linear {
        if let Some(i) = (0..6).find(|&i| pick(row, all, |r| r.ratio[i]).is_some()) {
            return Err(Error::invalid(
                ctx,
                format!("ratio {} applies to the linear form only", DOF_NAMES[i]),
            ));
        }
    }
    for (i, r) in ratio.iter().enumerate() {
        if !(*r > 0.0 && r.is_finite()) {
            return Err(Error::invalid(
                ctx,
                format!("ratio {} must be positive, got {r}", DOF_NAMES[i]),
            ));
        }
    }
    Ok(match form {
        Form::Linear => LevelLaw::Linear {
            k: linear_stiffness(row, all, current, &ratio, ctx)?,
            c,
        },
        Form::Nonlinear => LevelLaw::Nonlinear {
            curves: Box::new(curves(row, all, ctx)?),
            c,
        },
        Form::Coupled => {
            let k = pick(row, all, |r| r.matrix)
                .ok_or_else(|| Error::invalid(ctx, "the coupled form needs `matrix`"))?;
            LevelLaw::Coupled { k, c }
        }
        Form::Expression => {
            let e = pick(row, all, |r| r.expressions.clone())
                .ok_or_else(|| Error::invalid(ctx, "the expression form needs `expressions`"))?;
            LevelLaw::Expression {
                exprs: Box::new(e),
                c,
            }
        }
    })
}

/// Linear stiffness per DoF: the table's (or the current linear law's)
/// value times the ratio.
fn linear_stiffness(
    row: Option<&Row>,
    all: Option<&Row>,
    current: Option<&LevelLaw>,
    ratio: &[f64; 6],
    ctx: &str,
) -> Result<[f64; 6]> {
    let mut k = [0.0; 6];
    for i in 0..6 {
        let base = match pick(row, all, |r| r.stiffness[i]) {
            Some(v) => v,
            None => match current {
                Some(LevelLaw::Linear { k, .. }) => k[i],
                _ => {
                    return Err(Error::invalid(
                        ctx,
                        format!(
                            "no stiffness for {} (give it in the row or in [all])",
                            DOF_NAMES[i]
                        ),
                    ))
                }
            },
        };
        k[i] = base * ratio[i];
    }
    Ok(k)
}

/// One curve per DoF: the table's curve, else its linear stiffness.
fn curves(row: Option<&Row>, all: Option<&Row>, ctx: &str) -> Result<[Curve; 6]> {
    let mut curves: Vec<Curve> = Vec::with_capacity(6);
    for i in 0..6 {
        let cv = match pick(row, all, |r| r.curves[i].clone()) {
            Some(cv) => cv,
            None => match pick(row, all, |r| r.stiffness[i]) {
                Some(k) => Curve::Linear { k },
                None => {
                    return Err(Error::invalid(
                        ctx,
                        format!("no curve and no stiffness for {}", DOF_NAMES[i]),
                    ))
                }
            },
        };
        curves.push(cv);
    }
    curves
        .try_into()
        .map_err(|_| Error::invalid(ctx, "six curves expected"))
}

/// Whether row `r` gives values that `form` does not use.
fn gives_unused_values(r: &Row, form: Form) -> bool {
    match form {
        Form::Linear => {
            r.curves.iter().any(|c| c.is_some()) || r.matrix.is_some() || r.expressions.is_some()
        }
        Form::Nonlinear => r.matrix.is_some() || r.expressions.is_some(),
        Form::Coupled => {
            r.curves.iter().any(|c| c.is_some())
                || r.stiffness.iter().any(|c| c.is_some())
                || r.expressions.is_some()
        }
        Form::Expression => {
            r.curves.iter().any(|c| c.is_some())
                || r.stiffness.iter().any(|c| c.is_some())
                || r.matrix.is_some()
        }
    }
}

// ------------------------------------------------------------ writing

fn expr_num(x: f64) -> String {
    if x < 0.0 {
        format!("({})", fmt_f64(x))
    } else {
        fmt_f64(x)
    }
}

fn curve_expr(c: &Curve, dof: usize) -> Option<String> {
    let v = VARIABLES[dof];
    Some(match c {
        Curve::Linear { k } => format!("{}*{v}", expr_num(*k)),
        Curve::Cubic { k, c } => format!("{}*{v}+{}*{v}^3", expr_num(*k), expr_num(*c)),
        Curve::Sinh { k, a } => format!(
            "{}*{}*sinh({v}/{})",
            expr_num(*k),
            expr_num(*a),
            expr_num(*a)
        ),
        Curve::Bilinear { k_neg, k_pos } => {
            format!(
                "{}*min({v},0)+{}*max({v},0)",
                expr_num(*k_neg),
                expr_num(*k_pos)
            )
        }
        _ => return None,
    })
}

fn coupled_expr(row: &[f64; 6]) -> String {
    let terms: Vec<String> = row
        .iter()
        .enumerate()
        .filter(|(_, k)| **k != 0.0)
        .map(|(j, k)| format!("{}*{}", expr_num(*k), VARIABLES[j]))
        .collect();
    if terms.is_empty() {
        "0".into()
    } else {
        terms.join("+")
    }
}

/// The OpenSim function element of curve `c` of DoF `dof`.
fn function_element(c: &Curve, dof: usize) -> Result<Element> {
    Ok(match c {
        Curve::Linear { k } => {
            Element::new("LinearFunction").with_prop("coefficients", fmt_numbers(&[*k, 0.0]))
        }
        Curve::Cubic { k, c } => Element::new("PolynomialFunction")
            .with_prop("coefficients", fmt_numbers(&[*c, 0.0, *k, 0.0])),
        Curve::Bilinear { k_neg, k_pos } => Element::new("PiecewiseLinearFunction")
            .with_prop("x", fmt_numbers(&[-1.0, 0.0, 1.0]))
            .with_prop("y", fmt_numbers(&[-k_neg, 0.0, *k_pos])),
        Curve::Function(OFunction::Polynomial(coefficients)) => {
            Element::new("PolynomialFunction").with_prop("coefficients", fmt_numbers(coefficients))
        }
        Curve::Function(f) => {
            let Some((x, y, interp)) = curve_points(c) else {
                return Err(Error::invalid(
                    "stiffness writer",
                    format!(
                        "curve {}: not a curve a stiffness table states ({f:?})",
                        DOF_NAMES[dof]
                    ),
                ));
            };
            Element::new(match interp {
                Interp::Linear => "PiecewiseLinearFunction",
                Interp::Spline => "SimmSpline",
            })
            .with_prop("x", fmt_numbers(x))
            .with_prop("y", fmt_numbers(y))
        }
        // not reached: sinh laws are written as expressions
        Curve::Sinh { k, .. } => {
            Element::new("LinearFunction").with_prop("coefficients", fmt_numbers(&[*k, 0.0]))
        }
    })
}

/// The OpenSim class a law is written as.
fn class_of(law: &LevelLaw) -> &'static str {
    match law {
        LevelLaw::Linear { .. } => "BushingForce",
        LevelLaw::Nonlinear { curves, .. } => {
            if curves.iter().any(|c| matches!(c, Curve::Sinh { .. })) {
                "ExpressionBasedBushingForce"
            } else {
                "FunctionBasedBushingForce"
            }
        }
        LevelLaw::Coupled { .. } | LevelLaw::Expression { .. } => "ExpressionBasedBushingForce",
    }
}

/// The law's properties, in the order OpenSim writes them.
fn law_props(law: &LevelLaw) -> Result<Vec<Element>> {
    let c = law.damping();
    let damping = [
        Element::new("rotational_damping").with_text(fmt_numbers(&c[..3])),
        Element::new("translational_damping").with_text(fmt_numbers(&c[3..])),
    ];
    let mut out = Vec::new();
    match law {
        LevelLaw::Linear { k, .. } => {
            out.push(Element::new("rotational_stiffness").with_text(fmt_numbers(&k[..3])));
            out.push(Element::new("translational_stiffness").with_text(fmt_numbers(&k[3..])));
        }
        LevelLaw::Nonlinear { curves, .. } if class_of(law) == "FunctionBasedBushingForce" => {
            for (i, (prop, cv)) in FBBF_FUNCTIONS.iter().zip(curves.iter()).enumerate() {
                out.push(Element::new(*prop).with_child(function_element(cv, i)?));
            }
        }
        LevelLaw::Nonlinear { curves, .. } => {
            for (i, (prop, cv)) in EBBF_EXPRESSIONS.iter().zip(curves.iter()).enumerate() {
                out.push(
                    Element::new(*prop).with_text(curve_expr(cv, i).unwrap_or_else(|| "0".into())),
                );
            }
        }
        LevelLaw::Coupled { k, .. } => {
            for (prop, row) in EBBF_EXPRESSIONS.iter().zip(k.iter()) {
                out.push(Element::new(*prop).with_text(coupled_expr(row)));
            }
        }
        LevelLaw::Expression { exprs, .. } => {
            for (prop, e) in EBBF_EXPRESSIONS.iter().zip(exprs.iter()) {
                out.push(Element::new(*prop).with_text(e.clone()));
            }
        }
    }
    out.extend(damping);
    Ok(out)
}

/// Properties a bushing keeps when its law changes (everything that is not a law property).
fn is_law_prop(tag: &str) -> bool {
    matches!(
        tag,
        "rotational_stiffness"
            | "translational_stiffness"
            | "rotational_damping"
            | "translational_damping"
            | "moment_visual_scale"
            | "force_visual_scale"
            | "visual_aspect_ratio"
    ) || FBBF_FUNCTIONS.contains(&tag)
        || EBBF_EXPRESSIONS.contains(&tag)
}

/// The bushing element `e` rewritten with `law`: same name, sockets, frames
/// and other non-law properties; class per [`class_of`].
fn rewrite_bushing(e: &Element, law: &LevelLaw) -> Result<Element> {
    let mut out = Element::new(class_of(law));
    out.attrs = e.attrs.clone();
    out.line = 0;
    let mut pending_comment: Vec<Node> = Vec::new();
    for n in &e.children {
        match n {
            Node::Element(c) => {
                if is_law_prop(&c.name) {
                    pending_comment.clear();
                } else {
                    out.children.append(&mut pending_comment);
                    out.children.push(Node::Element(c.clone()));
                }
            }
            Node::Comment(_) => pending_comment.push(n.clone()),
            _ => {}
        }
    }
    for p in law_props(law)? {
        out.children.push(Node::Element(p));
    }
    Ok(out)
}

/// Write the laws into the document. A bushing whose current law equals the
/// new one is left untouched. Returns the levels whose bushing was rewritten.
pub fn apply<'a>(
    doc: &mut Document,
    laws: &'a [(BushingLevel, LevelLaw)],
) -> Result<Vec<&'a BushingLevel>> {
    let file = doc.path().to_path_buf();
    let mut changed = Vec::new();
    for (l, law) in laws {
        let e = doc.component("ForceSet", &l.bushing).ok_or_else(|| {
            Error::invalid(
                file.display().to_string(),
                format!("bushing '{}' not found", l.bushing),
            )
        })?;
        if read_law(e, &file).ok().as_ref() == Some(law) && e.name == class_of(law) {
            continue;
        }
        let new = rewrite_bushing(e, law)?;
        doc.replace_component("ForceSet", &l.bushing, new)?;
        changed.push(l);
    }
    Ok(changed)
}

/// The table law of a solver law (to write a law computed by the solver
/// side, e.g. a calibrated or diagnosed one, with [`apply`]).
/// `expressions` are the strings of an [`crate::solver::BushingModel::Expression`] law
/// (the solver keeps only their parsed form). Tabulated curves
/// (`Curve::Function`) are not supported.
pub fn law_of_model(
    m: &crate::solver::BushingModel,
    expressions: Option<&[String; 6]>,
) -> Result<LevelLaw> {
    use crate::solver::BushingModel;
    let c = m.damping();
    let curve = |cv: &Curve| -> Result<Curve> {
        match cv {
            Curve::Function(_) => Err(Error::invalid(
                "stiffness writer",
                "a tabulated solver curve cannot be converted to a table law",
            )),
            _ => Ok(cv.clone()),
        }
    };
    Ok(match m {
        BushingModel::Linear { .. } => {
            let p = m.stiffness_params();
            LevelLaw::Linear {
                k: std::array::from_fn(|i| p.get(i).copied().unwrap_or(0.0)),
                c,
            }
        }
        BushingModel::PerDof { curves, .. } => {
            let specs: Vec<Curve> = curves.iter().map(curve).collect::<Result<_>>()?;
            let curves: [Curve; 6] = specs
                .try_into()
                .map_err(|_| Error::invalid("stiffness writer", "six curves expected"))?;
            LevelLaw::Nonlinear {
                curves: Box::new(curves),
                c,
            }
        }
        BushingModel::Coupled { stiffness, .. } => LevelLaw::Coupled {
            k: std::array::from_fn(|i| std::array::from_fn(|j| stiffness[(i, j)])),
            c,
        },
        BushingModel::Expression { .. } => LevelLaw::Expression {
            exprs: Box::new(expressions.cloned().ok_or_else(|| {
                Error::invalid(
                    "stiffness writer",
                    "an expression law needs its expression strings",
                )
            })?),
            c,
        },
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn anatomical_aliases() {
        let alias = |b1: &str, b2: &str| alias(&BushingLevel::new("b", b1, b2));
        assert_eq!(alias("sacrum", "lumbar5").as_deref(), Some("L5_S1"));
        assert_eq!(alias("L5", "sacrum").as_deref(), Some("L5_S1"));
        assert_eq!(alias("thoracic12", "lumbar1").as_deref(), Some("T12_L1"));
        assert_eq!(alias("T2", "T1").as_deref(), Some("T1_T2"));
        assert_eq!(
            alias("thoracic3_s", "thoracic4_s").as_deref(),
            Some("T3_T4")
        );
        assert_eq!(alias("pelvis", "lumbar5"), None);
        assert_eq!(alias("lumbar5", "lumbar5"), None);
    }

    #[test]
    fn bodies_are_put_cranial_first() {
        let pair = |b1: &str, b2: &str| cranial_first(b1.into(), b2.into());
        let lumbar = ("lumbar5".to_string(), "sacrum".to_string());
        assert_eq!(pair("sacrum", "lumbar5"), lumbar);
        assert_eq!(pair("lumbar5", "sacrum"), lumbar);
        assert_eq!(pair("T2", "T3"), ("T2".into(), "T3".into()));
        // without vertebral names: socket 2's body first
        assert_eq!(pair("pelvis", "torso"), ("torso".into(), "pelvis".into()));
    }

    #[test]
    fn written_expressions_are_recognised_exactly() {
        let curves = [
            Curve::Sinh { k: 68.8, a: 0.05 },
            Curve::Cubic { k: 291.0, c: -12.5 },
            Curve::Bilinear {
                k_neg: 30.0,
                k_pos: 0.1 + 0.2,
            },
            Curve::Linear { k: 149000.0 },
            Curve::Linear { k: 1.0e-7 },
            Curve::Sinh {
                k: 135000.0,
                a: 0.001,
            },
        ];
        for (i, c) in curves.iter().enumerate() {
            let s = curve_expr(c, i).unwrap();
            let e = Expr::parse(&s).unwrap();
            assert_eq!(curve_of_expr(&e, i).as_ref(), Some(c), "{s}");
        }
        let row = [1.5, -0.25, 0.0, 3.0e-9, 0.0, -7.0];
        let e = Expr::parse(&coupled_expr(&row)).unwrap();
        assert_eq!(e.linear_coefficients(), Some(row));
    }

    #[test]
    fn coupled_matrices_must_be_spd() {
        let mut k = [[0.0; 6]; 6];
        for (i, r) in k.iter_mut().enumerate() {
            r[i] = 10.0;
        }
        let law = |k| LevelLaw::Coupled { k, c: [0.0; 6] };
        assert!(validate_law(&law(k), false, "t").is_ok());
        let mut asym = k;
        asym[0][1] = 1.0;
        assert!(validate_law(&law(asym), false, "t")
            .unwrap_err()
            .to_string()
            .contains("symmetric"));
        let mut indef = k;
        indef[0][1] = 20.0;
        indef[1][0] = 20.0;
        assert!(validate_law(&law(indef), false, "t")
            .unwrap_err()
            .to_string()
            .contains("positive definite"));
    }
}
