//! A NIfTI label map to per-level surfaces: the label table (given, or
//! chosen from the anatomy, [`super::choose`]), one line for the labels
//! that are not T1..S1 vertebrae, a level left out when its label touches
//! the edge of the field of view (the map refused when every vertebra
//! does), and one surface per level on the label's bounding box.

use super::choose::{choose_table, join, list};
use super::labels::{LabelClass, LabelTable};
use super::nifti::{self, LabelMap};
use super::surface::{self, LabelStats};
use super::{source_name, Finding, Kind, LevelInput, Loaded, Options, Severity};
use crate::error::{Error, Result};
use crate::landmarks::{Frame, Level, Units};
use nalgebra::Vector3;
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
                list(&stats.keys().copied().collect::<Vec<_>>())
            ),
        ));
    }
    let mut cut = Vec::new();
    let levels = extract_levels(
        &map,
        &stats,
        &wanted,
        opts.progress,
        &mut findings,
        &mut cut,
    );
    if levels.is_empty() {
        let names: Vec<String> = wanted
            .iter()
            .map(|(l, labels)| format!("{l} (label {})", join(labels)))
            .collect();
        return Err(Error::invalid(
            path.display().to_string(),
            format!(
                "every vertebra of the map is cut by the field of view ({}): no level can be palpated whole",
                names.join(", ")
            ),
        ));
    }
    let resolution = Resolution::of(&map);
    findings.extend(resolution.coarse_findings());
    Ok(Loaded {
        kind: Kind::LabelMap,
        source: source_name(path),
        frame: Some(Frame::Ras),
        units: opts.units.unwrap_or(Units::Millimetre),
        label_table: Some(table.name),
        levels,
        findings,
        cut_by_fov: cut,
        resolution: Some(resolution),
    })
}

/// Largest voxel edge (mm) the landmarking protocol is written for: a
/// thicker slice blurs the endplates it places landmarks on.
pub(crate) const PROTOCOL_VOXEL_MM: f64 = 3.0;

/// A label map's voxel size: what its landmarks can resolve.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Resolution {
    /// Voxel edge lengths along the map's i, j, k axes (mm).
    pub voxel_mm: [f64; 3],
    /// The anatomical direction each voxel axis runs closest to.
    #[serde(skip)]
    pub directions: [&'static str; 3],
}

impl Resolution {
    /// The voxel edges of a map and their directions in the RAS world.
    pub fn of(map: &LabelMap) -> Resolution {
        let m = map.affine.fixed_view::<3, 3>(0, 0);
        let edge = |k: usize| m.column(k).into_owned();
        Resolution {
            voxel_mm: [0, 1, 2].map(|k| edge(k).norm()),
            directions: [0, 1, 2].map(|k| match edge(k).iamax() {
                0 => "left-right",
                1 => "anterior-posterior",
                _ => "superior-inferior",
            }),
        }
    }

    /// The largest voxel edge (mm).
    pub(crate) fn largest_mm(&self) -> f64 {
        self.voxel_mm.iter().copied().fold(0.0, f64::max)
    }

    /// The resolution's part of every landmark's position uncertainty:
    /// half the largest voxel edge (mm).
    pub fn uncertainty_mm(&self) -> f64 {
        0.5 * self.largest_mm()
    }

    /// Highest confidence a landmark of this map can have: 1 up to the
    /// protocol's voxel, then falling as its ratio to the largest edge.
    pub fn confidence_cap(&self) -> f64 {
        (PROTOCOL_VOXEL_MM / self.largest_mm()).min(1.0)
    }

    /// One warning per voxel axis thicker than the protocol's voxel,
    /// naming the axis, its direction and its size.
    pub(crate) fn coarse_findings(&self) -> Vec<Finding> {
        let names = ["i", "j", "k"];
        (0..3)
            .filter(|&k| self.voxel_mm[k] > PROTOCOL_VOXEL_MM)
            .map(|k| {
                Finding::new(
                    None,
                    Severity::Warning,
                    format!(
                        "the label map's voxels are {:.2} mm along {} (its {} axis): too coarse for the protocol along {} (at most {PROTOCOL_VOXEL_MM} mm): every landmark is uncertain by at least {:.2} mm and its confidence capped at {:.2}; re-segment a scan with thinner slices",
                        self.voxel_mm[k],
                        names[k],
                        self.directions[k],
                        names[k],
                        self.uncertainty_mm(),
                        self.confidence_cap()
                    ),
                )
            })
            .collect()
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

/// Union of the statistics of some labels.
fn union_box(stats: &BTreeMap<u16, LabelStats>, labels: &[u16]) -> LabelStats {
    let mut it = labels.iter().filter_map(|l| stats.get(l));
    let first = *it.next().expect("present labels only");
    it.fold(first, |a, b| a.union(b))
}

/// Labels present that are not a T1..S1 vertebra: one line counting the
/// structures the table names (cervical vertebrae, organs, vessels, other
/// bones, discs, the cord) and one naming the labels it does not know.
fn label_findings(table: &LabelTable, stats: &BTreeMap<u16, LabelStats>) -> Vec<Finding> {
    let mut out = Vec::new();
    let mut others = Vec::new();
    let mut unknown = Vec::new();
    for &l in stats.keys() {
        match table.classes.get(&(l as u32)) {
            Some(LabelClass::Level(_)) => {}
            Some(_) => others.push(format!(
                "{l} {}",
                table.class_name(l as u32).unwrap_or_default()
            )),
            None => unknown.push(l),
        }
    }
    if !others.is_empty() {
        let shown: Vec<&str> = others.iter().take(8).map(String::as_str).collect();
        out.push(Finding::new(
            None,
            Severity::Info,
            format!(
                "{} other structures ignored (not T1..S1 vertebrae: {}{})",
                others.len(),
                shown.join(", "),
                if others.len() > shown.len() {
                    ", ..."
                } else {
                    ""
                }
            ),
        ));
    }
    if !unknown.is_empty() {
        out.push(Finding::new(
            None,
            Severity::Warning,
            format!(
                "{} label(s) not in the {} table ignored: {}",
                unknown.len(),
                table.name,
                list(&unknown)
            ),
        ));
    }
    out
}

/// One surface per level (metres); a level whose labels touch the edge of
/// the field of view is left out with a warning and listed in `cut`.
fn extract_levels(
    map: &LabelMap,
    stats: &BTreeMap<u16, LabelStats>,
    wanted: &BTreeMap<Level, Vec<u16>>,
    progress: bool,
    findings: &mut Vec<Finding>,
    cut: &mut Vec<Level>,
) -> Vec<LevelInput> {
    let bar = crate::util::progress::bar("surfaces", wanted.len() as u64, "labels", progress);
    // Levels cut by the field of view are left out, named.
    let mut inside = Vec::new();
    for (&level, labels) in wanted {
        let b = union_box(stats, labels);
        if b.touches_edge(&map.dims) && !(level.is_sacrum() && only_inferior_cut(map, &b)) {
            findings.push(Finding::new(
                Some(level),
                Severity::Warning,
                format!(
                    "{level} (label {}) is cut by the field of view (it reaches the map's edge: voxels {:?}..{:?} of {:?}): left out",
                    join(labels), b.min, b.max, map.dims
                ),
            ));
            cut.push(level);
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
            let (mesh, mut voxels) = surface::extract_with_voxels(map, labels, b.min, b.max);
            // Metres, as every level surface.
            for c in voxels.centres.iter_mut() {
                *c *= 1e-3;
            }
            voxels.edges = voxels.edges.map(|e| e * 1e-3);
            bar.inc(1);
            LevelInput {
                level: *level,
                mesh: mesh.scaled(&Vector3::repeat(1e-3)),
                origin: format!("label {}", join(labels)),
                voxels: Some(voxels),
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
