//! The vertebral body in the vertebra's local frame (X anterior, Y cranial,
//! Z right, the mid-sagittal plane is `z = 0`): its walls, its endplate
//! regions and the endplate landmarks (centre, mid-sagittal ends, lateral
//! extremes).

use super::local::{clip_polygon, closest_on_segment, polygon_section, LocalMesh};
use crate::mesh::{MeshQuery, TriMesh};
use crate::util::median;
use nalgebra::{Point3, Vector3};
use parry3d_f64::query::PointQuery;
use parry3d_f64::shape::Triangle;

/// Walls of the vertebral body (local coordinates, m).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Walls {
    pub x_ant: f64,
    pub x_post: f64,
    pub z_right: f64,
    pub z_left: f64,
    /// Height range of the anterior part of the mesh.
    pub y_lo: f64,
    pub y_hi: f64,
}

impl Walls {
    pub(crate) fn depth(&self) -> f64 {
        self.x_ant - self.x_post
    }
    pub(crate) fn half_width(&self) -> f64 {
        0.5 * (self.z_right - self.z_left)
    }
    pub(crate) fn height(&self) -> f64 {
        self.y_hi - self.y_lo
    }
    pub(crate) fn y_mid(&self) -> f64 {
        0.5 * (self.y_hi + self.y_lo)
    }
    /// X range of the body column (walls with a margin of 4 % of the depth).
    pub(crate) fn column_x(&self) -> (f64, f64) {
        let m = 0.04 * self.depth();
        (self.x_post - m, self.x_ant + m)
    }
}

/// Anterior and posterior walls by rays along -X through the body on and
/// beside the midline; lateral walls by rays along -Z/+Z from outside.
/// `q` is the query structure of the mesh `lm` was made from, in that
/// mesh's coordinates (built once per vertebra, whatever the trial frame):
/// the rays are cast in those coordinates and their crossings mapped back.
pub(crate) fn find_walls(lm: &LocalMesh, q: &MeshQuery) -> Option<Walls> {
    // Crossings of the local ray `o + t d` (the same `t` in both frames:
    // the frame change is rigid), as local points.
    let crossings = |o: Point3<f64>, d: Vector3<f64>| -> Vec<Point3<f64>> {
        let (ow, dw) = (lm.to_mesh * o, lm.to_mesh.rotation * d);
        q.ray_hits(&ow, &dw, f64::MAX)
            .into_iter()
            .map(|hit| o + d * hit.t)
            .collect()
    };
    let x_max = lm.verts.iter().map(|p| p.x).fold(f64::MIN, f64::max);
    let x_min = lm.verts.iter().map(|p| p.x).fold(f64::MAX, f64::min);
    let span = x_max - x_min;
    // Height of the anterior quarter of the mesh (the body's front).
    let front: Vec<f64> = lm
        .verts
        .iter()
        .filter(|p| p.x > x_max - 0.25 * span)
        .map(|p| p.y)
        .collect();
    let y_lo = front.iter().copied().fold(f64::MAX, f64::min);
    let y_hi = front.iter().copied().fold(f64::MIN, f64::max);
    let h = y_hi - y_lo;
    if h.is_nan() || h <= 0.0 {
        return None;
    }
    let y0 = 0.5 * (y_lo + y_hi);
    let (mut xa, mut xp) = (Vec::new(), Vec::new());
    for dy in [-0.25, -0.125, 0.0, 0.125, 0.25] {
        for z in [0.0, 0.12 * h, -0.12 * h] {
            let o = Point3::new(x_max + 0.1 * span, y0 + dy * h, z);
            let hits = crossings(o, -Vector3::x());
            if hits.len() >= 2 {
                xa.push(hits[0].x);
                xp.push(hits[1].x);
            }
        }
    }
    let (x_ant, x_post) = (median(&xa)?, median(&xp)?);
    let xc = 0.5 * (x_ant + x_post);
    let side = |dir: f64| {
        let zs: Vec<f64> = [-0.15, 0.0, 0.15]
            .iter()
            .filter_map(|dy| {
                let o = Point3::new(xc, y0 + dy * h, dir * 2.0 * span);
                crossings(o, Vector3::new(0.0, 0.0, -dir))
                    .first()
                    .map(|p| p.z)
            })
            .collect();
        median(&zs)
    };
    Some(Walls {
        x_ant,
        x_post,
        z_right: side(1.0)?,
        z_left: side(-1.0)?,
        y_lo,
        y_hi,
    })
}

/// One endplate region.
#[derive(Debug, Clone)]
pub(crate) struct Endplate {
    /// Faces of the region.
    pub faces: Vec<usize>,
    /// Outward unit normal (local; cranial for the superior endplate).
    pub normal: Vector3<f64>,
    /// Plane offset: `normal . p = offset`.
    pub offset: f64,
    /// Region area (m^2).
    pub area: f64,
    /// Half-thickness of the slab about the plane that the faces were
    /// selected in (m).
    pub tol: f64,
}

/// The protocol's bound on the angle between an endplate face's normal and
/// the endplate's (deg).
pub(crate) const ENDPLATE_MAX_ANGLE_DEG: f64 = 40.0;

/// The endplate region by the protocol: body faces within
/// [`ENDPLATE_MAX_ANGLE_DEG`] of the endplate normal, within a few mm of
/// its plane, between the walls.
pub(crate) fn find_endplate(lm: &LocalMesh, w: &Walls, superior: bool) -> Option<Endplate> {
    find_endplate_within(lm, w, superior, ENDPLATE_MAX_ANGLE_DEG)
}

/// [`find_endplate`] with another bound on the faces' angle (deg).
pub(crate) fn find_endplate_within(
    lm: &LocalMesh,
    w: &Walls,
    superior: bool,
    max_angle_deg: f64,
) -> Option<Endplate> {
    let s = if superior { 1.0 } else { -1.0 };
    let cos_max = max_angle_deg.to_radians().cos();
    let margin = 0.04 * w.depth();
    let tol = (0.1 * w.height()).max(0.003);
    let in_column = |c: &Point3<f64>| {
        c.x >= w.x_post - margin
            && c.x <= w.x_ant + margin
            && c.z <= w.z_right + margin
            && c.z >= w.z_left - margin
            && s * (c.y - w.y_mid()) > 0.0
    };
    let mut normal = Vector3::y() * s;
    let mut plane: Option<f64> = None;
    let mut faces = Vec::new();
    for _ in 0..3 {
        faces = (0..lm.tris.len())
            .filter(|&f| {
                let c = &lm.centroids[f];
                lm.normals[f].dot(&normal) >= cos_max
                    && in_column(c)
                    && plane.is_none_or(|d| (normal.dot(&c.coords) - d).abs() <= tol)
            })
            .collect();
        let area: f64 = faces.iter().map(|&f| lm.areas[f]).sum();
        if faces.is_empty() || area.is_nan() || area <= 0.0 {
            return None;
        }
        let n = faces
            .iter()
            .fold(Vector3::zeros(), |a, &f| a + lm.normals[f] * lm.areas[f]);
        normal = n.try_normalize(1e-12)?;
        // Plane offset: the area-weighted median height of the faces, but
        // on the first pass the outermost faces (the endplate is the cap).
        let mut hs: Vec<(f64, f64)> = faces
            .iter()
            .map(|&f| (normal.dot(&lm.centroids[f].coords), lm.areas[f]))
            .collect();
        hs.sort_by(|a, b| a.0.total_cmp(&b.0));
        let target = if plane.is_none() { 0.5 + 0.25 } else { 0.5 };
        let mut acc = 0.0;
        let d = hs.iter().find(|(_, a)| {
            acc += a;
            acc >= target * area
        });
        plane = d.map(|x| x.0);
    }
    let area = faces.iter().map(|&f| lm.areas[f]).sum();
    Some(Endplate {
        faces,
        normal,
        offset: plane?,
        area,
        tol,
    })
}

/// Depth of the lateral rim, as a fraction of the region's half-width: the
/// part of the region within it of the most lateral point is the rim,
/// whose middle (along X) is where the landmark is taken. On the label
/// dev label maps, 0.1-0.2 give worst 2.3-2.6 mm; 0.05 lets T1's
/// landmark slide 7 mm along a flat voxel rim.
const LATERAL_BAND: f64 = 0.15;

/// Half-thickness of the slab about the endplate plane that bounds the
/// lateral rim, as a multiple of the region's selection tolerance: a face
/// whose centroid is near the plane may reach below it into a pedicle root
/// (a 250-vertex L5's did, 7 mm below, with 1.5 tolerances).
const LATERAL_SLAB: f64 = 1.0;

/// The region as polygons (one per face, local coordinates), cut to the
/// slab `|normal . p - offset| <= slab` about the endplate plane and to
/// the X range `x_range`: a face whose centroid is near the plane may
/// reach below it into a pedicle root, or past the walls. Faces wholly
/// outside are dropped.
fn region_polygons(
    lm: &LocalMesh,
    ep: &Endplate,
    slab: f64,
    x_range: (f64, f64),
) -> Vec<Vec<Point3<f64>>> {
    let n = ep.normal;
    let x = Vector3::x();
    ep.faces
        .iter()
        .map(|&f| lm.tris[f].iter().map(|&k| lm.verts[k as usize]).collect())
        .map(|poly: Vec<Point3<f64>>| clip_polygon(&poly, &n, ep.offset + slab))
        .map(|poly| clip_polygon(&poly, &-n, -(ep.offset - slab)))
        .map(|poly| clip_polygon(&poly, &x, x_range.1))
        .map(|poly| clip_polygon(&poly, &-x, -x_range.0))
        .filter(|poly| poly.len() >= 3)
        .collect()
}

/// Fan triangles of the polygons.
fn fan(polys: &[Vec<Point3<f64>>]) -> impl Iterator<Item = Triangle> + '_ {
    polys
        .iter()
        .flat_map(|p| (1..p.len() - 1).map(move |k| Triangle::new(p[0], p[k], p[k + 1])))
}

/// The lateral landmark on `side` (+1 right,
/// -1 left): the part of the region within `LATERAL_BAND x half-width` of
/// its extreme is the lateral rim; the landmark is the region's outermost
/// point at the X of that rim's area centroid, so that it does not slide
/// along a flat rim with surface noise or voxel steps.
fn rim_middle(polys: &[Vec<Point3<f64>>], side: f64) -> Option<Point3<f64>> {
    let (lo, hi) = polys
        .iter()
        .flatten()
        .fold((f64::MAX, f64::MIN), |(lo, hi), p| {
            (lo.min(side * p.z), hi.max(side * p.z))
        });
    let band = LATERAL_BAND * 0.5 * (hi - lo);
    // The lateral rim: the region cut to side * z >= hi - band.
    let n = Vector3::z() * -side;
    let rim: Vec<Vec<Point3<f64>>> = polys
        .iter()
        .map(|p| clip_polygon(p, &n, band - hi))
        .filter(|p| p.len() >= 3)
        .collect();
    let (sum, area) = fan(&rim).fold((Vector3::zeros(), 0.0), |(s, a), t| {
        let w = t.area();
        (s + t.center().coords * w, a + w)
    });
    // A rim of no area (an edge-on sliver): its outermost point.
    if area.is_nan() || area <= 0.0 {
        return polys
            .iter()
            .flatten()
            .copied()
            .max_by(|a, b| (side * a.z).total_cmp(&(side * b.z)));
    }
    // Where along the rim: its area centroid's X; the landmark is the
    // region's outermost point at that X.
    let cx = sum.x / area;
    rim.iter()
        .flat_map(|p| polygon_section(p, 0, cx))
        .max_by(|a, b| (side * a.z).total_cmp(&(side * b.z)))
        .or_else(|| {
            let c = Point3::from(sum / area);
            fan(&rim)
                .map(|t| t.project_local_point(&c, true).point)
                .min_by(|a, b| (a - c).norm().total_cmp(&(b - c).norm()))
        })
}

/// The most lateral points of the endplate region (right, left), inside
/// `x_range` (the whole region if nothing is): the middles of its lateral
/// rims ([`rim_middle`]), within `LATERAL_SLAB` tolerances of the plane.
/// The literal "furthest point" is ill-posed on a flat lateral rim: a
/// coarse mesh's furthest vertex may sit at either end of a rim edge that
/// is level to 0.1 mm, and a voxel surface's at any step; the rim's middle
/// is the same point on a mesh, its decimation and its label map.
fn lateral_extremes(
    lm: &LocalMesh,
    ep: &Endplate,
    x_range: (f64, f64),
) -> Option<[Point3<f64>; 4]> {
    let mut polys = region_polygons(lm, ep, LATERAL_SLAB * ep.tol, x_range);
    if polys.is_empty() {
        polys = region_polygons(lm, ep, f64::MAX, (f64::MIN, f64::MAX));
    }
    let furthest = |side: f64| {
        polys
            .iter()
            .flatten()
            .copied()
            .max_by(|a, b| (side * a.z).total_cmp(&(side * b.z)))
    };
    Some([
        rim_middle(&polys, 1.0)?,
        rim_middle(&polys, -1.0)?,
        furthest(1.0)?,
        furthest(-1.0)?,
    ])
}

/// Landmarks of one endplate (local): centre, anterior, posterior, right,
/// left, and whether the mid-sagittal section was found.
pub(crate) struct EndplatePoints {
    pub centre: Point3<f64>,
    pub front: Point3<f64>,
    pub back: Point3<f64>,
    pub right: Point3<f64>,
    pub left: Point3<f64>,
    /// The literal furthest points of the region to the right and left
    /// (a vertex of a coarse mesh, either end of a flat rim).
    pub furthest_right: Point3<f64>,
    pub furthest_left: Point3<f64>,
    pub midline_section: bool,
}

/// SEC/IEC (area centroid moved to the nearest point of the region's
/// mid-sagittal section, so on the surface and on the plane; the nearest
/// region point where the region has no section), SA/SP (ends of the
/// region's mid-sagittal section), SR/SL ([`lateral_extremes`]; with
/// `column`, only the region between those X bounds and not behind the
/// section's posterior end: a large face of a coarse mesh may reach past
/// the walls into a pedicle, and a pedicle root may be as lateral as the
/// rim; the sacrum, with no walls, passes an unbounded column).
pub(crate) fn endplate_points(
    lm: &LocalMesh,
    ep: &Endplate,
    column: Option<(f64, f64)>,
) -> Option<EndplatePoints> {
    let region: TriMesh = lm.submesh(&ep.faces);
    // Area centroid of the region.
    let c = Point3::from(
        ep.faces.iter().fold(Vector3::zeros(), |a, &f| {
            a + lm.centroids[f].coords * lm.areas[f]
        }) / ep.area,
    );
    // The mid-sagittal section: the centre on it, its two ends.
    let section = lm.cut_segments(ep.faces.iter().copied(), 2, 0.0);
    let midline_section = !section.is_empty();
    // Lateral extremes inside the column and not behind the endplate's
    // posterior end (there the pedicle roots join the body, on a small
    // vertebra as far out as the rim).
    let x_back = section
        .iter()
        .flatten()
        .map(|p| p.x)
        .reduce(f64::min)
        .unwrap_or(f64::MIN);
    let x_range = column.map_or((f64::MIN, f64::MAX), |(lo, hi)| (lo.max(x_back), hi));
    let [right, left, furthest_right, furthest_left] = lateral_extremes(lm, ep, x_range)?;
    let centre = match section
        .iter()
        .map(|[a, b]| closest_on_segment(&c, a, b))
        .min_by(|a, b| (a - c).norm().total_cmp(&(b - c).norm()))
    {
        Some(p) => p,
        None => MeshQuery::new(&region).ok()?.closest_point(&c).point,
    };
    let pts: Vec<Point3<f64>> = if midline_section {
        section.into_iter().flatten().collect()
    } else {
        region.vertices
    };
    let front = pts
        .iter()
        .copied()
        .max_by(|a, b| (a.x - a.z.abs()).total_cmp(&(b.x - b.z.abs())))?;
    let back = pts
        .iter()
        .copied()
        .max_by(|a, b| (-a.x - a.z.abs()).total_cmp(&(-b.x - b.z.abs())))?;
    Some(EndplatePoints {
        centre,
        front,
        back,
        right,
        left,
        furthest_right,
        furthest_left,
        midline_section,
    })
}
