//! The palpation engine on meshes that are not a whole, upright vertebra
//!: a box, a sphere, half a vertebra, an
//! upside-down or mirrored vertebra, a vertebra with a hole where its
//! superior endplate is. Each gives a clear error or a finding naming the
//! level (and the landmark where one is concerned), never a silent marker.

mod common;

use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use osim_spine::landmarks::{Code, Level};
use osim_spine::mesh::{self, TriMesh};
use osim_spine::palpation::{palpate_vertebra, FrameHint, Severity, VertebraPalpation};

fn l3() -> Option<TriMesh> {
    let dir = common::shared("data/geometry-bodyframe")?;
    Some(mesh::read(&dir.join("lumbar3.vtp")).unwrap())
}

/// A closed box of the given half sizes (m).
fn boxed(h: Vector3<f64>) -> TriMesh {
    let v: Vec<Point3<f64>> = (0..8)
        .map(|i| {
            Point3::new(
                if i & 1 == 0 { -h.x } else { h.x },
                if i & 2 == 0 { -h.y } else { h.y },
                if i & 4 == 0 { -h.z } else { h.z },
            )
        })
        .collect();
    let q = [
        [0, 2, 3, 1],
        [4, 5, 7, 6],
        [0, 1, 5, 4],
        [2, 6, 7, 3],
        [0, 4, 6, 2],
        [1, 3, 7, 5],
    ];
    let triangles = q
        .iter()
        .flat_map(|f| [[f[0], f[1], f[2]], [f[0], f[2], f[3]]])
        .collect();
    TriMesh {
        vertices: v,
        triangles,
    }
}

/// A UV sphere of radius `r`.
fn sphere(r: f64) -> TriMesh {
    let (nu, nv) = (24u32, 12u32);
    let mut vertices = vec![Point3::new(0.0, r, 0.0)];
    for j in 1..nv {
        let th = std::f64::consts::PI * f64::from(j) / f64::from(nv);
        for i in 0..nu {
            let ph = std::f64::consts::TAU * f64::from(i) / f64::from(nu);
            vertices.push(Point3::new(
                r * th.sin() * ph.cos(),
                r * th.cos(),
                r * th.sin() * ph.sin(),
            ));
        }
    }
    vertices.push(Point3::new(0.0, -r, 0.0));
    let idx = |j: u32, i: u32| 1 + (j - 1) * nu + i % nu;
    let last = (vertices.len() - 1) as u32;
    let mut triangles = Vec::new();
    for i in 0..nu {
        triangles.push([0, idx(1, i + 1), idx(1, i)]);
        triangles.push([last, idx(nv - 1, i), idx(nv - 1, i + 1)]);
        for j in 1..nv - 1 {
            triangles.push([idx(j, i), idx(j, i + 1), idx(j + 1, i + 1)]);
            triangles.push([idx(j, i), idx(j + 1, i + 1), idx(j + 1, i)]);
        }
    }
    TriMesh {
        vertices,
        triangles,
    }
}

/// The mesh with the triangles whose centroid fails `keep` removed.
fn without(m: &TriMesh, keep: impl Fn(&Point3<f64>) -> bool) -> TriMesh {
    let triangles = m
        .triangles
        .iter()
        .copied()
        .filter(|t| {
            let c = t
                .iter()
                .fold(Vector3::zeros(), |a, &k| a + m.vertices[k as usize].coords)
                / 3.0;
            keep(&Point3::from(c))
        })
        .collect();
    TriMesh {
        vertices: m.vertices.clone(),
        triangles,
    }
}

/// The outcome must be an error naming the level, or a palpation with an
/// error or warning finding (at the level; about `code` when given).
fn assert_flagged(what: &str, r: osim_spine::Result<VertebraPalpation>, code: Option<Code>) {
    match r {
        Err(e) => {
            let msg = e.to_string();
            assert!(
                msg.contains("L3"),
                "{what}: error does not name the level: {msg}"
            );
        }
        Ok(p) => {
            let hits: Vec<String> = p
                .findings
                .iter()
                .filter(|f| f.level == Level::L3)
                .filter(|f| code.is_none_or(|c| f.code == Some(c)))
                .filter(|f| matches!(f.severity, Severity::Error | Severity::Warning))
                .map(|f| f.to_string())
                .collect();
            assert!(
                !hits.is_empty(),
                "{what}: palpated without a finding: {:?}",
                p.findings
            );
        }
    }
}

#[test]
fn shapes_that_are_not_a_vertebra_are_flagged() {
    let hint = FrameHint::body_frame();
    let b = boxed(Vector3::new(0.02, 0.015, 0.025));
    assert_flagged("box", palpate_vertebra(&b, Level::L3, &hint), None);
    assert_flagged(
        "sphere",
        palpate_vertebra(&sphere(0.02), Level::L3, &hint),
        None,
    );
}

#[test]
fn half_upside_down_mirrored_and_holed_vertebrae_are_flagged() {
    let Some(m) = l3() else { return };
    let hint = FrameHint::body_frame();
    // Half a vertebra (the right half only).
    let half = without(&m, |c| c.z > 0.0);
    assert_flagged("half", palpate_vertebra(&half, Level::L3, &hint), None);
    // Upside-down: turned 180 deg about the anterior axis, hint unchanged.
    let flip = Isometry3::from_parts(
        Translation3::identity(),
        UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI),
    );
    assert_flagged(
        "upside-down",
        palpate_vertebra(&m.transformed(&flip), Level::L3, &hint),
        None,
    );
    // A hole where the superior endplate is.
    let top = m.vertices.iter().map(|p| p.y).fold(f64::MIN, f64::max);
    let holed = without(&m, |c| {
        !(c.y > top - 0.012 && c.x > -0.012 && c.x < 0.012 && c.z.abs() < 0.01)
    });
    assert_flagged(
        "holed endplate",
        palpate_vertebra(&holed, Level::L3, &hint),
        None,
    );
    // Mirrored left-right: a vertebra is nearly symmetric, so the mirror is
    // palpated like the original, right codes on the right.
    let mirrored = TriMesh {
        vertices: m
            .vertices
            .iter()
            .map(|p| Point3::new(p.x, p.y, -p.z))
            .collect(),
        triangles: m.triangles.iter().map(|t| [t[0], t[2], t[1]]).collect(),
    };
    let p = palpate_vertebra(&mirrored, Level::L3, &hint).unwrap();
    let q = palpate_vertebra(&m, Level::L3, &hint).unwrap();
    for c in Code::ALL {
        let a = p.landmarks[&c].point;
        let mirror = c.mirror().unwrap_or(c);
        let b = q.landmarks[&mirror].point;
        let d = (a - Point3::new(b.x, b.y, -b.z)).norm();
        assert!(
            d < 1e-3,
            "mirrored L3_{c} is {:.2} mm from the mirror image of {mirror}",
            d * 1e3
        );
        assert!(
            c.mirror().is_none() || (c.to_string().ends_with('R') == (a.z > 0.0)),
            "L3_{c} on the wrong side"
        );
    }
}
