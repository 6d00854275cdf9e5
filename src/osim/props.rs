//! Typed property helpers on the elements of an .osim tree: read a number,
//! a Vec3, a bool or a list of numbers (every getter names the file and the
//! element on error, [`loc`]), and write them back with shortest round-trip
//! formatting. Used by the document, the typed model, the functions and the
//! legacy upgrades alike.

use super::xml::Element;
use crate::error::{Error, Result};
use crate::util::fmt_f64;
use nalgebra::Vector3;
use std::path::Path;

/// Where an element is, for error messages: `<Tag name="x"> (line N)`.
pub fn loc(e: &Element) -> String {
    match e.attr("name") {
        Some(n) if e.line > 0 => format!("<{} name=\"{}\"> (line {})", e.name, n, e.line),
        Some(n) => format!("<{} name=\"{}\">", e.name, n),
        None if e.line > 0 => format!("<{}> (line {})", e.name, e.line),
        None => format!("<{}>", e.name),
    }
}

/// Parse whitespace-separated numbers of property `prop` of `e`; every value
/// must be finite. `None` when the property is absent.
pub fn opt_numbers(e: &Element, prop: &str, file: &Path) -> Result<Option<Vec<f64>>> {
    let Some(c) = e.child(prop) else {
        return Ok(None);
    };
    parse_numbers(&c.text(), c, file).map(Some)
}

/// Parse whitespace-separated finite numbers from `text` (found in `at`).
pub fn parse_numbers(text: &str, at: &Element, file: &Path) -> Result<Vec<f64>> {
    text.split_whitespace()
        .map(|tok| {
            let v: f64 = tok
                .parse()
                .map_err(|_| Error::parse(file, loc(at), format!("'{tok}' is not a number")))?;
            if v.is_finite() {
                Ok(v)
            } else {
                Err(Error::parse(
                    file,
                    loc(at),
                    format!("value '{tok}' is not finite (NaN/inf)"),
                ))
            }
        })
        .collect()
}

fn required<'a>(e: &'a Element, prop: &str, file: &Path) -> Result<&'a Element> {
    e.child(prop)
        .ok_or_else(|| Error::parse(file, loc(e), format!("missing required property <{prop}>")))
}

/// Required scalar property.
pub fn f64_prop(e: &Element, prop: &str, file: &Path) -> Result<f64> {
    let c = required(e, prop, file)?;
    scalar_of(c, file)
}

/// Optional scalar property with a default when absent.
pub fn f64_or(e: &Element, prop: &str, default: f64, file: &Path) -> Result<f64> {
    match e.child(prop) {
        Some(c) => scalar_of(c, file),
        None => Ok(default),
    }
}

fn scalar_of(c: &Element, file: &Path) -> Result<f64> {
    let v = parse_numbers(&c.text(), c, file)?;
    match v.as_slice() {
        [x] => Ok(*x),
        _ => Err(Error::parse(
            file,
            loc(c),
            format!("expected one number, found {}", v.len()),
        )),
    }
}

/// Required property with exactly `n` numbers.
pub fn fixed_prop(e: &Element, prop: &str, n: usize, file: &Path) -> Result<Vec<f64>> {
    let c = required(e, prop, file)?;
    let v = parse_numbers(&c.text(), c, file)?;
    if v.len() != n {
        return Err(Error::parse(
            file,
            loc(c),
            format!("expected {n} numbers, found {}", v.len()),
        ));
    }
    Ok(v)
}

/// Required Vec3 property.
pub fn vec3_prop(e: &Element, prop: &str, file: &Path) -> Result<Vector3<f64>> {
    let v = fixed_prop(e, prop, 3, file)?;
    Ok(Vector3::new(v[0], v[1], v[2]))
}

/// Optional Vec3 property with a default when absent.
pub fn vec3_or(
    e: &Element,
    prop: &str,
    default: Vector3<f64>,
    file: &Path,
) -> Result<Vector3<f64>> {
    if e.child(prop).is_some() {
        vec3_prop(e, prop, file)
    } else {
        Ok(default)
    }
}

/// Optional bool property (`true`/`false`, as OpenSim writes) with default.
pub fn bool_or(e: &Element, prop: &str, default: bool, file: &Path) -> Result<bool> {
    let Some(c) = e.child(prop) else {
        return Ok(default);
    };
    match c.text().trim() {
        "true" | "1" => Ok(true),
        "false" | "0" => Ok(false),
        other => Err(Error::parse(
            file,
            loc(c),
            format!("'{other}' is not true/false"),
        )),
    }
}

/// Optional string property, trimmed; `None` when absent.
pub fn str_prop(e: &Element, prop: &str) -> Option<String> {
    e.child_text(prop)
}

/// Set a scalar property (shortest round-trip formatting).
pub fn set_f64(e: &mut Element, prop: &str, v: f64) {
    e.set_child_text(prop, fmt_f64(v));
}

/// Set a Vec3 property.
pub fn set_vec3(e: &mut Element, prop: &str, v: &Vector3<f64>) {
    e.set_child_text(prop, fmt_numbers(v.as_slice()));
}

/// Set a list-of-numbers property.
pub fn set_numbers(e: &mut Element, prop: &str, v: &[f64]) {
    e.set_child_text(prop, fmt_numbers(v));
}

/// Numbers separated by single spaces.
pub fn fmt_numbers(v: &[f64]) -> String {
    v.iter().map(|x| fmt_f64(*x)).collect::<Vec<_>>().join(" ")
}
