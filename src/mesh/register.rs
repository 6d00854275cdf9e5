//! Rigid and similarity registration.
//!
//! * [`umeyama`] / [`kabsch`]: closed-form best similarity / rigid motion
//!   for point correspondences.
//! * [`icp`] / [`icp_mesh`]: iterative closest point onto a target surface
//!   (a [`MeshQuery`]) without correspondences. The initial alignment tries
//!   the 24 proper signed permutations of the principal-axis frames (a short
//!   refinement on a subsample for each, then full refinement of the best
//!   few) and keeps the lowest trimmed RMS. Each refinement step solves the
//!   linearised point-to-plane problem plus a lightly weighted point-to-point
//!   term, rejecting the worst pairs (trimmed ICP) so that partial overlap
//!   works.
//! * [`affine_icp`]: iterative closest point with a general affine map
//!   (rotation, anisotropic scale, shear), from a given start: carries a
//!   template's points onto a patient's differently proportioned bone.
//! * [`Residuals`]: surface-distance statistics (RMS, max, percentiles).
//! * [`gpa`] / [`gpa_meshes`]: generalised Procrustes analysis of shapes in
//!   vertex correspondence, giving the mean shape.

use super::geom::{point_principal_axes, PrincipalAxes};
use super::{MeshQuery, TriMesh};
use crate::error::{Error, Result};
use crate::util::quantiles::quantile;
use nalgebra::{Matrix3, Matrix4, Point3, Rotation3, SMatrix, SVector, UnitQuaternion, Vector3};

/// A similarity transform `p -> scale * R p + translation`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Similarity {
    /// Rotation.
    pub rotation: UnitQuaternion<f64>,
    /// Translation (m).
    pub translation: Vector3<f64>,
    /// Uniform scale factor (1 for a rigid motion).
    pub scale: f64,
}

impl Default for Similarity {
    fn default() -> Self {
        Similarity::identity()
    }
}

impl Similarity {
    /// The identity.
    pub fn identity() -> Similarity {
        Similarity {
            rotation: UnitQuaternion::identity(),
            translation: Vector3::zeros(),
            scale: 1.0,
        }
    }
    /// Apply to a point.
    pub fn apply(&self, p: &Point3<f64>) -> Point3<f64> {
        Point3::from(self.scale * (self.rotation * p.coords) + self.translation)
    }
    /// `self` after `other`: `p -> self(other(p))`.
    pub fn compose(&self, other: &Similarity) -> Similarity {
        Similarity {
            rotation: self.rotation * other.rotation,
            translation: self.scale * (self.rotation * other.translation) + self.translation,
            scale: self.scale * other.scale,
        }
    }
    /// The inverse transform.
    pub fn inverse(&self) -> Similarity {
        let r = self.rotation.inverse();
        Similarity {
            rotation: r,
            translation: -(r * self.translation) / self.scale,
            scale: 1.0 / self.scale,
        }
    }
    /// Homogeneous 4x4 matrix.
    pub fn to_matrix(&self) -> Matrix4<f64> {
        let mut m = Matrix4::identity();
        let r = self.rotation.to_rotation_matrix().into_inner() * self.scale;
        m.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
        m.fixed_view_mut::<3, 1>(0, 3).copy_from(&self.translation);
        m
    }
    /// Apply to every vertex of a mesh (re-winding if the scale were
    /// negative, which [`umeyama`] never produces).
    pub fn apply_mesh(&self, mesh: &TriMesh) -> TriMesh {
        TriMesh {
            vertices: mesh.vertices.iter().map(|p| self.apply(p)).collect(),
            triangles: mesh.triangles.clone(),
        }
    }
}

/// Best similarity (or rigid motion if `!with_scale`) mapping `src` onto
/// `dst` in the least-squares sense (Umeyama 1991). Needs at least three
/// corresponding, non-collinear points.
pub fn umeyama(src: &[Point3<f64>], dst: &[Point3<f64>], with_scale: bool) -> Result<Similarity> {
    let ctx = "point registration";
    if src.len() != dst.len() {
        return Err(Error::invalid(
            ctx,
            format!(
                "{} source points but {} target points",
                src.len(),
                dst.len()
            ),
        ));
    }
    if src.len() < 3 {
        return Err(Error::invalid(
            ctx,
            "at least 3 corresponding points are needed",
        ));
    }
    let n = src.len() as f64;
    let ms = src.iter().fold(Vector3::zeros(), |a, p| a + p.coords) / n;
    let md = dst.iter().fold(Vector3::zeros(), |a, p| a + p.coords) / n;
    let mut cov = Matrix3::zeros();
    let mut var_s = 0.0;
    for (s, d) in src.iter().zip(dst) {
        let (a, b) = (s.coords - ms, d.coords - md);
        cov += b * a.transpose();
        var_s += a.norm_squared();
    }
    cov /= n;
    var_s /= n;
    if !cov.iter().all(|x| x.is_finite()) || var_s <= 0.0 {
        return Err(Error::invalid(ctx, "degenerate or non-finite points"));
    }
    let svd = cov.svd(true, true);
    let (Some(u), Some(vt)) = (svd.u, svd.v_t) else {
        return Err(Error::numerical(ctx, "SVD failed"));
    };
    let mut sv = svd.singular_values;
    // Order singular values descending for the rank test.
    let mut sorted = [sv[0], sv[1], sv[2]];
    sorted.sort_by(|a, b| b.total_cmp(a));
    if sorted[1] <= 1e-12 * sorted[0].max(f64::MIN_POSITIVE) {
        return Err(Error::invalid(
            ctx,
            "the points are collinear: the rotation is not determined",
        ));
    }
    let d = if (u.determinant() * vt.determinant()) < 0.0 {
        -1.0
    } else {
        1.0
    };
    // Flip the direction of the smallest singular value.
    let imin = (0..3).min_by(|&a, &b| sv[a].total_cmp(&sv[b])).unwrap_or(2);
    let mut s = Matrix3::identity();
    s[(imin, imin)] = d;
    let r = u * s * vt;
    sv[imin] *= d;
    let scale = if with_scale { sv.sum() / var_s } else { 1.0 };
    let rot = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r));
    Ok(Similarity {
        rotation: rot,
        translation: md - scale * (rot * ms),
        scale,
    })
}

/// Best rigid motion mapping `src` onto `dst` (Kabsch).
pub fn kabsch(src: &[Point3<f64>], dst: &[Point3<f64>]) -> Result<Similarity> {
    umeyama(src, dst, false)
}

/// Statistics of distances (m).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Residuals {
    /// Number of distances.
    pub n: usize,
    /// Root mean square.
    pub rms: f64,
    /// Mean.
    pub mean: f64,
    /// Maximum.
    pub max: f64,
    /// Median.
    pub p50: f64,
    /// 90th percentile.
    pub p90: f64,
    /// 95th percentile.
    pub p95: f64,
    /// 99th percentile.
    pub p99: f64,
}

impl Residuals {
    /// Statistics of `d` (percentiles by the crate's one convention, R's
    /// type 7: [`crate::util::quantiles::quantile`]); all zero if empty or
    /// holding a NaN.
    fn from_distances(d: &[f64]) -> Residuals {
        let pct = |p: f64| quantile(d, p);
        let (Some(p50), Some(p90), Some(p95), Some(p99), Some(max)) =
            (pct(0.5), pct(0.9), pct(0.95), pct(0.99), pct(1.0))
        else {
            return Residuals::default();
        };
        let n = d.len();
        Residuals {
            n,
            rms: (d.iter().map(|x| x * x).sum::<f64>() / n as f64).sqrt(),
            mean: d.iter().sum::<f64>() / n as f64,
            max,
            p50,
            p90,
            p95,
            p99,
        }
    }

    /// Distances from `points` to the surface of `target`.
    pub fn to_surface(points: &[Point3<f64>], target: &MeshQuery) -> Residuals {
        let d: Vec<f64> = points.iter().map(|p| target.distance(p)).collect();
        Residuals::from_distances(&d)
    }
}

/// Options for [`icp`].
#[derive(Debug, Clone, PartialEq)]
pub struct IcpOptions {
    /// Estimate a uniform scale too (similarity registration).
    pub allow_scale: bool,
    /// Fraction of the closest pairs kept at each iteration (trimmed ICP);
    /// 1.0 keeps all. Lower it when the source overlaps the target only
    /// partly (e.g. 0.7 for a source with extra parts).
    pub keep_fraction: f64,
    /// Maximum refinement iterations.
    pub max_iterations: usize,
    /// Stop when the trimmed RMS improves by less than this fraction.
    pub tolerance: f64,
    /// Start from this transform instead of the principal-axes search.
    pub initial: Option<Similarity>,
    /// Source points used for the initial-alignment search.
    pub search_points: usize,
    /// Refinement iterations per initial candidate on the subsample.
    pub search_iterations: usize,
    /// Candidates (best after the subsample stage) refined fully; the one
    /// with the lowest trimmed RMS wins.
    pub search_keep: usize,
}

impl Default for IcpOptions {
    fn default() -> Self {
        IcpOptions {
            allow_scale: false,
            keep_fraction: 0.9,
            max_iterations: 200,
            tolerance: 1e-10,
            initial: None,
            search_points: 400,
            search_iterations: 30,
            search_keep: 4,
        }
    }
}

/// Result of [`icp`].
#[derive(Debug, Clone, PartialEq)]
pub struct IcpResult {
    /// Transform taking the source onto the target.
    pub transform: Similarity,
    /// Distances of all transformed source points to the target surface.
    pub residuals: Residuals,
    /// RMS of the kept (trimmed) pairs at the end (m).
    pub trimmed_rms: f64,
    /// Refinement iterations done.
    pub iterations: usize,
}

/// Register a source mesh onto a target surface (principal axes from the
/// surfaces, residuals over the source vertices).
pub fn icp_mesh(source: &TriMesh, target: &MeshQuery, opts: &IcpOptions) -> Result<IcpResult> {
    let axes = source
        .principal_axes()
        .ok_or_else(|| Error::invalid("ICP", "the source mesh has no area"))?;
    icp_impl(&source.vertices, &axes, target, opts)
}

/// Register source points onto a target surface.
pub fn icp(source: &[Point3<f64>], target: &MeshQuery, opts: &IcpOptions) -> Result<IcpResult> {
    let axes =
        point_principal_axes(source).ok_or_else(|| Error::invalid("ICP", "no source points"))?;
    icp_impl(source, &axes, target, opts)
}

fn icp_impl(
    source: &[Point3<f64>],
    src_axes: &PrincipalAxes,
    target: &MeshQuery,
    opts: &IcpOptions,
) -> Result<IcpResult> {
    let ctx = "ICP";
    if source.len() < 3 {
        return Err(Error::invalid(ctx, "at least 3 source points are needed"));
    }
    if !(opts.keep_fraction > 0.0 && opts.keep_fraction <= 1.0) {
        return Err(Error::invalid(ctx, "keep_fraction must be in (0, 1]"));
    }
    let (transform, trimmed_rms, iterations) = match opts.initial {
        Some(t) => refine(source, target, t, opts, opts.max_iterations),
        None => {
            let tgt_axes = target
                .mesh()
                .principal_axes()
                .ok_or_else(|| Error::invalid(ctx, "the target mesh has no area"))?;
            let step = source.len().div_ceil(opts.search_points.max(3));
            let sub: Vec<Point3<f64>> = source.iter().step_by(step.max(1)).copied().collect();
            // Short refinement from every candidate on a subsample...
            let mut coarse: Vec<(f64, usize, Similarity)> =
                pca_candidates(src_axes, &tgt_axes, opts.allow_scale)
                    .into_iter()
                    .enumerate()
                    .map(|(k, cand)| {
                        let (t, rms, _) = refine(&sub, target, cand, opts, opts.search_iterations);
                        (rms, k, t)
                    })
                    .collect();
            coarse.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            // ...then full refinement of the most promising ones.
            let mut best: Option<(Similarity, f64, usize)> = None;
            for (_, _, t) in coarse.iter().take(opts.search_keep.max(1)) {
                let r = refine(source, target, *t, opts, opts.max_iterations);
                if best.is_none_or(|b| r.1 < b.1) {
                    best = Some(r);
                }
            }
            best.ok_or_else(|| Error::numerical(ctx, "no initial alignment"))?
        }
    };
    let moved: Vec<Point3<f64>> = source.iter().map(|p| transform.apply(p)).collect();
    Ok(IcpResult {
        transform,
        residuals: Residuals::to_surface(&moved, target),
        trimmed_rms,
        iterations,
    })
}

/// The 24 proper rotations taking the source principal frame onto the
/// target one up to axis order and signs, with centroids matched and (for
/// similarity) the scale from the variance ratio.
fn pca_candidates(src: &PrincipalAxes, tgt: &PrincipalAxes, scale: bool) -> Vec<Similarity> {
    let s = if scale && src.variances.sum() > 0.0 {
        (tgt.variances.sum() / src.variances.sum()).sqrt()
    } else {
        1.0
    };
    let perms = [
        [0, 1, 2],
        [0, 2, 1],
        [1, 0, 2],
        [1, 2, 0],
        [2, 0, 1],
        [2, 1, 0],
    ];
    let mut out = Vec::new();
    for p in perms {
        for signs in 0..8u8 {
            let mut m = Matrix3::zeros();
            for (i, &j) in p.iter().enumerate() {
                m[(i, j)] = if signs >> i & 1 == 1 { -1.0 } else { 1.0 };
            }
            if m.determinant() < 0.0 {
                continue;
            }
            let r = tgt.axes * m * src.axes.transpose();
            let rot = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r));
            out.push(Similarity {
                rotation: rot,
                translation: tgt.centre.coords - s * (rot * src.centre.coords),
                scale: s,
            });
        }
    }
    out
}

/// Indices of the `keep` smallest distances (stable, deterministic).
fn kept(d: &[f64], keep: f64) -> Vec<usize> {
    let mut idx: Vec<usize> = (0..d.len()).collect();
    idx.sort_by(|&a, &b| d[a].total_cmp(&d[b]).then(a.cmp(&b)));
    let k = ((d.len() as f64 * keep).ceil() as usize).clamp(3.min(d.len()), d.len());
    idx.truncate(k);
    idx
}

/// Refinement: linearised point-to-plane + weighted point-to-point steps
/// about the current centroid, on the kept pairs.
fn refine(
    src: &[Point3<f64>],
    target: &MeshQuery,
    mut t: Similarity,
    opts: &IcpOptions,
    max_iterations: usize,
) -> (Similarity, f64, usize) {
    const W_POINT: f64 = 0.1;
    let mut prev = f64::INFINITY;
    let mut rms = f64::INFINITY;
    let mut iters = 0;
    let npar = if opts.allow_scale { 7 } else { 6 };
    for it in 0..max_iterations {
        iters = it + 1;
        let moved: Vec<Point3<f64>> = src.iter().map(|p| t.apply(p)).collect();
        let hits: Vec<_> = moved.iter().map(|p| target.closest_point(p)).collect();
        let d: Vec<f64> = hits.iter().map(|h| h.t).collect();
        let keep = kept(&d, opts.keep_fraction);
        rms = (keep.iter().map(|&i| d[i] * d[i]).sum::<f64>() / keep.len() as f64).sqrt();
        let scale_len = target
            .mesh()
            .bounds()
            .map(|(lo, hi)| (hi - lo).norm())
            .unwrap_or(1.0);
        if rms <= 1e-13 * scale_len || (prev.is_finite() && prev - rms <= opts.tolerance * prev) {
            break;
        }
        prev = rms;
        let c = keep
            .iter()
            .fold(Vector3::zeros(), |a, &i| a + moved[i].coords)
            / keep.len() as f64;
        let mut jtj = SMatrix::<f64, 7, 7>::zeros();
        let mut jtr = SVector::<f64, 7>::zeros();
        for &i in &keep {
            let p = moved[i];
            let q = hits[i].point;
            let dv = p.coords - c;
            let n = target.mesh().triangle_normal(hits[i].triangle);
            let mut row = |j: SVector<f64, 7>, r: f64, w: f64| {
                jtj += w * j * j.transpose();
                jtr += w * j * r;
            };
            // Point-to-plane.
            let dn = dv.cross(&n);
            row(
                SVector::<f64, 7>::from_column_slice(&[
                    dn.x,
                    dn.y,
                    dn.z,
                    n.x,
                    n.y,
                    n.z,
                    n.dot(&dv),
                ]),
                n.dot(&(p - q)),
                1.0,
            );
            // Point-to-point, each axis: d/d(omega) of (omega x dv)_k etc.
            for k in 0..3 {
                let e = Vector3::ith(k, 1.0);
                let g = dv.cross(&e);
                row(
                    SVector::<f64, 7>::from_column_slice(&[g.x, g.y, g.z, e.x, e.y, e.z, dv[k]]),
                    (p - q)[k],
                    W_POINT * W_POINT,
                );
            }
        }
        let a = jtj.view((0, 0), (npar, npar)).into_owned();
        let b = jtr.rows(0, npar).into_owned();
        let damp = 1e-12 * a.trace().max(f64::MIN_POSITIVE);
        let a = a + nalgebra::DMatrix::identity(npar, npar) * damp;
        let Some(x) = a.lu().solve(&(-b)) else { break };
        let omega = Vector3::new(x[0], x[1], x[2]);
        let dt = Vector3::new(x[3], x[4], x[5]);
        let ds = if opts.allow_scale { x[6] } else { 0.0 };
        let rot = UnitQuaternion::from_scaled_axis(omega);
        let s = 1.0 + ds;
        let step = Similarity {
            rotation: rot,
            translation: c + dt - s * (rot * c),
            scale: s,
        };
        if s.is_nan() || s <= 0.0 {
            break;
        }
        t = step.compose(&t);
    }
    (t, rms, iters)
}

/// An affine map `p -> a p + b`, and the trimmed RMS of the last step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AffineFit {
    /// The linear part `a`.
    pub a: Matrix3<f64>,
    /// The translation `b` (mesh units).
    pub b: Vector3<f64>,
    /// RMS closest-point distance of the kept pairs at the last step (mesh units).
    pub trimmed_rms: f64,
}

impl AffineFit {
    /// The mapped point `a p + b`.
    pub fn apply(&self, p: &Point3<f64>) -> Point3<f64> {
        Point3::from(self.a * p.coords + self.b)
    }
}

/// Iterative closest point of `source` onto `target` with a general affine
/// map, starting from the identity (the source already placed near the
/// target). Each step solves, for the current closest points, the linear
/// least squares of point-to-plane distances plus a lightly weighted
/// point-to-point term (which keeps the map from sliding along the
/// surface), on the `keep_fraction` closest pairs. Errors when the source
/// has fewer than 4 points or the problem is degenerate (flat source).
pub fn affine_icp(
    source: &[Point3<f64>],
    target: &MeshQuery,
    keep_fraction: f64,
    max_iterations: usize,
) -> Result<AffineFit> {
    const W_POINT: f64 = 0.1;
    if source.len() < 4 {
        return Err(Error::invalid(
            "affine ICP",
            format!("{} source points (at least 4)", source.len()),
        ));
    }
    // Work about the source's centroid, so that the normal equations are
    // well scaled.
    let c = source.iter().fold(Vector3::zeros(), |a, p| a + p.coords) / source.len() as f64;
    let mut fit = AffineFit {
        a: Matrix3::identity(),
        b: Vector3::zeros(),
        trimmed_rms: f64::INFINITY,
    };
    let mut prev = f64::INFINITY;
    for _ in 0..max_iterations {
        let moved: Vec<Point3<f64>> = source.iter().map(|p| fit.apply(p)).collect();
        let hits: Vec<_> = moved.iter().map(|p| target.closest_point(p)).collect();
        let d: Vec<f64> = hits.iter().map(|h| h.t).collect();
        let keep = kept(&d, keep_fraction);
        let rms = (keep.iter().map(|&i| d[i] * d[i]).sum::<f64>() / keep.len() as f64).sqrt();
        fit.trimmed_rms = rms;
        if prev.is_finite() && prev - rms <= 1e-6 * prev {
            break;
        }
        prev = rms;
        // Unknowns: a (row-major, 9) and b' (3) of p -> a (p - c) + b'.
        let mut jtj = SMatrix::<f64, 12, 12>::zeros();
        let mut jtr = SVector::<f64, 12>::zeros();
        for &i in &keep {
            let v = source[i].coords - c;
            let q = hits[i].point.coords;
            let n = target.mesh().triangle_normal(hits[i].triangle);
            let mut row = |w: &Vector3<f64>, r: f64, weight: f64| {
                let mut j = SVector::<f64, 12>::zeros();
                for k in 0..3 {
                    for m in 0..3 {
                        j[3 * k + m] = w[k] * v[m];
                    }
                    j[9 + k] = w[k];
                }
                jtj += weight * j * j.transpose();
                jtr += weight * j * r;
            };
            row(&n, n.dot(&q), 1.0);
            for k in 0..3 {
                let e = Vector3::ith(k, 1.0);
                row(&e, q[k], W_POINT * W_POINT);
            }
        }
        let damp = 1e-12 * jtj.trace().max(f64::MIN_POSITIVE);
        let Some(x) = (jtj + SMatrix::<f64, 12, 12>::identity() * damp)
            .lu()
            .solve(&jtr)
        else {
            return Err(Error::invalid("affine ICP", "degenerate normal equations"));
        };
        let a = Matrix3::from_fn(|k, m| x[3 * k + m]);
        if !a.iter().all(|v| v.is_finite()) || a.determinant() <= 0.0 {
            return Err(Error::invalid("affine ICP", "the map folds the source"));
        }
        fit.a = a;
        fit.b = Vector3::new(x[9], x[10], x[11]) - a * c;
    }
    Ok(fit)
}

/// Result of [`gpa`].
#[derive(Debug, Clone, PartialEq)]
pub struct GpaResult {
    /// The mean shape (m), centred at the origin; with scaling, its size is
    /// the average centroid size of the inputs.
    pub mean: Vec<Point3<f64>>,
    /// For each input shape, the transform taking it onto `mean`.
    pub transforms: Vec<Similarity>,
    /// RMS distance of the aligned shapes' points to the mean (m).
    pub rms: f64,
    /// Iterations done.
    pub iterations: usize,
}

fn centroid_size(p: &[Point3<f64>]) -> f64 {
    let n = p.len() as f64;
    let c = p.iter().fold(Vector3::zeros(), |a, q| a + q.coords) / n;
    p.iter()
        .map(|q| (q.coords - c).norm_squared())
        .sum::<f64>()
        .sqrt()
}

/// Generalised Procrustes analysis of shapes in point correspondence:
/// alternately align every shape to the current mean (similarity if
/// `with_scale`, else rigid) and re-average, until the mean moves by less
/// than `tol` (m, RMS per point) or 100 iterations.
pub fn gpa(shapes: &[Vec<Point3<f64>>], with_scale: bool, tol: f64) -> Result<GpaResult> {
    let ctx = "Procrustes analysis";
    if shapes.len() < 2 {
        return Err(Error::invalid(ctx, "at least two shapes are needed"));
    }
    let n = shapes[0].len();
    if n < 3 {
        return Err(Error::invalid(ctx, "shapes need at least 3 points"));
    }
    if let Some(k) = shapes.iter().position(|s| s.len() != n) {
        return Err(Error::invalid(
            ctx,
            format!("shape {k} has {} points, shape 0 has {n}", shapes[k].len()),
        ));
    }
    let sizes: Vec<f64> = shapes.iter().map(|s| centroid_size(s)).collect();
    let target_size = sizes.iter().sum::<f64>() / sizes.len() as f64;
    let normalise = |m: &mut Vec<Point3<f64>>| {
        let c = m.iter().fold(Vector3::zeros(), |a, q| a + q.coords) / n as f64;
        for p in m.iter_mut() {
            *p -= c;
        }
        if with_scale {
            let s = target_size / centroid_size(m).max(f64::MIN_POSITIVE);
            for p in m.iter_mut() {
                *p = Point3::from(p.coords * s);
            }
        }
    };
    let mut mean = shapes[0].clone();
    normalise(&mut mean);
    let mut transforms = vec![Similarity::identity(); shapes.len()];
    let mut iterations = 0;
    for it in 0..100 {
        iterations = it + 1;
        let mut acc = vec![Vector3::zeros(); n];
        for (k, s) in shapes.iter().enumerate() {
            let t = umeyama(s, &mean, with_scale)?;
            transforms[k] = t;
            for (a, p) in acc.iter_mut().zip(s) {
                *a += t.apply(p).coords;
            }
        }
        let mut new: Vec<Point3<f64>> = acc
            .into_iter()
            .map(|a| Point3::from(a / shapes.len() as f64))
            .collect();
        normalise(&mut new);
        let change = (new
            .iter()
            .zip(&mean)
            .map(|(a, b)| (a - b).norm_squared())
            .sum::<f64>()
            / n as f64)
            .sqrt();
        mean = new;
        if change <= tol {
            break;
        }
    }
    let mut sq = 0.0;
    for (k, s) in shapes.iter().enumerate() {
        let t = umeyama(s, &mean, with_scale)?;
        transforms[k] = t;
        sq += s
            .iter()
            .zip(&mean)
            .map(|(p, m)| (t.apply(p) - m).norm_squared())
            .sum::<f64>();
    }
    Ok(GpaResult {
        mean,
        transforms,
        rms: (sq / (n * shapes.len()) as f64).sqrt(),
        iterations,
    })
}

/// GPA of meshes in vertex correspondence (same vertex count and the same
/// triangles); the mean mesh takes the first mesh's triangles.
pub fn gpa_meshes(meshes: &[TriMesh], with_scale: bool, tol: f64) -> Result<(TriMesh, GpaResult)> {
    let first = meshes
        .first()
        .ok_or_else(|| Error::invalid("Procrustes analysis", "no meshes"))?;
    if let Some(k) = meshes.iter().position(|m| m.triangles != first.triangles) {
        return Err(Error::invalid(
            "Procrustes analysis",
            format!("mesh {k} has different triangles from mesh 0: not in vertex correspondence"),
        ));
    }
    let shapes: Vec<Vec<Point3<f64>>> = meshes.iter().map(|m| m.vertices.clone()).collect();
    let r = gpa(&shapes, with_scale, tol)?;
    Ok((
        TriMesh {
            vertices: r.mean.clone(),
            triangles: first.triangles.clone(),
        },
        r,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn umeyama_recovers_a_similarity_exactly() {
        let src: Vec<Point3<f64>> = (0..10)
            .map(|i| Point3::new((i as f64).sin(), (i as f64 * 0.7).cos(), i as f64 * 0.1))
            .collect();
        let truth = Similarity {
            rotation: UnitQuaternion::from_euler_angles(0.4, -2.0, 1.3),
            translation: Vector3::new(0.1, -0.3, 2.0),
            scale: 1.7,
        };
        let dst: Vec<Point3<f64>> = src.iter().map(|p| truth.apply(p)).collect();
        let t = umeyama(&src, &dst, true).unwrap();
        assert!((t.scale - 1.7).abs() < 1e-12);
        assert!(t.rotation.angle_to(&truth.rotation) < 1e-12);
        assert!((t.translation - truth.translation).norm() < 1e-12);
        let inv = t.inverse().compose(&t);
        assert!((inv.to_matrix() - Matrix4::identity()).norm() < 1e-12);
        // Rigid fit of a scaled set keeps scale 1.
        assert_eq!(kabsch(&src, &dst).unwrap().scale, 1.0);
    }

    #[test]
    fn umeyama_refuses_collinear_points() {
        let a: Vec<Point3<f64>> = (0..5).map(|i| Point3::new(i as f64, 0.0, 0.0)).collect();
        assert!(umeyama(&a, &a, false).is_err());
        assert!(umeyama(&a[..2], &a[..2], false).is_err());
    }

    #[test]
    fn affine_icp_recovers_an_anisotropic_scaling_of_a_closed_surface() {
        // A lumpy, asymmetric closed surface (a latitude-longitude sphere
        // pushed out unevenly, so that no symmetry lets the map slide),
        // and the same surface scaled about an off-centre point and
        // turned: the map must come back from the surface alone.
        let (nlat, nlon) = (40usize, 80usize);
        let mut vertices = vec![Point3::new(0.0, 0.0, 1.0), Point3::new(0.0, 0.0, -1.0)];
        for i in 1..nlat {
            let th = std::f64::consts::PI * i as f64 / nlat as f64;
            for j in 0..nlon {
                let ph = std::f64::consts::TAU * j as f64 / nlon as f64;
                vertices.push(Point3::new(
                    th.sin() * ph.cos(),
                    th.sin() * ph.sin(),
                    th.cos(),
                ));
            }
        }
        let at = |i: usize, j: usize| (2 + (i - 1) * nlon + j % nlon) as u32;
        let mut triangles = Vec::new();
        for j in 0..nlon {
            triangles.push([0, at(1, j), at(1, j + 1)]);
            triangles.push([1, at(nlat - 1, j + 1), at(nlat - 1, j)]);
            for i in 1..nlat - 1 {
                triangles.push([at(i, j), at(i + 1, j), at(i + 1, j + 1)]);
                triangles.push([at(i, j), at(i + 1, j + 1), at(i, j + 1)]);
            }
        }
        for v in &mut vertices {
            let u = v.coords;
            let r = 0.02 * (1.0 + 0.3 * u.x * u.x + 0.2 * u.y + 0.1 * u.x * u.z);
            *v = Point3::from(u * r);
        }
        let m = TriMesh {
            vertices,
            triangles,
        };
        let centre = Point3::new(0.003, -0.002, 0.001);
        let rot = Rotation3::from_euler_angles(0.02, -0.03, 0.025);
        let scale = Matrix3::from_diagonal(&Vector3::new(1.1, 0.9, 1.05));
        let a = rot.matrix() * scale;
        let truth = |p: &Point3<f64>| Point3::from(a * (p - centre) + centre.coords);
        let target = TriMesh {
            vertices: m.vertices.iter().map(truth).collect(),
            triangles: m.triangles.clone(),
        };
        let q = MeshQuery::new(&target).unwrap();
        let fit = affine_icp(&m.vertices, &q, 1.0, 200).unwrap();
        let err = (fit.apply(&centre) - centre).norm();
        assert!(err < 2e-5, "centre carried {err} m off");
        assert!((fit.a - a).norm() < 5e-3, "{}", fit.a);
        assert!(fit.trimmed_rms < 2e-5);
    }

    #[test]
    fn residual_percentiles() {
        let d: Vec<f64> = (1..=100).map(|i| i as f64).collect();
        let r = Residuals::from_distances(&d);
        // R: quantile(1:100, c(.5, .9, .95, .99)) -> 50.5 90.1 95.05 99.01
        let want = [50.5, 90.1, 95.05, 99.01, 100.0];
        for (got, want) in [r.p50, r.p90, r.p95, r.p99, r.max].iter().zip(want) {
            assert!((got - want).abs() < 1e-9, "{got} vs {want}");
        }
        assert!((r.rms - (338350.0f64 / 100.0).sqrt()).abs() < 1e-9);
    }
}
