//! Synthetic landmark sets: clean vertebrae from the dimension table
//! ([`crate::anatomy`]) stacked along a parametric spine curve, with
//! optional seeded Gaussian noise. Used by tests and as a fixture generator.
//!
//! Construction (OpenSim frame, metres): the sacrum's superior endplate
//! centre `S1_SEC` is at the origin, its cranial axis tilted anteriorly by
//! the sacral slope. Going cranially, each intervertebral joint adds a
//! relative rotation `Rz(sagittal) * Rx(frontal) * Ry(axial)` in the lower
//! vertebra's frame; the disc is placed along the mean cranial axis of the
//! two vertebrae with the table's disc height, then the vertebra body (mean
//! of anterior/posterior height) above it. Bends are smooth bumps of
//! curvature: a [`Bend`] of angle `a` centred at `apex` distributes `a` over
//! the joints with Gaussian weights of SD `width` levels, so the angle
//! between the end vertebrae of a bend is `a` (its Cobb angle in its plane).
//! Positive sagittal angles are lordotic (extension), positive frontal
//! angles bend the upper spine to the right. Axial rotation is an absolute
//! profile ([`Twist`]) peaking at its apex.
//!
//! Landmarks sit at dimensioned positions in the vertebra frame ([`local_position`]).

use super::frames::VertebraFrame;
use super::{Code, LandmarkSet, Level};
use crate::anatomy::{DimensionTable, LevelDimensions};
use crate::error::{Error, Result};
use nalgebra::{Point3, Rotation3, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

/// A smooth bend: `angle` (rad) spread over the joints around `apex`
/// (level index, fractional: 14.5 = L3-L4 disc) with Gaussian weights of SD
/// `width` levels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Bend {
    /// Level index of the bend's centre (fractional: between levels).
    pub apex: f64,
    /// Gaussian SD of the weights (levels).
    pub width: f64,
    /// Total bend angle (rad).
    pub angle: f64,
}

/// Axial rotation profile: `peak` (rad) at `apex`, Gaussian of SD `width`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Twist {
    /// Level index of the peak (fractional).
    pub apex: f64,
    /// Gaussian SD (levels).
    pub width: f64,
    /// Peak axial rotation (rad).
    pub peak: f64,
}

/// A spine shape.
#[derive(Debug, Clone, PartialEq)]
pub struct SpineShape {
    /// Sacral slope (rad), anterior tilt of the S1 endplate.
    pub sacral_slope: f64,
    /// Sagittal bends (positive lordotic).
    pub sagittal: Vec<Bend>,
    /// Frontal bends (positive bends the upper spine to the right).
    pub frontal: Vec<Bend>,
    /// Axial rotation profiles.
    pub axial: Vec<Twist>,
}

fn deg(x: f64) -> f64 {
    x.to_radians()
}

impl SpineShape {
    /// A straight-in-the-frontal-plane spine: sacral slope 40 deg, lumbar
    /// lordosis 50 deg (apex L3), thoracic kyphosis 40 deg (apex T7).
    pub fn normal() -> Self {
        SpineShape {
            sacral_slope: deg(40.0),
            sagittal: vec![
                Bend {
                    apex: 14.0,
                    width: 1.5,
                    angle: deg(50.0),
                },
                Bend {
                    apex: 6.0,
                    width: 3.0,
                    angle: deg(-40.0),
                },
            ],
            frontal: vec![],
            axial: vec![],
        }
    }

    /// The thesis case (Table 5.2): lumbar main curve of `cobb_deg` (apex
    /// L2-L3, to the left), thoracic compensatory curve of 0.7 x that (apex
    /// T9-T10), supine lordosis 34 deg, kyphosis 11 deg, apical rotation
    /// 0.4 x Cobb.
    pub fn lumbar_scoliosis(cobb_deg: f64) -> Self {
        SpineShape {
            sacral_slope: deg(28.0),
            sagittal: vec![
                Bend {
                    apex: 14.0,
                    width: 1.5,
                    angle: deg(34.0),
                },
                Bend {
                    apex: 6.0,
                    width: 3.0,
                    angle: deg(-11.0),
                },
            ],
            frontal: vec![
                Bend {
                    apex: 13.5,
                    width: 1.2,
                    angle: deg(-cobb_deg),
                },
                Bend {
                    apex: 8.5,
                    width: 1.5,
                    angle: deg(0.7 * cobb_deg),
                },
            ],
            axial: vec![
                Twist {
                    apex: 13.5,
                    width: 1.5,
                    peak: deg(0.4 * cobb_deg),
                },
                Twist {
                    apex: 8.5,
                    width: 1.5,
                    peak: deg(-0.3 * cobb_deg),
                },
            ],
        }
    }

    /// A single right thoracic curve of `cobb_deg` (apex T8), hypokyphotic.
    pub fn thoracic_scoliosis(cobb_deg: f64) -> Self {
        SpineShape {
            sacral_slope: deg(45.0),
            sagittal: vec![
                Bend {
                    apex: 14.0,
                    width: 1.5,
                    angle: deg(55.0),
                },
                Bend {
                    apex: 6.0,
                    width: 3.0,
                    angle: deg(-25.0),
                },
            ],
            frontal: vec![Bend {
                apex: 7.0,
                width: 1.8,
                angle: deg(cobb_deg),
            }],
            axial: vec![Twist {
                apex: 7.0,
                width: 2.0,
                peak: deg(-0.35 * cobb_deg),
            }],
        }
    }

    fn twist_at(&self, level_index: f64) -> f64 {
        self.axial
            .iter()
            .map(|t| t.peak * (-0.5 * ((level_index - t.apex) / t.width).powi(2)).exp())
            .sum()
    }
}

/// Options for [`generate`].
#[derive(Debug, Clone, PartialEq)]
pub struct SynthOptions {
    /// Most cranial level (the set runs `top..=S1`).
    pub top: Level,
    /// The spine's shape.
    pub shape: SpineShape,
    /// Gaussian noise SD per coordinate (m); 0 for a clean set.
    pub noise_sd: f64,
    /// Seed of the noise generator.
    pub seed: u64,
}

impl Default for SynthOptions {
    fn default() -> Self {
        SynthOptions {
            top: Level::T1,
            shape: SpineShape::normal(),
            noise_sd: 0.0,
            seed: 1,
        }
    }
}

/// Position of `code` in the vertebra frame of `level` (m; x anterior, y
/// cranial, z right; origin at the body centre, or at the S1 superior
/// endplate centre for the sacrum). `None` when the code does not exist at
/// that level.
pub fn local_position(d: &LevelDimensions, code: Code) -> Option<Vector3<f64>> {
    if d.level.is_sacrum() {
        let (w, dp) = (d.sup_ep_width.mean, d.sup_ep_depth.mean);
        return Some(match code {
            Code::SEC => Vector3::zeros(),
            Code::SA => Vector3::new(0.5 * dp, 0.0, 0.0),
            Code::SP => Vector3::new(-0.5 * dp, 0.0, 0.0),
            Code::SR => Vector3::new(0.0, 0.0, 0.5 * w),
            Code::SL => Vector3::new(0.0, 0.0, -0.5 * w),
            // S1 pedicles: posterior of the endplate, 15 mm apart from the
            // midline plus half the canal (~30 mm wide sacral canal).
            Code::PTR => Vector3::new(-0.5 * dp - 0.006, -0.004, 0.02),
            Code::PTL => Vector3::new(-0.5 * dp - 0.006, -0.004, -0.02),
            _ => return None,
        });
    }
    let (ha, hp) = (d.ant_height.mean, d.post_height.mean);
    let h = 0.5 * (ha + hp);
    let (ws, ds, wi, di) = (
        d.sup_ep_width.mean,
        d.sup_ep_depth.mean,
        d.inf_ep_width.mean,
        d.inf_ep_depth.mean,
    );
    // Pedicles: just behind the posterior wall, centred laterally on
    // +-(canal width + pedicle width)/2, in the upper part of the body.
    let px = -0.5 * 0.5 * (ds + di) - 0.004;
    let pz = 0.5 * (d.canal_width.mean + d.pedicle_width.mean);
    let pc = 0.15 * h;
    let ph = 0.5 * d.pedicle_height.mean;
    Some(match code {
        Code::SEC => Vector3::new(0.0, 0.5 * h, 0.0),
        Code::IEC => Vector3::new(0.0, -0.5 * h, 0.0),
        Code::SA => Vector3::new(0.5 * ds, 0.5 * ha, 0.0),
        Code::SP => Vector3::new(-0.5 * ds, 0.5 * hp, 0.0),
        Code::SR => Vector3::new(0.0, 0.5 * h, 0.5 * ws),
        Code::SL => Vector3::new(0.0, 0.5 * h, -0.5 * ws),
        Code::IA => Vector3::new(0.5 * di, -0.5 * ha, 0.0),
        Code::IP => Vector3::new(-0.5 * di, -0.5 * hp, 0.0),
        Code::IR => Vector3::new(0.0, -0.5 * h, 0.5 * wi),
        Code::IL => Vector3::new(0.0, -0.5 * h, -0.5 * wi),
        Code::PTR => Vector3::new(px, pc + ph, pz),
        Code::PTL => Vector3::new(px, pc + ph, -pz),
        Code::PBR => Vector3::new(px, pc - ph, pz),
        Code::PBL => Vector3::new(px, pc - ph, -pz),
    })
}

/// The true vertebra frames of a synthetic spine, caudal (S1) to cranial;
/// origins at the body centres (S1: superior endplate centre).
pub fn frames(table: &DimensionTable, top: Level, shape: &SpineShape) -> Vec<VertebraFrame> {
    let levels: Vec<Level> = Level::ALL.into_iter().filter(|l| *l >= top).rev().collect(); // S1 first
                                                                                           // Joints between levels[k] (lower) and levels[k+1] (upper), at index
                                                                                           // (lower.index() - 0.5).
    let joints: Vec<f64> = levels
        .iter()
        .skip(1)
        .map(|u| u.index() as f64 + 0.5)
        .collect();
    let weights = |b: &Bend| -> Vec<f64> {
        let w: Vec<f64> = joints
            .iter()
            .map(|j| (-0.5 * ((j - b.apex) / b.width).powi(2)).exp())
            .collect();
        let s: f64 = w.iter().sum();
        w.iter()
            .map(|x| if s > 0.0 { x / s } else { 0.0 })
            .collect()
    };
    let n = joints.len();
    let mut sag = vec![0.0; n];
    let mut fro = vec![0.0; n];
    for b in &shape.sagittal {
        for (a, w) in sag.iter_mut().zip(weights(b)) {
            *a += b.angle * w;
        }
    }
    for b in &shape.frontal {
        for (a, w) in fro.iter_mut().zip(weights(b)) {
            *a += b.angle * w;
        }
    }
    let mut out = Vec::with_capacity(levels.len());
    let mut rot = Rotation3::from_axis_angle(&Vector3::z_axis(), -shape.sacral_slope);
    let mut sec_below = Point3::origin();
    out.push(VertebraFrame {
        level: Level::S1,
        origin: sec_below,
        rotation: rot,
    });
    for (k, &upper) in levels.iter().enumerate().skip(1) {
        let lower = levels[k - 1];
        let j = k - 1;
        let ax = shape.twist_at(upper.index() as f64) - shape.twist_at(lower.index() as f64);
        let rel = Rotation3::from_axis_angle(&Vector3::z_axis(), sag[j])
            * Rotation3::from_axis_angle(&Vector3::x_axis(), fro[j])
            * Rotation3::from_axis_angle(&Vector3::y_axis(), ax);
        let new_rot = rot * rel;
        let y_low = rot * Vector3::y();
        let y_up = new_rot * Vector3::y();
        let disc = table.level(upper).disc_height.mean;
        let h = table.level(upper).body_height().mean;
        let axis = (y_low + y_up).normalize();
        let iec = sec_below + axis * disc;
        let centre = iec + y_up * (0.5 * h);
        sec_below = centre + y_up * (0.5 * h);
        rot = new_rot;
        out.push(VertebraFrame {
            level: upper,
            origin: centre,
            rotation: rot,
        });
    }
    out
}

/// Generate a landmark set `top..=S1` (all 14 landmarks per vertebra, the
/// 5 required + 2 pedicle landmarks on S1).
pub fn generate(opts: &SynthOptions) -> Result<LandmarkSet> {
    let table = DimensionTable::embedded()?;
    generate_with(&table, opts)
}

/// [`generate`] with a given dimension table.
pub(crate) fn generate_with(table: &DimensionTable, opts: &SynthOptions) -> Result<LandmarkSet> {
    if !(opts.noise_sd >= 0.0 && opts.noise_sd.is_finite()) {
        return Err(Error::invalid("synth", "noise SD must be finite and >= 0"));
    }
    let mut rng = ChaCha8Rng::seed_from_u64(opts.seed);
    let normal = Normal::new(0.0, opts.noise_sd.max(f64::MIN_POSITIVE))
        .map_err(|e| Error::invalid("synth", e.to_string()))?;
    let mut set = LandmarkSet::new();
    // Generate cranial -> caudal so the noise stream is stable per level order.
    let mut fr = frames(table, opts.top, &opts.shape);
    fr.reverse();
    for f in fr {
        let d = table.level(f.level);
        for code in Code::ALL {
            if !f.level.allowed(code) {
                continue;
            }
            if let Some(local) = local_position(d, code) {
                let mut p = f.origin + f.rotation * local;
                if opts.noise_sd > 0.0 {
                    p += Vector3::new(
                        normal.sample(&mut rng),
                        normal.sample(&mut rng),
                        normal.sample(&mut rng),
                    );
                }
                set.insert(f.level, code, p);
            }
        }
    }
    Ok(set)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::landmarks::frames::{vertebra_dimensions, vertebra_frame};

    #[test]
    fn clean_set_reproduces_table_dimensions_and_frames() {
        let table = DimensionTable::embedded().unwrap();
        let shape = SpineShape::lumbar_scoliosis(75.0);
        let set = generate_with(
            &table,
            &SynthOptions {
                top: Level::T1,
                shape: shape.clone(),
                noise_sd: 0.0,
                seed: 3,
            },
        )
        .unwrap();
        assert_eq!(set.len(), 17 * 14 + 7);
        let truth = frames(&table, Level::T1, &shape);
        for f in truth.iter().filter(|f| !f.level.is_sacrum()) {
            let d = table.level(f.level);
            let got = vertebra_frame(&set, f.level).unwrap();
            // The landmark frame is the construction frame up to the
            // pedicle-height offset of the origin (none: SEC/IEC symmetric).
            assert!((got.origin - f.origin).norm() < 1e-12);
            assert!((got.rotation.matrix() - f.rotation.matrix()).norm() < 1e-9);
            let dims = vertebra_dimensions(&set, f.level);
            assert!((dims.sup_width.unwrap() - d.sup_ep_width.mean).abs() < 1e-12);
            // Wedged body: the inferior endplate is inclined by the
            // anterior/posterior height difference.
            let dh = 0.5 * (d.ant_height.mean - d.post_height.mean);
            let expect = d.inf_ep_depth.mean.hypot(dh);
            assert!((dims.inf_depth.unwrap() - expect).abs() < 1e-12);
        }
    }

    #[test]
    fn frontal_bend_gives_its_cobb_angle() {
        // Cobb angle between end vertebrae of a single frontal bend = angle.
        let table = DimensionTable::embedded().unwrap();
        let shape = SpineShape {
            sacral_slope: 0.0,
            sagittal: vec![],
            frontal: vec![Bend {
                apex: 13.5,
                width: 1.0,
                angle: 60f64.to_radians(),
            }],
            axial: vec![],
        };
        let f = frames(&table, Level::T1, &shape);
        let top = f.last().unwrap().rotation * Vector3::y();
        let bottom = f[0].rotation * Vector3::y();
        let cobb = top.angle(&bottom).to_degrees();
        assert!((cobb - 60.0).abs() < 1e-6, "{cobb}");
        // Bends to the right (+z) going up.
        assert!(top.z > 0.0);
    }

    #[test]
    fn same_seed_same_set_different_seed_differs() {
        let o = SynthOptions {
            noise_sd: 0.002,
            seed: 7,
            ..Default::default()
        };
        let a = generate(&o).unwrap();
        let b = generate(&o).unwrap();
        assert_eq!(a, b);
        let c = generate(&SynthOptions { seed: 8, ..o }).unwrap();
        assert_ne!(a, c);
    }
}
