//! Geometry on synthetic truth and on the real meshes in `../shared/data/`:
//! inside tests against the generalised winding number, sphere fits on
//! noisy caps and on the vertebral bodies' anterior walls, ICP without
//! correspondences (rigid, similarity, cropped), and GPA.

mod common;

use nalgebra::{Point3, Unit, UnitQuaternion, Vector3};
use osim_spine::mesh::{self, AnatomicalFrame, IcpOptions, MeshQuery, Similarity, TriMesh};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal, UnitSphere};

fn read_shared(rel: &str) -> Option<TriMesh> {
    let p = common::shared(rel)?;
    Some(mesh::read(&p).unwrap())
}

/// Generalised winding number of a consistently oriented closed mesh at p
/// (solid angles, Van Oosterom & Strackee): +-1 inside, 0 outside.
fn winding_number(m: &TriMesh, p: &Point3<f64>) -> f64 {
    let mut w = 0.0;
    for [a, b, c] in m.triangle_corners() {
        let (a, b, c) = (a - p, b - p, c - p);
        let (la, lb, lc) = (a.norm(), b.norm(), c.norm());
        let num = a.dot(&b.cross(&c));
        let den = la * lb * lc + a.dot(&b) * lc + b.dot(&c) * la + c.dot(&a) * lb;
        w += 2.0 * num.atan2(den);
    }
    w / (4.0 * std::f64::consts::PI)
}

fn random_rotation(rng: &mut ChaCha8Rng) -> UnitQuaternion<f64> {
    let axis: [f64; 3] = UnitSphere.sample(rng);
    let angle = rng.random_range(0.0..std::f64::consts::PI);
    UnitQuaternion::from_axis_angle(&Unit::new_normalize(Vector3::from(axis)), angle)
}

/// Vertebral-body OBJ, duplicated seam vertices welded (closed surface).
fn body(level: &str) -> Option<TriMesh> {
    let m = read_shared(&format!("data/vertebra-meshes/{level}_body.obj"))?;
    Some(m.welded(1e-9).0)
}

#[test]
fn welded_vertebral_bodies_are_closed_and_orientable() {
    for level in ["L1", "L2", "L3", "L4", "L5", "S1"] {
        let Some(mut m) = body(level) else { return };
        let rep = m.edge_report();
        assert!(
            rep.is_watertight(),
            "{level}: {} boundary, {} non-manifold",
            rep.boundary_edges.len(),
            rep.non_manifold_edges.len()
        );
        m.orient_consistently();
        assert!(m.edge_report().inconsistent_edges.is_empty());
        let v = m.signed_volume();
        // A lumbar body is ~30-60 cm^3.
        assert!(v > 1e-5 && v < 1e-4, "{level}: volume {v} m^3");
    }
}

#[test]
fn inside_test_agrees_with_winding_number_on_real_meshes() {
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let mut files = vec!["data/vertebra-meshes/L3_body.obj".to_string()];
    for f in ["lumbar1", "thoracic7_s", "sacrum"] {
        files.push(format!("data/geometry-bodyframe/{f}.vtp"));
    }
    for f in &files {
        let Some(raw) = read_shared(f) else { return };
        let m = raw.welded(1e-9).0;
        let rep = m.edge_report();
        if !rep.is_watertight() {
            println!(
                "{f}: not closed ({} boundary edges), skipped",
                rep.boundary_edges.len()
            );
            continue;
        }
        let mut oriented = m.clone();
        let flipped = oriented.orient_consistently();
        println!(
            "{f}: {flipped} of {} triangles flipped to orient",
            m.triangles.len()
        );
        // Query the mesh as read (flipped winding kept) and fully reversed.
        let q = MeshQuery::new(&m).unwrap();
        let mut reversed = m.clone();
        for t in &mut reversed.triangles {
            t.swap(1, 2);
        }
        let qr = MeshQuery::new(&reversed).unwrap();
        let (lo, hi) = m.bounds().unwrap();
        let (mut inside, mut total) = (0, 0);
        for _ in 0..300 {
            let p = Point3::from(lo.coords.zip_map(&hi.coords, |a, b| {
                let pad = 0.1 * (b - a);
                rng.random_range(a - pad..b + pad)
            }));
            let w = winding_number(&oriented, &p);
            if (w.abs() - 0.5).abs() < 0.2 {
                continue; // within numerical reach of the surface
            }
            let truth = w.abs() > 0.5;
            assert_eq!(q.contains(&p), truth, "{f}: {p:?} winding {w}");
            assert_eq!(qr.contains(&p), truth, "{f}: reversed mesh at {p:?}");
            inside += truth as usize;
            total += 1;
        }
        assert!(
            inside > 10 && total - inside > 10,
            "{f}: {inside}/{total} inside"
        );
    }
}

#[test]
fn sphere_fit_on_noisy_caps_is_within_0_1_mm() {
    let mut worst: f64 = 0.0;
    for (k, cap_deg) in [60.0f64, 90.0, 120.0].iter().enumerate() {
        for (j, noise_mm) in [0.05f64, 0.1, 0.2].iter().enumerate() {
            let mut rng = ChaCha8Rng::seed_from_u64(100 + 10 * k as u64 + j as u64);
            let centre = Point3::new(0.03, -0.01, 0.12);
            let radius = 0.02;
            let rot = random_rotation(&mut rng);
            let half = (cap_deg / 2.0).to_radians();
            let noise = Normal::new(0.0, noise_mm * 1e-3).unwrap();
            let pts: Vec<Point3<f64>> = (0..2000)
                .map(|_| {
                    // Uniform on the cap: cos(theta) uniform in [cos(half), 1].
                    let ct = rng.random_range(half.cos()..1.0);
                    let st = (1.0 - ct * ct).sqrt();
                    let ph = rng.random_range(0.0..std::f64::consts::TAU);
                    let dir = rot * Vector3::new(st * ph.cos(), st * ph.sin(), ct);
                    centre + dir * radius + Vector3::from_fn(|_, _| noise.sample(&mut rng))
                })
                .collect();
            let s = mesh::fit_sphere(&pts).unwrap();
            let dc = (s.centre - centre).norm();
            let dr = (s.radius - radius).abs();
            println!(
                "cap {cap_deg} deg, noise {noise_mm} mm: centre error {:.4} mm, radius error {:.4} mm, rms {:.4} mm",
                dc * 1e3,
                dr * 1e3,
                s.rms * 1e3
            );
            assert!(dc < 1e-4 && dr < 1e-4);
            // The residual RMS estimates the noise (3-D noise projected on the normal).
            assert!(
                (s.rms / (noise_mm * 1e-3) - 1.0).abs() < 0.1,
                "rms {}",
                s.rms
            );
            worst = worst.max(dc).max(dr);
        }
    }
    println!("worst centre/radius error: {:.4} mm", worst * 1e3);
}

/// Anterior direction derived from the anatomy, not assumed: the body's
/// centroid lies anterior of the whole vertebra's centroid (the posterior
/// elements pull the latter back); cranial is +Z in these files.
fn frame_from_anatomy(level: &str, body: &TriMesh) -> Option<AnatomicalFrame> {
    let whole = read_shared(&format!("data/vertebra-meshes/{level}_whole.obj"))?;
    let mut d = body.area_centroid().unwrap() - whole.area_centroid().unwrap();
    d.z = 0.0; // horizontal component: cranial is +Z
    Some(AnatomicalFrame::new(d, Vector3::z()).unwrap())
}

#[test]
fn anterior_wall_sphere_centre_lies_inside_each_vertebral_body() {
    for level in ["L1", "L2", "L3", "L4", "L5"] {
        let Some(m) = body(level) else { return };
        let Some(frame) = frame_from_anatomy(level, &m) else {
            return;
        };
        // The anatomy puts anterior along +X in these files.
        assert!(
            frame.anterior.x > 0.95,
            "{level}: anterior {:?}",
            frame.anterior
        );
        let nodes = mesh::anterior_body_nodes(&m, &frame).unwrap();
        let pts: Vec<Point3<f64>> = nodes.iter().map(|&i| m.vertices[i]).collect();
        let s = mesh::fit_sphere(&pts).unwrap();
        let q = MeshQuery::new(&m).unwrap();
        let inside = q.contains(&s.centre);
        let depth = -q.signed_distance(&s.centre);
        println!(
            "{level}: {} anterior nodes of {}, radius {:.2} mm, rms {:.3} mm, centre {:.2} mm inside the surface",
            nodes.len(),
            m.vertices.len(),
            s.radius * 1e3,
            s.rms * 1e3,
            depth * 1e3
        );
        assert!(nodes.len() > 50, "{level}: only {} nodes", nodes.len());
        assert!(
            inside,
            "{level}: sphere centre {:?} outside the body",
            s.centre
        );
        // Every node is on the anterior side of the fitted centre.
        assert!(pts
            .iter()
            .all(|p| (p - s.centre).dot(&frame.anterior) > 0.0));
        // A wrong frame (posterior given as anterior) selects nothing sensible:
        let wrong = AnatomicalFrame::new(-frame.anterior.into_inner(), Vector3::z()).unwrap();
        let other = mesh::anterior_body_nodes(&m, &wrong).unwrap_or_default();
        assert!(other.iter().all(|i| !nodes.contains(i)));
    }
}

fn crop(m: &TriMesh, dir: &Vector3<f64>, drop_fraction: f64) -> TriMesh {
    let mut h: Vec<f64> = m.vertices.iter().map(|p| p.coords.dot(dir)).collect();
    let mut sorted = h.clone();
    sorted.sort_by(f64::total_cmp);
    let cut = sorted[((1.0 - drop_fraction) * (sorted.len() - 1) as f64) as usize];
    let keep: Vec<bool> = h.iter_mut().map(|x| *x <= cut).collect();
    let tris = m
        .triangles
        .iter()
        .filter(|t| t.iter().all(|&k| keep[k as usize]))
        .copied()
        .collect();
    TriMesh {
        vertices: m.vertices.clone(),
        triangles: tris,
    }
    .welded(0.0)
    .0
}

fn check_icp(name: &str, target: &TriMesh, allow_scale: bool, crop_fraction: f64, seed: u64) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let truth = Similarity {
        rotation: random_rotation(&mut rng),
        translation: Vector3::from_fn(|_, _| rng.random_range(-0.1..0.1)),
        scale: if allow_scale {
            rng.random_range(0.8..1.25)
        } else {
            1.0
        },
    };
    let mut source = truth.apply_mesh(target);
    if crop_fraction > 0.0 {
        let d: [f64; 3] = UnitSphere.sample(&mut rng);
        source = crop(&source, &Vector3::from(d), crop_fraction);
    }
    let q = MeshQuery::new(target).unwrap();
    let opts = IcpOptions {
        allow_scale,
        ..Default::default()
    };
    let r = mesh::icp_mesh(&source, &q, &opts).unwrap();
    let inv = truth.inverse();
    let ang = r.transform.rotation.angle_to(&inv.rotation);
    println!(
        "{name} (scale {allow_scale}, crop {crop_fraction}): {} source vertices, rms {:.2e} m, max {:.2e} m, p95 {:.2e} m, rotation error {:.2e} rad, scale {:.9} vs {:.9}, {} iterations",
        source.vertices.len(),
        r.residuals.rms,
        r.residuals.max,
        r.residuals.p95,
        ang,
        r.transform.scale,
        inv.scale,
        r.iterations
    );
    assert!(r.residuals.rms < 1e-6, "{name}: rms {}", r.residuals.rms);
    assert!(ang < 1e-4, "{name}: rotation off by {ang} rad");
    assert!((r.transform.scale - inv.scale).abs() < 1e-5);
}

#[test]
fn icp_recovers_rigid_and_similarity_transforms_without_correspondences() {
    let Some(l2) = body("L2") else { return };
    let Some(whole) = read_shared("data/vertebra-meshes/L4_whole.obj") else {
        return;
    };
    let Some(t7) = read_shared("data/geometry-bodyframe/thoracic7_s.vtp") else {
        return;
    };
    for (name, m) in [("L2_body", &l2), ("L4_whole", &whole), ("thoracic7_s", &t7)] {
        check_icp(name, m, false, 0.0, 1);
        check_icp(name, m, true, 0.0, 2);
    }
}

#[test]
fn icp_recovers_a_cropped_source() {
    let Some(l2) = body("L2") else { return };
    let Some(whole) = read_shared("data/vertebra-meshes/L4_whole.obj") else {
        return;
    };
    for (name, m) in [("L2_body", &l2), ("L4_whole", &whole)] {
        check_icp(name, m, false, 0.3, 3);
        check_icp(name, m, true, 0.3, 4);
    }
}

#[test]
fn gpa_recovers_the_mean_shape() {
    let Some(base) = read_shared("data/geometry-bodyframe/lumbar3.vtp") else {
        return;
    };
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let sigma = 0.2e-3;
    let noise = Normal::new(0.0, sigma).unwrap();
    let copies: Vec<TriMesh> = (0..20)
        .map(|_| {
            let t = Similarity {
                rotation: random_rotation(&mut rng),
                translation: Vector3::from_fn(|_, _| rng.random_range(-0.2..0.2)),
                scale: rng.random_range(0.8..1.25),
            };
            let mut m = t.apply_mesh(&base);
            for v in &mut m.vertices {
                *v += Vector3::from_fn(|_, _| noise.sample(&mut rng)) * t.scale;
            }
            m
        })
        .collect();
    let (mean, r) = mesh::gpa_meshes(&copies, true, 1e-12).unwrap();
    let align = |shape: &[Point3<f64>]| -> f64 {
        let t = mesh::umeyama(shape, &base.vertices, true).unwrap();
        let sq: f64 = shape
            .iter()
            .zip(&base.vertices)
            .map(|(p, b)| (t.apply(p) - b).norm_squared())
            .sum();
        (sq / shape.len() as f64).sqrt()
    };
    let err_mean = align(&mean.vertices);
    let err_one = align(&copies[0].vertices);
    println!(
        "GPA of 20 copies (noise {} mm): mean-shape error {:.4} mm vs one copy {:.4} mm, {} iterations, rms to mean {:.4} mm",
        sigma * 1e3,
        err_mean * 1e3,
        err_one * 1e3,
        r.iterations,
        r.rms * 1e3
    );
    // sqrt(3) sigma / sqrt(20) ~ 0.077 mm expected.
    assert!(err_mean < 0.12e-3, "{err_mean}");
    assert!(err_mean < 0.4 * err_one);
    // Noise-free copies give the base shape exactly.
    let exact: Vec<TriMesh> = (0..5)
        .map(|_| {
            Similarity {
                rotation: random_rotation(&mut rng),
                translation: Vector3::from_fn(|_, _| rng.random_range(-0.2..0.2)),
                scale: rng.random_range(0.8..1.25),
            }
            .apply_mesh(&base)
        })
        .collect();
    let (m2, _) = mesh::gpa_meshes(&exact, true, 1e-14).unwrap();
    assert!(align(&m2.vertices) < 1e-12);
}
