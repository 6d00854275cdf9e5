//! Plausibility of each level's surface before palpation: the pieces of
//! the surface (two vertebrae in one label may come as two pieces of
//! similar size), its size against a vertebra's, and its height along the
//! spine against its neighbours' (a label holding two vertebrae is about
//! twice as tall as one; a volume ratio says little, adjacent vertebrae
//! differ by up to 2.5 times). A failing level is left out with a named
//! warning.

use super::evidence::Structure;
use crate::landmarks::Level;
use crate::mesh::TriMesh;

/// Smallest and largest enclosed volume of a T1..L5 vertebra or the
/// sacrum (m^3): 3 cm^3 to 300 cm^3 (thoracic vertebrae are about
/// 15-30 cm^3, lumbar 40-70 cm^3, a sacrum up to about 200 cm^3).
const VOLUME_RANGE: (f64, f64) = (3e-6, 3e-4);
/// Largest bounding-box diagonal of a vertebra or sacrum (m).
const MAX_DIAGONAL: f64 = 0.25;
/// Smallest bounding-box diagonal (m).
const MIN_DIAGONAL: f64 = 0.03;
/// A piece holding at least this fraction of the largest piece's area
/// counts as a vertebra-sized piece; smaller ones are segmentation debris.
const PIECE_FRACTION: f64 = 0.2;
/// Height along the spine over the mean of the neighbours' beyond which a
/// label is taken for two vertebrae (one vertebra is 0.8-1.25 times its
/// neighbours' height; two in one label about twice).
const MERGED_RATIO: f64 = 1.6;

/// Connected pieces of a mesh (triangles sharing vertices), largest area first.
pub fn pieces(m: &TriMesh) -> Vec<TriMesh> {
    let n = m.vertices.len();
    let mut parent: Vec<u32> = (0..n as u32).collect();
    fn find(p: &mut [u32], mut x: u32) -> u32 {
        while p[x as usize] != x {
            p[x as usize] = p[p[x as usize] as usize];
            x = p[x as usize];
        }
        x
    }
    for t in &m.triangles {
        let a = find(&mut parent, t[0]);
        for &k in &t[1..] {
            let b = find(&mut parent, k);
            parent[b as usize] = a;
        }
    }
    let mut groups: std::collections::BTreeMap<u32, Vec<[u32; 3]>> = Default::default();
    for t in &m.triangles {
        let r = find(&mut parent, t[0]);
        groups.entry(r).or_default().push(*t);
    }
    let mut out: Vec<TriMesh> = groups
        .into_values()
        .map(|tris| TriMesh {
            vertices: m.vertices.clone(),
            triangles: tris,
        })
        .map(|p| compact(&p))
        .collect();
    out.sort_by(|a, b| b.area().total_cmp(&a.area()));
    out
}

/// The mesh without unreferenced vertices.
fn compact(m: &TriMesh) -> TriMesh {
    let mut map = vec![u32::MAX; m.vertices.len()];
    let mut vertices = Vec::new();
    let triangles = m
        .triangles
        .iter()
        .map(|t| {
            t.map(|k| {
                if map[k as usize] == u32::MAX {
                    map[k as usize] = vertices.len() as u32;
                    vertices.push(m.vertices[k as usize]);
                }
                map[k as usize]
            })
        })
        .collect();
    TriMesh {
        vertices,
        triangles,
    }
}

/// The verdict on one level's surface.
#[derive(Debug, Clone, PartialEq)]
pub enum Verdict {
    /// Fit to palpate (debris pieces dropped, if any: their count).
    Ok {
        /// The surface to palpate.
        mesh: TriMesh,
        /// Number of debris pieces dropped.
        dropped_pieces: usize,
    },
    /// Left out, with the reason.
    Reject(String),
}

/// Pieces and size of one level's surface. Pieces whose bounding boxes
/// touch (within [`TOUCH`]) belong together (a vertebra may be modelled
/// as overlapping shells); two vertebra-sized groups apart are two
/// vertebrae in one label.
pub fn check_shape(level: Level, m: &TriMesh) -> Verdict {
    let parts = pieces(m);
    let Some(largest) = parts.first() else {
        return Verdict::Reject("empty surface".into());
    };
    let big_area = PIECE_FRACTION * largest.area();
    let groups = group_touching(&parts);
    let big = groups
        .iter()
        .filter(|g| g.iter().map(|&i| parts[i].area()).sum::<f64>() >= big_area)
        .count();
    if big > 1 && !level.is_sacrum() {
        return Verdict::Reject(format!(
            "{big} separate parts of vertebral size: two vertebrae in one label (merged labels)?"
        ));
    }
    let main = groups
        .iter()
        .max_by(|a, b| group_area(&parts, a).total_cmp(&group_area(&parts, b)))
        .cloned()
        .unwrap_or_default();
    let kept: Vec<&TriMesh> = main.iter().map(|&i| &parts[i]).collect();
    let mesh = TriMesh::merge(&kept).unwrap_or_else(|_| largest.clone());
    let v = mesh.signed_volume();
    let diag = mesh.bounds().map(|(a, b)| (b - a).norm()).unwrap_or(0.0);
    if !(VOLUME_RANGE.0..=VOLUME_RANGE.1).contains(&v)
        || !(MIN_DIAGONAL..=MAX_DIAGONAL).contains(&diag)
    {
        return Verdict::Reject(format!(
            "volume {:.1} cm^3 and size {:.0} mm are not those of a vertebra ({:.0}-{:.0} cm^3, {:.0}-{:.0} mm): not a vertebra, or wrong units?",
            v * 1e6,
            diag * 1e3,
            VOLUME_RANGE.0 * 1e6,
            VOLUME_RANGE.1 * 1e6,
            MIN_DIAGONAL * 1e3,
            MAX_DIAGONAL * 1e3
        ));
    }
    Verdict::Ok {
        mesh,
        dropped_pieces: parts.len() - kept.len(),
    }
}

/// Gap (m) under which two pieces' bounding boxes count as touching.
const TOUCH: f64 = 0.002;

/// Total area of a group of pieces.
fn group_area(parts: &[TriMesh], g: &[usize]) -> f64 {
    g.iter().map(|&i| parts[i].area()).sum()
}

/// Groups of pieces (indices) whose bounding boxes touch, transitively.
fn group_touching(parts: &[TriMesh]) -> Vec<Vec<usize>> {
    let boxes: Vec<_> = parts.iter().filter_map(|p| p.bounds()).collect();
    let touch = |a: usize, b: usize| {
        (0..3).all(|k| {
            boxes[a].0[k] <= boxes[b].1[k] + TOUCH && boxes[b].0[k] <= boxes[a].1[k] + TOUCH
        })
    };
    let mut group: Vec<usize> = (0..boxes.len()).collect();
    let mut changed = true;
    while changed {
        changed = false;
        for a in 0..boxes.len() {
            for b in 0..boxes.len() {
                if group[a] != group[b] && touch(a, b) {
                    let (lo, hi) = (group[a].min(group[b]), group[a].max(group[b]));
                    group.iter_mut().filter(|g| **g == hi).for_each(|g| *g = lo);
                    changed = true;
                }
            }
        }
    }
    let mut out: std::collections::BTreeMap<usize, Vec<usize>> = Default::default();
    for (i, g) in group.into_iter().enumerate() {
        out.entry(g).or_default().push(i);
    }
    out.into_values().collect()
}

/// Levels (index into `levels`, cranial to caudal) whose height along the
/// spine (the line through their neighbours' centroids) exceeds
/// [`MERGED_RATIO`] times their neighbours' (within two levels, the
/// sacrum excluded): likely two vertebrae in one label.
pub fn merged(levels: &[Level], parts: &[Structure]) -> Vec<(usize, f64)> {
    let n = levels.len();
    let mut out = Vec::new();
    for i in 0..n {
        if levels[i].is_sacrum() || parts[i].truncated {
            continue;
        }
        let nb: Vec<usize> = [i.checked_sub(1), (i + 1 < n).then_some(i + 1)]
            .into_iter()
            .flatten()
            .filter(|&j| !levels[j].is_sacrum() && !parts[j].truncated)
            .filter(|&j| levels[j].index().abs_diff(levels[i].index()) <= 2)
            .collect();
        let (Some(&a), Some(&b)) = (nb.first(), nb.last()) else {
            continue;
        };
        let (top, bottom) = if a == b { (i.min(a), i.max(a)) } else { (a, b) };
        let Some(u) = (parts[top].centroid - parts[bottom].centroid).try_normalize(1e-9) else {
            continue;
        };
        let mean = nb.iter().map(|&j| parts[j].extent(&u)).sum::<f64>() / nb.len() as f64;
        let r = parts[i].extent(&u) / mean.max(1e-9);
        if r > MERGED_RATIO {
            out.push((i, r));
        }
    }
    out
}
