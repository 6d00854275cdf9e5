//! A NIfTI label map to per-level surfaces: the label table (given, or the
//! built-in one whose levels lie in cranio-caudal order in the map's
//! world), a named finding for every label that is not a T1..S1 vertebra,
//! a level left out when its label touches the edge of the field of view,
//! and one surface per level on the label's bounding box.

use super::labels::{LabelClass, LabelTable};
use super::nifti::{self, LabelMap};
use super::surface::{self, LabelStats};
use super::{source_name, Finding, Kind, LevelInput, Loaded, Options, Severity};
use crate::error::{Error, Result};
use crate::landmarks::{Frame, Level, Units};
use nalgebra::{Point3, Vector3};
use std::collections::BTreeMap;
use std::path::Path;

/// Read a label map into level surfaces (metres, world RAS axes).
pub fn load(path: &Path, opts: &Options) -> Result<Loaded> {
    let map = nifti::read(path)?;
    let stats = surface::label_stats(&map);
    let (table, mut findings) = choose_table(&map, &stats, opts.labels.as_deref(), path)?;
    findings.extend(
        map.notes
            .iter()
            .map(|n| Finding::new(None, Severity::Info, n.clone())),
    );
    findings.extend(label_findings(&table, &stats));
    let wanted = present_levels(&table, &stats);
    if wanted.is_empty() {
        return Err(Error::invalid(
            path.display().to_string(),
            format!(
                "no vertebra label (T1..L5, sacrum) of the {} table in the map; labels present: {}",
                table.name,
                list_labels(&stats)
            ),
        ));
    }
    let levels = extract_levels(&map, &stats, &wanted, opts.progress, &mut findings);
    Ok(Loaded {
        kind: Kind::LabelMap,
        source: source_name(path),
        frame: Some(Frame::Ras),
        units: opts.units.unwrap_or(Units::Millimetre),
        label_table: Some(table.name),
        levels,
        findings,
    })
}

/// Labels present, as text (at most 20).
fn list_labels(stats: &BTreeMap<u16, LabelStats>) -> String {
    let v: Vec<String> = stats.keys().take(20).map(|l| l.to_string()).collect();
    if v.is_empty() {
        "none (the map is empty)".into()
    } else {
        v.join(" ")
    }
}

/// Each level of the table present in the map, with its labels.
fn present_levels(
    table: &LabelTable,
    stats: &BTreeMap<u16, LabelStats>,
) -> BTreeMap<Level, Vec<u16>> {
    let mut out: BTreeMap<Level, Vec<u16>> = BTreeMap::new();
    for (level, labels) in table.labels_of_levels() {
        let here: Vec<u16> = labels
            .into_iter()
            .filter_map(|l| u16::try_from(l).ok())
            .filter(|l| stats.contains_key(l))
            .collect();
        if !here.is_empty() {
            out.insert(level, here);
        }
    }
    out
}

/// The `--labels` table, or the built-in table whose levels are best
/// ordered cranio-caudally (superior = +z of the RAS world).
fn choose_table(
    map: &LabelMap,
    stats: &BTreeMap<u16, LabelStats>,
    given: Option<&Path>,
    path: &Path,
) -> Result<(LabelTable, Vec<Finding>)> {
    if let Some(p) = given {
        return Ok((LabelTable::read(p)?, vec![]));
    }
    let scored: Vec<(i64, usize, LabelTable)> = LabelTable::builtin()
        .into_iter()
        .map(|t| {
            let lv = present_levels(&t, stats);
            (order_score(map, stats, &lv), lv.len(), t)
        })
        .collect();
    let best = scored
        .iter()
        .max_by_key(|(s, n, _)| (*s, *n))
        .filter(|(_, n, _)| *n > 0)
        .ok_or_else(|| {
            Error::invalid(
                path.display().to_string(),
                format!(
                    "no vertebra label of TotalSegmentator or TotalSpineSeg in the map (labels present: {}); give the table with --labels FILE",
                    list_labels(stats)
                ),
            )
        })?;
    let note = format!(
        "label table: {} (its levels are in cranio-caudal order in the map; give --labels to override)",
        best.2.name
    );
    Ok((
        best.2.clone(),
        vec![Finding::new(None, Severity::Info, note)],
    ))
}

/// Level pairs in cranio-caudal order minus pairs out of order, judged by
/// the world height (+z, RAS) of the labels' bounding-box centres.
fn order_score(
    map: &LabelMap,
    stats: &BTreeMap<u16, LabelStats>,
    lv: &BTreeMap<Level, Vec<u16>>,
) -> i64 {
    let z: Vec<f64> = lv
        .values()
        .map(|labels| box_centre(map, &union_box(stats, labels)).z)
        .collect();
    let mut score = 0;
    for i in 0..z.len() {
        for j in i + 1..z.len() {
            score += if z[i] > z[j] { 1 } else { -1 };
        }
    }
    score
}

/// Union of the bounding boxes of some labels.
fn union_box(stats: &BTreeMap<u16, LabelStats>, labels: &[u16]) -> LabelStats {
    let mut it = labels.iter().filter_map(|l| stats.get(l));
    let first = *it.next().expect("present labels only");
    it.fold(first, |mut a, b| {
        a.count += b.count;
        for k in 0..3 {
            a.min[k] = a.min[k].min(b.min[k]);
            a.max[k] = a.max[k].max(b.max[k]);
        }
        a
    })
}

/// World position of a box's centre.
fn box_centre(map: &LabelMap, s: &LabelStats) -> Point3<f64> {
    let c = Vector3::from_fn(|k, _| 0.5 * (s.min[k] + s.max[k]) as f64);
    map.world(&Point3::from(c))
}

/// Labels present that are not a T1..S1 vertebra: info for structures
/// the table names, a warning for labels it does not know.
fn label_findings(table: &LabelTable, stats: &BTreeMap<u16, LabelStats>) -> Vec<Finding> {
    let mut out = Vec::new();
    let mut others = Vec::new();
    for &l in stats.keys() {
        match table.classes.get(&(l as u32)) {
            Some(LabelClass::Level(_)) => {}
            Some(LabelClass::Cervical(c)) => others.push(format!("{l} (C{c})")),
            Some(LabelClass::Other(name)) => others.push(format!("{l} ({name})")),
            None => out.push(Finding::new(
                None,
                Severity::Warning,
                format!(
                    "label {l} is not in the {} table: not a vertebra of the model, ignored",
                    table.name
                ),
            )),
        }
    }
    if !others.is_empty() {
        out.push(Finding::new(
            None,
            Severity::Info,
            format!(
                "labels that are not T1..S1 vertebrae, ignored: {}",
                others.join(", ")
            ),
        ));
    }
    out
}

/// One surface per level (metres); a level whose labels touch the edge of
/// the field of view is left out with a warning.
fn extract_levels(
    map: &LabelMap,
    stats: &BTreeMap<u16, LabelStats>,
    wanted: &BTreeMap<Level, Vec<u16>>,
    progress: bool,
    findings: &mut Vec<Finding>,
) -> Vec<LevelInput> {
    let bar = progress_bar(wanted.len(), progress);
    // Levels cut by the field of view are left out, named.
    let mut inside = Vec::new();
    for (&level, labels) in wanted {
        let b = union_box(stats, labels);
        if b.touches_edge(&map.dims) && !(level.is_sacrum() && only_inferior_cut(map, &b)) {
            findings.push(Finding::new(
                Some(level),
                Severity::Warning,
                format!(
                    "label {} touches the edge of the field of view (voxels {:?}..{:?} of {:?}): truncated vertebra, level left out",
                    join(labels), b.min, b.max, map.dims
                ),
            ));
            bar.inc(1);
        } else {
            inside.push((level, labels, b));
        }
    }
    // One surface per level, in parallel (in order), in metres.
    use rayon::prelude::*;
    let out = inside
        .par_iter()
        .map(|(level, labels, b)| {
            let mesh = surface::extract(map, labels, b.min, b.max).scaled(&Vector3::repeat(1e-3));
            bar.inc(1);
            LevelInput {
                level: *level,
                mesh,
                origin: format!("label {}", join(labels)),
            }
        })
        .collect();
    bar.finish_and_clear();
    out
}

/// `true` when every face of the volume the box touches lies inferior
/// (a sacrum cut below its plateau keeps its plateau).
fn only_inferior_cut(map: &LabelMap, b: &LabelStats) -> bool {
    (0..3).all(|k| {
        let axis = map.affine.fixed_view::<3, 1>(0, k).into_owned().normalize();
        let low = b.min[k] == 0 && axis.z < 0.5;
        let high = b.max[k] + 1 == map.dims[k] && axis.z > -0.5;
        !low && !high
    })
}

/// `25+26`.
fn join(labels: &[u16]) -> String {
    labels
        .iter()
        .map(|l| l.to_string())
        .collect::<Vec<_>>()
        .join("+")
}

/// A progress bar on stderr (hidden when not wanted or not a terminal).
fn progress_bar(n: usize, show: bool) -> indicatif::ProgressBar {
    if !show {
        return indicatif::ProgressBar::hidden();
    }
    let b = indicatif::ProgressBar::new(n as u64);
    if let Ok(st) = indicatif::ProgressStyle::with_template("surfaces {bar:30} {pos}/{len} {msg}") {
        b.set_style(st);
    }
    b
}
