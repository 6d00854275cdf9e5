//! From level surfaces to a landmark set: level selection, screening
//! ([`super::checks`]), the naming of a mesh folder against the anatomy
//! ([`super::evidence`]), the frame of the segmentation, and the palpated
//! levels assembled into a landmark set ending at the sacrum (gaps allowed:
//! one doubtful level does not drop the others), with every level left out
//! and every uncertain landmark named.

use super::checks::{self, Verdict};
use super::evidence::{self, Place, Reading, Structure};
use super::hints::frame_axes;
use super::{Finding, Kind, LevelInput, LevelResult, Loaded, Options, Palpated, Severity};
use crate::anatomy::DimensionTable;
use crate::error::{Error, Result};
use crate::landmarks::{Frame, LandmarkSet, Level};
use crate::mesh::MeshQuery;
use crate::palpation::{self, FrameHint, VertebraPalpation};
use nalgebra::Vector3;

/// Confidence below which a landmark is flagged as uncertain.
pub const UNCERTAIN: f64 = 0.5;

/// Keep the levels of `range` (inclusive); an error when none is left.
pub fn select_levels(loaded: &mut Loaded, range: Option<(Level, Level)>) -> Result<()> {
    let Some((a, b)) = range else { return Ok(()) };
    let (lo, hi) = (a.min(b), a.max(b));
    loaded.levels.retain(|l| (lo..=hi).contains(&l.level));
    if loaded.levels.is_empty() {
        let cut: Vec<String> = loaded
            .cut_by_fov
            .iter()
            .filter(|l| (lo..=hi).contains(*l))
            .map(|l| l.to_string())
            .collect();
        let why = if cut.is_empty() {
            String::new()
        } else {
            format!(" whole ({} cut by the field of view)", cut.join(", "))
        };
        return Err(Error::invalid(
            "--levels",
            format!("no level of {lo}..{hi} in the segmentation{why}"),
        ));
    }
    Ok(())
}

/// Leave out the levels whose surface is not a single plausible vertebra.
pub fn screen(loaded: &mut Loaded) {
    let mut kept: Vec<LevelInput> = Vec::new();
    for mut input in std::mem::take(&mut loaded.levels) {
        match checks::check_shape(input.level, &input.mesh) {
            Verdict::Reject(why) => loaded.findings.push(Finding::new(
                Some(input.level),
                Severity::Warning,
                format!("{} ({}): {why}; level left out", input.level, input.origin),
            )),
            Verdict::Ok {
                mesh,
                dropped_pieces,
            } => {
                if dropped_pieces > 0 {
                    loaded.findings.push(Finding::new(
                        Some(input.level),
                        Severity::Info,
                        format!("{dropped_pieces} small separate piece(s) of the surface ignored"),
                    ));
                }
                input.mesh = mesh;
                kept.push(input);
            }
        }
    }
    let levels: Vec<Level> = kept.iter().map(|l| l.level).collect();
    let parts: Vec<Structure> = kept
        .iter()
        .map(|l| Structure::of_mesh(&l.mesh, l.origin.clone(), false))
        .collect();
    let big = checks::merged(&levels, &parts);
    for (i, ratio) in &big {
        loaded.findings.push(Finding::new(
            Some(levels[*i]),
            Severity::Warning,
            format!(
                "{} ({}): {ratio:.1} times as tall along the spine as its neighbours: two vertebrae in one label (merged labels)?; level left out",
                levels[*i], kept[*i].origin
            ),
        ));
    }
    loaded.levels = kept
        .into_iter()
        .enumerate()
        .filter(|(i, _)| !big.iter().any(|(j, _)| j == i))
        .map(|(_, l)| l)
        .collect();
}

/// A mesh folder's file names against the anatomy ([`evidence`]): a clear
/// contradiction (files swapped, a level misnumbered, a "sacrum" that is a
/// lumbar vertebra) refuses the folder naming the files; doubts are
/// warnings. A label map's names were checked choosing its table.
pub fn check_naming(loaded: &mut Loaded) -> Result<()> {
    if loaded.kind != Kind::MeshFolder {
        return Ok(());
    }
    let parts: Vec<(Place, Structure)> = loaded
        .levels
        .iter()
        .map(|l| {
            (
                Place::Level(l.level),
                Structure::of_mesh(&l.mesh, l.origin.clone(), false),
            )
        })
        .collect();
    let reading = Reading {
        named: parts.iter().map(|(p, s)| (*p, s)).collect(),
        others: Vec::new(),
    };
    let up = loaded.frame.map(|f| frame_axes(f).1);
    let dims = DimensionTable::embedded()?;
    let a = evidence::assess(&reading, up, &dims);
    if !a.consistent() {
        return Err(Error::invalid(
            &loaded.source,
            format!(
                "the files' level names contradict the anatomy: {} (rename the files to the levels they hold)",
                a.problems.join("; ")
            ),
        ));
    }
    for d in a.doubts {
        loaded
            .findings
            .push(Finding::new(None, Severity::Warning, d));
    }
    Ok(())
}

/// Least agreement of the anatomy with a frame for that frame to be taken
/// as detected: the mean of the cosines between the anatomical anterior and
/// cranial directions and the frame's (0.75: both within about 40 deg; a
/// segmentation whose axes are permuted scores about 0.5 in every frame).
const DETECT_MIN_AGREEMENT: f64 = 0.75;

/// The axes of the segmentation: as known (NIfTI world, declared
/// `--frame`), checked against the anatomy; else detected from it.
pub fn world_frame(loaded: &mut Loaded, hints: &[FrameHint]) -> Result<Frame> {
    let ant: Vector3<f64> = hints.iter().map(|h| h.anterior).sum();
    let cra: Vector3<f64> = hints.iter().map(|h| h.cranial).sum();
    let score = |f: Frame| {
        let (a, c) = frame_axes(f);
        (ant.normalize().dot(&a) + cra.normalize().dot(&c)) / 2.0
    };
    let best = Frame::ALL
        .into_iter()
        .max_by(|a, b| score(*a).total_cmp(&score(*b)))
        .unwrap_or(Frame::Lps);
    if hints.is_empty() {
        return loaded
            .frame
            .ok_or_else(|| Error::invalid(&loaded.source, "no level left to palpate"));
    }
    match loaded.frame {
        Some(f) => {
            if best != f && score(f) < 0.5 {
                loaded.findings.push(Finding::new(None, Severity::Warning, format!(
                    "the anatomy (mean anterior and cranial directions) fits the {best} frame better than the {f} frame the segmentation is in (agreement {:.2} vs {:.2})",
                    score(best), score(f)
                )));
            }
            Ok(f)
        }
        None if score(best) < DETECT_MIN_AGREEMENT => {
            let all: Vec<String> = Frame::ALL
                .into_iter()
                .map(|f| format!("{f} {:.2}", score(f)))
                .collect();
            Err(Error::invalid(
                &loaded.source,
                format!(
                    "frame not declared, and the anatomy fits none of the known frames (agreement {}; 1 = axes exactly anatomical, at least {DETECT_MIN_AGREEMENT} needed): the segmentation's axes are not patient axes; give --frame if they are, else rotate it into LPS or RAS",
                    all.join(", ")
                ),
            ))
        }
        None => {
            loaded.findings.push(Finding::new(None, Severity::Info, format!(
                "frame not declared: {best} detected from the anatomy (agreement {:.2}; 1 = axes exactly anatomical)",
                score(best)
            )));
            Ok(best)
        }
    }
}

/// The palpated levels and the landmark set (OpenSim frame, metres).
pub fn assemble(
    mut loaded: Loaded,
    world: Frame,
    results: Vec<(Level, Result<VertebraPalpation>)>,
    opts: &Options,
) -> Result<Palpated> {
    let mut levels = Vec::new();
    let cap = loaded.resolution.map(|r| r.confidence_cap()).unwrap_or(1.0);
    for (input, (_, r)) in loaded.levels.iter().zip(results) {
        if let Some(p) = accept(input, r, cap, &mut loaded.findings) {
            levels.push(p);
        }
    }
    name_missing(&levels, opts, &loaded.cut_by_fov, &mut loaded.findings);
    require_sacrum(&levels, opts, &loaded)?;
    let to_os = world.to_opensim();
    let mut set = LandmarkSet::new();
    for r in &levels {
        for (code, lm) in &r.palpation.landmarks {
            set.insert(r.level, *code, (to_os * lm.point.coords).into());
        }
    }
    let frame = match loaded.kind {
        Kind::LabelMap => opts.frame.unwrap_or(Frame::Ras),
        Kind::MeshFolder => world,
    };
    Ok(Palpated {
        kind: loaded.kind,
        source: loaded.source,
        label_table: loaded.label_table,
        set,
        world,
        units: loaded.units,
        frame,
        levels,
        findings: loaded.findings,
        resolution: loaded.resolution,
        laterals: opts.laterals,
    })
}

/// One level's engine result, or `None` (finding pushed) when it is left out.
fn accept(
    input: &LevelInput,
    r: Result<VertebraPalpation>,
    cap: f64,
    findings: &mut Vec<Finding>,
) -> Option<LevelResult> {
    let level = input.level;
    let p = match r {
        Ok(p) => p,
        Err(e) => {
            findings.push(Finding::new(
                Some(level),
                Severity::Warning,
                format!("palpation failed ({e}); level left out"),
            ));
            return None;
        }
    };
    let mut errors = false;
    for f in &p.findings {
        let severity = match f.severity {
            palpation::Severity::Warning => Severity::Warning,
            palpation::Severity::Error => {
                errors = true;
                Severity::Warning
            }
        };
        findings.push(Finding {
            level: Some(f.level),
            code: f.code,
            severity,
            message: f.message.clone(),
        });
    }
    let missing: Vec<String> = level
        .required_codes()
        .iter()
        .filter(|c| !p.landmarks.contains_key(c))
        .map(|c| c.to_string())
        .collect();
    if errors || !missing.is_empty() {
        let why = if errors {
            "the engine reported errors".to_string()
        } else {
            format!("no {}", missing.join(", "))
        };
        findings.push(Finding::new(
            Some(level),
            Severity::Warning,
            format!("{level}: {why}; level left out"),
        ));
        return None;
    }
    Some(with_distances(input, p, cap, findings))
}

/// Distance of each landmark to the surface; low confidence flagged (by
/// the palpation: a cap from the voxel size is said once, by the map).
fn with_distances(
    input: &LevelInput,
    mut p: VertebraPalpation,
    cap: f64,
    findings: &mut Vec<Finding>,
) -> LevelResult {
    let query = MeshQuery::new(&input.mesh).ok();
    let mut distance = std::collections::BTreeMap::new();
    for (code, lm) in p.landmarks.iter_mut() {
        let own = lm.confidence;
        if own > cap {
            lm.confidence = cap;
            let why = format!("capped at {cap:.2} by the label map's voxel size");
            lm.note = Some(match lm.note.take() {
                Some(n) => format!("{n}; {why}"),
                None => why,
            });
        }
        if let Some(q) = &query {
            distance.insert(*code, q.distance(&lm.point));
        }
        if own < UNCERTAIN {
            findings.push(Finding {
                level: Some(input.level),
                code: Some(*code),
                severity: Severity::Warning,
                message: format!(
                    "{}_{code} uncertain (confidence {:.2}){}",
                    input.level,
                    own,
                    lm.note
                        .as_deref()
                        .map(|n| format!(": {n}"))
                        .unwrap_or_default()
                ),
            });
        }
    }
    LevelResult {
        level: input.level,
        origin: input.origin.clone(),
        mesh: input.mesh.clone(),
        palpation: p,
        distance,
    }
}

/// The levels of the wanted range that are not in the set, in one
/// warning: those between palpated levels (gaps, which `generate` fills
/// from their neighbours), those cut by the field of view, and the others
/// (above or below what the segmentation holds whole).
fn name_missing(
    levels: &[LevelResult],
    opts: &Options,
    cut: &[Level],
    findings: &mut Vec<Finding>,
) {
    let (lo, hi) = opts
        .levels
        .map(|(a, b)| (a.min(b), a.max(b)))
        .unwrap_or((Level::T1, Level::S1));
    let have = |l: &Level| levels.iter().any(|r| r.level == *l);
    let (Some(top), Some(bottom)) = (levels.first(), levels.last()) else {
        return;
    };
    let missing: Vec<Level> = Level::ALL
        .into_iter()
        .filter(|l| (lo..=hi).contains(l) && !have(l))
        .collect();
    let names = |f: &dyn Fn(&Level) -> bool| -> Vec<String> {
        missing
            .iter()
            .filter(|l| f(l))
            .map(|l| l.to_string())
            .collect()
    };
    let inside = |l: &Level| *l > top.level && *l < bottom.level;
    let gaps = names(&|l| inside(l));
    let fov = names(&|l| cut.contains(l) && !inside(l));
    let rest = names(&|l| !(cut.contains(l) || inside(l)));
    let mut parts = Vec::new();
    if !gaps.is_empty() {
        parts.push(format!(
            "{} between palpated levels (a gap: `generate` fills it from its neighbours)",
            gaps.join(" ")
        ));
    }
    if !fov.is_empty() {
        parts.push(format!("{} cut by the field of view", fov.join(" ")));
    }
    if !rest.is_empty() {
        parts.push(format!("{} not in the segmentation whole", rest.join(" ")));
    }
    if !parts.is_empty() {
        findings.push(Finding::new(
            None,
            Severity::Warning,
            format!("levels not in the landmark set: {}", parts.join("; ")),
        ));
    }
}

/// The sacrum must be palpated when the wanted range includes it.
fn require_sacrum(levels: &[LevelResult], opts: &Options, loaded: &Loaded) -> Result<()> {
    let wants = opts
        .levels
        .map(|(a, b)| a.max(b) == Level::S1)
        .unwrap_or(true);
    if wants && !levels.iter().any(|r| r.level == Level::S1) {
        let why: Vec<String> = loaded
            .findings
            .iter()
            .filter(|f| f.level == Some(Level::S1))
            .map(|f| f.message.clone())
            .collect();
        return Err(Error::invalid(
            &loaded.source,
            format!(
                "no sacrum palpated{}: a landmark set ends at S1 (give --levels ..L5 to palpate without it)",
                if why.is_empty() { " (none in the segmentation)".to_string() } else { format!(" ({})", why.join("; ")) }
            ),
        ));
    }
    Ok(())
}
