//! From a file's raw content to a landmark set: units and frame detected
//! ([`super::detect`]), names and duplicates checked strictly
//! ([`RawLandmarks::to_set`]) or leniently for the checker
//! ([`RawLandmarks::build_set`]).

use super::detect::{self, Detection};
use super::raw::RawLandmarks;
use super::{Frame, LandmarkId, LandmarkSet};
use crate::error::{Error, Result};
use nalgebra::{Point3, Vector3};

impl RawLandmarks {
    /// Units/frame detection for this content.
    pub fn detect(&self) -> Detection {
        detect::detect(self)
    }

    /// Build the set with the given detection's units and frame, leniently:
    /// the first of duplicated names wins, unknown names are skipped. For
    /// the checker, which reports those problems itself.
    pub fn build_set(&self, det: &Detection) -> LandmarkSet {
        let scale = det.units.map(|u| u.to_metres()).unwrap_or(1e-3);
        let rot = det.frame.unwrap_or(Frame::OpenSim).to_opensim();
        let mut set = LandmarkSet::new();
        for p in &self.points {
            if let Some(id) = p.id {
                if !id.level.allowed(id.code) {
                    continue;
                }
                set.points
                    .entry(id)
                    .or_insert_with(|| Point3::from(rot * Vector3::from(p.xyz) * scale));
            }
        }
        set.detection = Some(det.clone());
        set
    }

    /// Validate strictly and build the set: every name must be
    /// `<LEVEL>_<CODE>` valid at its level, no duplicates, units and frame
    /// declared-and-consistent or detectable without doubt.
    pub fn to_set(&self) -> Result<LandmarkSet> {
        let mut seen: std::collections::BTreeMap<LandmarkId, Option<usize>> = Default::default();
        for p in &self.points {
            let loc = p
                .line
                .map(|l| format!("line {l}"))
                .unwrap_or_else(|| format!("landmark `{}`", p.name));
            if let Some(b) = &p.body {
                return Err(Error::parse(
                    &self.path,
                    loc,
                    format!(
                        "`{}` is given in the frame of body `{b}` (a `body` column): that is a palpation of a model for `base --palpation`, not a patient's landmark set",
                        p.name
                    ),
                ));
            }
            let Some(id) = p.id else {
                return Err(Error::parse(
                    &self.path,
                    loc,
                    format!(
                        "unknown landmark name `{}`: expected <LEVEL>_<CODE> (LEVEL T1..T12, L1..L5, S1; CODE SEC, IEC, PTR, PTL, PBR, PBL, SA, SP, SR, SL, IA, IP, IR, IL)",
                        crate::util::messages::shown(&p.name)
                    ),
                ));
            };
            if !id.level.allowed(id.code) {
                return Err(Error::parse(
                    &self.path,
                    loc,
                    format!(
                        "`{}` is not a sacral landmark (S1 has SEC, SA, SP, SR, SL, PTR, PTL)",
                        p.name
                    ),
                ));
            }
            if let Some(prev) = seen.insert(id, p.line) {
                let prev = prev
                    .map(|l| format!(" (first at line {l})"))
                    .unwrap_or_default();
                return Err(Error::parse(
                    &self.path,
                    loc,
                    format!("duplicate landmark `{id}`{prev}"),
                ));
            }
        }
        let det = self.detect();
        if let Some(msg) = det.problems().into_iter().next() {
            return Err(Error::invalid(self.path.display().to_string(), msg));
        }
        Ok(self.build_set(&det))
    }
}
