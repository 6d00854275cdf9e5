//! Load cases of the experiment format (`../shared/formats/experiment.md`):
//! the `[[case]]` tables, parsed with serde and validated with messages that
//! name the file and the case. Used by `osim-spine simulate` (a load file of
//! `[[case]]` tables) and by calibration (the cases of `experiment.toml`).

use crate::error::{Error, Result};
use crate::solver::{Load, LoadFrame};
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Axes a load vector is given in.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum FrameName {
    Ground,
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
    let parsed: CaseFile = toml::from_str(text).map_err(|e| {
        let location = match e.span() {
            Some(s) => format!(
                "line {}",
                text[..s.start.min(text.len())].lines().count().max(1)
            ),
            None => "file".to_string(),
        };
        Error::parse(file, location, e.message().to_string())
    })?;
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

/// Read and parse a load file.
pub fn read_cases(path: &Path) -> Result<Vec<LoadCase>> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    parse_cases(&text, path)
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
}
