//! Which label table names a label map, from the evidence in the map
//! ([`super::evidence`]): a built-in table is a candidate when it knows
//! every label present and names at least one vertebra; each candidate's
//! naming is assessed against the anatomy (order along the world's
//! superior axis, spacing, a sacrum that is a sacrum, no vertebra called
//! an organ and no organ called a vertebra). One consistent candidate is
//! chosen; between several, the one whose spacing fits the published
//! spine best, when it fits clearly better (the count of levels against
//! the length of spine they span); otherwise the map is refused, naming
//! the candidates and `--labels`. A `--labels` table is assessed the same
//! way and refused when the anatomy contradicts it.

use super::evidence::{self, Assessment, Place, Reading, Structure};
use super::labels::{LabelClass, LabelTable};
use super::nifti::LabelMap;
use super::surface::LabelStats;
use super::{Finding, Severity};
use crate::anatomy::DimensionTable;
use crate::error::{Error, Result};
use nalgebra::{Matrix3, Vector3};
use std::collections::BTreeMap;
use std::path::Path;

/// A clearly better spacing fit: the other candidate's |ln scale| exceeds
/// the best's by at least ln 1.25 (a 25 % larger or smaller spine).
const SCALE_MARGIN: f64 = 0.223;
/// Spacing scales a patient's spine can have against the published adult
/// means (a small child's to a tall adult's).
const PLAUSIBLE_SCALE: (f64, f64) = (0.55, 1.8);

/// The structure of some labels (metres, world RAS).
pub fn structure(map: &LabelMap, s: &LabelStats, origin: String) -> Structure {
    let a: Matrix3<f64> = map.affine.fixed_view::<3, 3>(0, 0).into_owned();
    let (c, cov) = s.moments();
    Structure {
        origin,
        centroid: map.world(&c) * 1e-3,
        volume: s.count as f64 * a.determinant().abs() * 1e-9,
        // A voxel's own extent (1/12 of its edge squared) added.
        covariance: a * (cov + Matrix3::identity() / 12.0) * a.transpose() * 1e-6,
        truncated: s.touches_edge(&map.dims),
    }
}

/// `27+28`.
pub fn join(labels: &[u16]) -> String {
    labels
        .iter()
        .map(|l| l.to_string())
        .collect::<Vec<_>>()
        .join("+")
}

/// What a table makes of the map: its structures and assessment.
struct Candidate {
    table: LabelTable,
    assessment: Assessment,
    /// Labels present that the table does not have.
    unknown: Vec<u16>,
}

/// Structures by named place, and the others with what the table calls them.
type Named = (Vec<(Place, Structure)>, Vec<(String, Structure)>);

/// The structures of the map as `table` names them (one per named place,
/// its labels' union; one per other label).
fn structures(map: &LabelMap, stats: &BTreeMap<u16, LabelStats>, table: &LabelTable) -> Named {
    let mut by_place: BTreeMap<Place, Vec<u16>> = BTreeMap::new();
    let mut others = Vec::new();
    for &l in stats.keys() {
        match table.classes.get(&(l as u32)) {
            Some(LabelClass::Level(v)) => by_place.entry(Place::Level(*v)).or_default().push(l),
            Some(LabelClass::Cervical(c)) => {
                by_place.entry(Place::Cervical(*c)).or_default().push(l)
            }
            Some(LabelClass::Other(name)) => others.push((
                name.clone(),
                structure(map, &stats[&l], format!("label {l}")),
            )),
            None => others.push((
                "not in the table".into(),
                structure(map, &stats[&l], format!("label {l}")),
            )),
        }
    }
    let named = by_place
        .into_iter()
        .map(|(p, labels)| {
            let s = labels
                .iter()
                .skip(1)
                .fold(stats[&labels[0]], |a, l| a.union(&stats[l]));
            (p, structure(map, &s, format!("label {}", join(&labels))))
        })
        .collect();
    (named, others)
}

/// Assess `table`'s naming of the map.
fn assess(
    map: &LabelMap,
    stats: &BTreeMap<u16, LabelStats>,
    table: LabelTable,
    dims: &DimensionTable,
) -> Candidate {
    let (named, others) = structures(map, stats, &table);
    let reading = Reading {
        named: named.iter().map(|(p, s)| (*p, s)).collect(),
        others: others.iter().map(|(w, s)| (w.clone(), s)).collect(),
    };
    let assessment = evidence::assess(&reading, Some(Vector3::z()), dims);
    let unknown = stats
        .keys()
        .copied()
        .filter(|l| !table.classes.contains_key(&(*l as u32)))
        .collect();
    Candidate {
        table,
        assessment,
        unknown,
    }
}

/// Does the table name any vertebra present?
fn names_a_level(table: &LabelTable, stats: &BTreeMap<u16, LabelStats>) -> bool {
    stats
        .keys()
        .any(|l| matches!(table.classes.get(&(*l as u32)), Some(LabelClass::Level(_))))
}

/// The table of the map (given, or chosen from the evidence) and what was
/// noticed choosing it.
pub fn choose_table(
    map: &LabelMap,
    stats: &BTreeMap<u16, LabelStats>,
    given: Option<&Path>,
    path: &Path,
) -> Result<(LabelTable, Vec<Finding>)> {
    let dims = DimensionTable::embedded()?;
    let file = path.display().to_string();
    if let Some(p) = given {
        let c = assess(map, stats, LabelTable::read(p)?, &dims);
        if !c.assessment.consistent() {
            return Err(Error::invalid(
                file,
                format!(
                    "the anatomy contradicts the label table {}: {}",
                    p.display(),
                    c.assessment.problems.join("; ")
                ),
            ));
        }
        let findings = doubts(&c);
        return Ok((c.table, findings));
    }
    let builtin = LabelTable::builtin();
    if !builtin.iter().any(|t| names_a_level(t, stats)) {
        let names: Vec<String> = builtin.iter().map(|t| t.name.clone()).collect();
        return Err(Error::invalid(
            &file,
            format!(
                "no vertebra label of a built-in table ({}) in the map (labels present: {}): give its table with --labels FILE",
                names.join(", "),
                list(&stats.keys().copied().collect::<Vec<_>>())
            ),
        ));
    }
    let mut rejected: Vec<String> = Vec::new();
    let mut consistent: Vec<Candidate> = Vec::new();
    for t in builtin {
        if !names_a_level(&t, stats) {
            rejected.push(format!("{}: names no vertebra present", t.name));
            continue;
        }
        let c = assess(map, stats, t, &dims);
        if !c.unknown.is_empty() {
            rejected.push(format!(
                "{}: has no label {}",
                c.table.name,
                list(&c.unknown)
            ));
        } else if !c.assessment.consistent() {
            rejected.push(format!(
                "{}: {}",
                c.table.name,
                c.assessment.problems.join("; ")
            ));
        } else {
            consistent.push(c);
        }
    }
    let chosen = pick(consistent, &mut rejected).ok_or_else(|| {
        Error::invalid(
            &file,
            format!(
                "no built-in label table names this map's structures consistently with the anatomy (labels present: {}):\n  {}\n(a map with another table's labels, or with labels of two tables): give the table with --labels FILE",
                list(&stats.keys().copied().collect::<Vec<_>>()),
                rejected.join("\n  ")
            ),
        )
    })?;
    let (c, why) = chosen;
    let mut findings = vec![Finding::new(
        None,
        Severity::Info,
        format!(
            "label table: {} ({why}; give --labels to override)",
            c.table.name
        ),
    )];
    findings.extend(doubts(&c));
    Ok((c.table, findings))
}

/// The one consistent candidate, or the one whose spacing fits clearly
/// best; `None` when there is none or the evidence cannot decide (the
/// undecided candidates are added to `rejected`).
fn pick(mut consistent: Vec<Candidate>, rejected: &mut Vec<String>) -> Option<(Candidate, String)> {
    let fit = |c: &Candidate| {
        c.assessment
            .scale
            .map(|s| s.ln().abs())
            .unwrap_or(f64::INFINITY)
    };
    consistent.sort_by(|a, b| fit(a).total_cmp(&fit(b)));
    let scale = |c: &Candidate| {
        c.assessment
            .scale
            .map(|s| format!("{s:.2}"))
            .unwrap_or_else(|| "unmeasured".into())
    };
    match consistent.len() {
        0 => None,
        1 => {
            let c = consistent.remove(0);
            let why = "the only built-in table that names the map's structures consistently with the anatomy".to_string();
            Some((c, why))
        }
        _ => {
            let (best, second) = (fit(&consistent[0]), fit(&consistent[1]));
            let plausible = consistent[0]
                .assessment
                .scale
                .is_some_and(|s| (PLAUSIBLE_SCALE.0..=PLAUSIBLE_SCALE.1).contains(&s));
            if plausible && second - best >= SCALE_MARGIN {
                let why = format!(
                    "its levels' spacing is {} times the published spine's, against {} with {}",
                    scale(&consistent[0]),
                    scale(&consistent[1]),
                    consistent[1].table.name
                );
                Some((consistent.remove(0), why))
            } else {
                rejected.extend(consistent.iter().map(|c| {
                    format!(
                        "{}: consistent, spacing {} times the published spine's (candidate)",
                        c.table.name,
                        scale(c)
                    )
                }));
                rejected.push(
                    "the candidates' level names cannot be told apart from the anatomy".into(),
                );
                None
            }
        }
    }
}

/// The doubts of an assessment as warnings.
fn doubts(c: &Candidate) -> Vec<Finding> {
    c.assessment
        .doubts
        .iter()
        .map(|d| Finding::new(None, Severity::Warning, d.clone()))
        .collect()
}

/// Labels as text (at most 20).
pub fn list(labels: &[u16]) -> String {
    let mut v: Vec<String> = labels.iter().take(20).map(|l| l.to_string()).collect();
    if labels.len() > 20 {
        v.push(format!("... ({} in all)", labels.len()));
    }
    if v.is_empty() {
        "none (the map is empty)".into()
    } else {
        v.join(" ")
    }
}
