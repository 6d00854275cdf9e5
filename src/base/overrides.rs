//! A modeller's own palpation of the generic model (`base --palpation FILE`,
//! `--centres FILE`): the thesis's workflow, where the operator who
//! palpated the patients also palpated the base model, so that both follow
//! the same hand. The named landmarks (and vertebral centres) replace the
//! engine's; everything else stays the engine's.
//!
//! Both files are landmark files (`../shared/formats/landmarks.md`, read by
//! [`crate::landmarks::io`]): names `<LEVEL>_<CODE>` (palpation) or
//! `<LEVEL>_centre` (centres), with `# units:` and either
//! - `# frame:` and coordinates in the generic model's ground at its
//!   default pose (the frame of the file: `opensim`, or `LPS`/`RAS` read as
//!   patient axes of that ground), or
//! - a `body` column (`name,body,x,y,z`): coordinates in that body's frame
//!   (OpenSim axes; `# frame:` absent or `opensim`).

use crate::error::{Error, Result};
use crate::landmarks::io::{read_path, RawLandmarks};
use crate::landmarks::{Code, Frame, Level};
use nalgebra::{Isometry3, Point3, Vector3};
use std::collections::BTreeMap;
use std::path::Path;

/// Where a given point is: in ground at the default pose, or in a body.
#[derive(Debug, Clone, PartialEq)]
pub enum Placed {
    /// A point in ground at the model's default pose (m).
    Ground(Point3<f64>),
    /// A point in the named body's frame (m).
    Body(String, Point3<f64>),
}

impl Placed {
    /// The point in the frame of `body`, with the bodies' default poses.
    pub fn in_body(
        &self,
        body: &str,
        poses: &BTreeMap<String, Isometry3<f64>>,
        ctx: &str,
    ) -> Result<Point3<f64>> {
        let pose = |b: &str| {
            poses
                .get(b)
                .copied()
                .ok_or_else(|| Error::invalid(ctx, format!("body '{b}' is not in the base model")))
        };
        Ok(match self {
            Placed::Ground(p) => pose(body)?.inverse() * p,
            Placed::Body(b, p) if b == body => *p,
            Placed::Body(b, p) => pose(body)?.inverse() * (pose(b)? * p),
        })
    }
}

/// A modeller's palpation: landmarks and vertebral centres by level.
#[derive(Debug, Clone, Default)]
pub struct Overrides {
    /// Given landmarks by level and code.
    pub landmarks: BTreeMap<(Level, Code), Placed>,
    /// Given vertebral centres by level.
    pub centres: BTreeMap<Level, Placed>,
    /// The files they came from (for the report).
    pub sources: Vec<String>,
}

impl Overrides {
    /// Read `--palpation` and `--centres` files (either may be absent).
    pub fn read(palpation: Option<&Path>, centres: Option<&Path>) -> Result<Overrides> {
        let mut out = Overrides::default();
        if let Some(p) = palpation {
            for (name, line, placed) in points(&read_path(p)?)? {
                let id = crate::landmarks::LandmarkId::parse_name(&name)
                    .map(|x| x.0)
                    .filter(|id| id.level.allowed(id.code))
                    .ok_or_else(|| {
                        Error::parse(
                            p,
                            &line,
                            format!("`{name}` is not a landmark of the protocol (<LEVEL>_<CODE>)"),
                        )
                    })?;
                out.landmarks.insert((id.level, id.code), placed);
            }
            out.sources.push(p.display().to_string());
        }
        if let Some(p) = centres {
            for (name, line, placed) in points(&read_path(p)?)? {
                let level = centre_level(&name).ok_or_else(|| {
                    Error::parse(
                        p,
                        &line,
                        format!("`{name}`: expected <LEVEL>_centre (T1..L5)"),
                    )
                })?;
                out.centres.insert(level, placed);
            }
            out.sources.push(p.display().to_string());
        }
        Ok(out)
    }

    /// Nothing given.
    pub fn is_empty(&self) -> bool {
        self.landmarks.is_empty() && self.centres.is_empty()
    }
}

/// `T3_centre` -> T3 (vertebrae only; case-insensitive suffix).
fn centre_level(name: &str) -> Option<Level> {
    let (l, c) = name.split_once('_')?;
    let level: Level = l.parse().ok()?;
    (c.eq_ignore_ascii_case("centre") || c.eq_ignore_ascii_case("center"))
        .then_some(level)
        .filter(|l| !l.is_sacrum())
}

/// Every point of a file in metres, OpenSim axes, with its place; units
/// must be declared, and the frame too for ground coordinates.
fn points(raw: &RawLandmarks) -> Result<Vec<(String, String, Placed)>> {
    let path = &raw.path;
    let units = raw.declared_units.ok_or_else(|| {
        Error::parse(
            path,
            "header",
            "no `# units:` line: say `mm` or `m` (a palpation of a model is not guessed)",
        )
    })?;
    let any_body = raw.points.iter().any(|p| p.body.is_some());
    let frame = match (raw.declared_frame, any_body) {
        (Some(f), false) => f,
        (None, true) | (Some(Frame::OpenSim), true) => Frame::OpenSim,
        (None, false) => {
            return Err(Error::parse(path, "header", "no `# frame:` line: ground coordinates need `opensim`, `LPS` or `RAS` (or give a `body` column)"));
        }
        (Some(f), true) => {
            return Err(Error::parse(path, "header", format!("`# frame: {f:?}` with a `body` column: body frames have OpenSim axes (say `opensim` or nothing)")));
        }
    };
    let r = frame.to_opensim();
    let k = units.to_metres();
    Ok(raw
        .points
        .iter()
        .map(|p| {
            let v = r * Vector3::from(p.xyz) * k;
            let line = p
                .line
                .map(|l| format!("line {l}"))
                .unwrap_or_else(|| p.name.clone());
            let placed = match &p.body {
                Some(b) => Placed::Body(b.clone(), Point3::from(v)),
                None => Placed::Ground(Point3::from(v)),
            };
            (p.name.clone(), line, placed)
        })
        .collect())
}
