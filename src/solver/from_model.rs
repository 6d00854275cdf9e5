//! Adapter from the typed OpenSim model ([`crate::osim::model::Model`]) to
//! the solver's [`SystemSpec`]: bodies, joints (WeldJoint, PinJoint,
//! UniversalJoint, SliderJoint, BallJoint, GimbalJoint, FreeJoint,
//! CustomJoint with any axes and functions; BallJoint and FreeJoint keep
//! OpenSim's angular-velocity speeds, see [`JointKind::Free`]), coordinates (mapped by name), BushingForces, gravity.
//! Muscles and other force elements contribute no force to the solver; see
//! [`ignored_forces`]. Coordinate coupler constraints are not enforced.

use super::spec::*;
use crate::error::{Error, Result};
use crate::osim::model::{Force, JointKind as OJointKind, Model, OtherBushing};
use nalgebra::{Matrix3, Vector3};
use std::collections::BTreeMap;

/// The model's function for the solver: every class the solver evaluates
/// (an unsupported one, also inside a multiplier, is refused here).
fn convert_function(f: &Function, ctx: &str) -> Result<Function> {
    match f {
        Function::Unsupported { class } => Err(Error::invalid(
            ctx,
            format!("function class {class} is not supported by the solver"),
        )),
        Function::Multiplier { inner, .. } => {
            convert_function(inner, ctx)?;
            Ok(f.clone())
        }
        _ => Ok(f.clone()),
    }
}

/// Property names of a FunctionBasedBushingForce's six functions, in deflection order.
pub const FBBF_FUNCTIONS: [&str; 6] = [
    "m_x_theta_x_function",
    "m_y_theta_y_function",
    "m_z_theta_z_function",
    "f_x_delta_x_function",
    "f_y_delta_y_function",
    "f_z_delta_z_function",
];

/// Property names of an ExpressionBasedBushingForce's six expressions, in deflection order.
pub const EBBF_EXPRESSIONS: [&str; 6] = [
    "Mx_expression",
    "My_expression",
    "Mz_expression",
    "Fx_expression",
    "Fy_expression",
    "Fz_expression",
];

/// Diagonal damping of a function- or expression-based bushing (0 when absent, as in OpenSim).
fn other_damping(b: &OtherBushing, ctx: &str) -> Result<[f64; 6]> {
    let mut d = [0.0; 6];
    for (k, prop) in ["rotational_damping", "translational_damping"]
        .iter()
        .enumerate()
    {
        if let Some((_, text)) = b.properties.iter().find(|(t, _)| t == prop) {
            let v: Vec<f64> = text
                .split_whitespace()
                .map(|w| w.parse::<f64>())
                .collect::<std::result::Result<_, _>>()
                .map_err(|_| Error::invalid(ctx, format!("<{prop}> is not a list of numbers")))?;
            if v.len() != 3 || !v.iter().all(|x| x.is_finite()) {
                return Err(Error::invalid(
                    ctx,
                    format!("<{prop}> must hold 3 finite numbers"),
                ));
            }
            d[3 * k..3 * k + 3].copy_from_slice(&v);
        }
    }
    Ok(d)
}

/// The force law of a FunctionBasedBushingForce or ExpressionBasedBushingForce.
/// Missing functions/expressions are zero (OpenSim's defaults). An
/// expression-based bushing whose six expressions are all linear forms of
/// the deflection becomes [`BushingModel::Coupled`].
fn other_bushing_model(b: &OtherBushing, ctx: &str) -> Result<BushingModel> {
    let damping = other_damping(b, ctx)?;
    match b.class.as_str() {
        "FunctionBasedBushingForce" => {
            let mut curves: Vec<Curve> = Vec::with_capacity(6);
            for prop in FBBF_FUNCTIONS {
                let f = match b.functions.iter().find(|(t, _)| t == prop) {
                    Some((_, f)) => convert_function(f, &format!("{ctx}: <{prop}>"))?,
                    None => Function::Constant(0.0),
                };
                curves.push(Curve::Function(f));
            }
            let curves: [Curve; 6] = curves
                .try_into()
                .map_err(|_| Error::invalid(ctx, "needs six functions"))?;
            Ok(BushingModel::PerDof {
                curves: Box::new(curves),
                damping,
            })
        }
        "ExpressionBasedBushingForce" => {
            let mut exprs: Vec<Expr> = Vec::with_capacity(6);
            for prop in EBBF_EXPRESSIONS {
                let text = b
                    .properties
                    .iter()
                    .find(|(t, _)| t == prop)
                    .map(|(_, v)| v.as_str())
                    .unwrap_or("0.0");
                let e = Expr::parse(text)
                    .map_err(|e| Error::invalid(ctx, format!("<{prop}> '{text}': {e}")))?;
                exprs.push(e);
            }
            let rows: Option<Vec<[f64; 6]>> =
                exprs.iter().map(|e| e.linear_coefficients()).collect();
            if let Some(rows) = rows {
                let k = nalgebra::Matrix6::from_fn(|i, j| rows[i][j]);
                return Ok(BushingModel::Coupled {
                    stiffness: k,
                    damping,
                });
            }
            let exprs: [Expr; 6] = exprs
                .try_into()
                .map_err(|_| Error::invalid(ctx, "needs six expressions"))?;
            Ok(BushingModel::Expression {
                exprs: Box::new(exprs),
                damping,
            })
        }
        other => Err(Error::invalid(
            ctx,
            format!("bushing class {other} is not supported by the solver"),
        )),
    }
}

/// Names (class: name) of force elements the solver does not apply.
pub fn ignored_forces(model: &Model) -> Vec<String> {
    model
        .forces
        .iter()
        .filter(|f| !matches!(f, Force::Bushing(_) | Force::OtherBushing(_)))
        .map(|f| format!("{}: {}", f.class(), f.name()))
        .collect()
}

impl SystemSpec {
    /// Build the solver description of an OpenSim model.
    pub fn from_model(model: &Model) -> Result<SystemSpec> {
        let mut spec = SystemSpec::kinematics_from_model(model)?;
        let file = model.file.display().to_string();
        let body_idx: BTreeMap<&str, usize> = model
            .bodies
            .iter()
            .enumerate()
            .map(|(i, b)| (b.name.as_str(), i))
            .collect();
        let mut bushings = Vec::new();
        // A bushing's frame: the body it is fixed to (None = ground) and the
        // frame's transform in that body.
        let frame = |name: &str, ctx: &str, socket: &str| -> Result<FrameSpec> {
            let (bn, x) = model.resolve_frame(&format!("/forceset/{name}"), socket)?;
            let body = if bn == "ground" {
                None
            } else {
                Some(*body_idx.get(bn.as_str()).ok_or_else(|| {
                    Error::invalid(ctx.to_string(), format!("body '{bn}' not found"))
                })?)
            };
            Ok(FrameSpec { body, transform: x })
        };
        for f in &model.forces {
            match f {
                Force::Bushing(b) => {
                    let ctx = format!("{file}: BushingForce '{}'", b.name);
                    bushings.push(BushingSpec {
                        name: b.name.clone(),
                        frame1: frame(&b.name, &ctx, &b.socket_frame1)?,
                        frame2: frame(&b.name, &ctx, &b.socket_frame2)?,
                        model: BushingModel::Linear {
                            rot_stiffness: b.rotational_stiffness,
                            trans_stiffness: b.translational_stiffness,
                            rot_damping: b.rotational_damping,
                            trans_damping: b.translational_damping,
                        },
                    });
                }
                Force::OtherBushing(b) => {
                    let ctx = format!("{file}: {} '{}'", b.class, b.name);
                    bushings.push(BushingSpec {
                        name: b.name.clone(),
                        frame1: frame(&b.name, &ctx, &b.socket_frame1)?,
                        frame2: frame(&b.name, &ctx, &b.socket_frame2)?,
                        model: other_bushing_model(b, &ctx)?,
                    });
                }
                _ => {}
            }
        }
        spec.bushings = bushings;
        Ok(spec)
    }

    /// The kinematic part of [`SystemSpec::from_model`]: bodies, joints,
    /// coordinates and gravity, no force elements (so models whose forces
    /// the solver does not model still have forward kinematics).
    pub fn kinematics_from_model(model: &Model) -> Result<SystemSpec> {
        let file = model.file.display().to_string();
        // bodies and coordinates keep the model's order
        let (bodies, body_idx) = spec_bodies(model);
        let (coordinates, coord_idx) = spec_coordinates(model);
        let frames = model.joint_frames()?;
        let mut joints = Vec::with_capacity(model.joints.len());
        for (j, fr) in model.joints.iter().zip(&frames) {
            let ctx = format!("{file}: joint '{}'", j.name);
            let body =
                |name: &str| -> Result<Option<usize>> {
                    if name == "ground" {
                        return Ok(None);
                    }
                    body_idx.get(name).copied().map(Some).ok_or_else(|| {
                        Error::invalid(ctx.clone(), format!("body '{name}' not found"))
                    })
                };
            let parent = body(&fr.parent_body)?;
            let Some(child) = body(&fr.child_body)? else {
                return Err(Error::invalid(ctx, "a joint's child frame may not be on ground (reversed joints are not supported)"));
            };
            joints.push(JointSpec {
                name: j.name.clone(),
                parent,
                child,
                x_pf: fr.parent_in_body,
                x_bm: fr.child_in_body,
                kind: joint_kind(j, &coord_idx, &ctx)?,
            });
        }
        Ok(SystemSpec {
            bodies,
            joints,
            coordinates,
            bushings: Vec::new(),
            gravity: model.gravity,
        })
    }

    /// Read an .osim file and build its solver description.
    pub fn read_osim(path: &std::path::Path) -> Result<SystemSpec> {
        let doc = crate::osim::document::Document::read(path)?;
        let model = doc.model()?;
        SystemSpec::from_model(&model)
    }
}

/// The model's bodies as solver bodies, and their indices by name.
fn spec_bodies(model: &Model) -> (Vec<BodySpec>, BTreeMap<&str, usize>) {
    let mut body_idx: BTreeMap<&str, usize> = BTreeMap::new();
    let mut bodies = Vec::with_capacity(model.bodies.len());
    for (i, b) in model.bodies.iter().enumerate() {
        let [ixx, iyy, izz, ixy, ixz, iyz] = b.inertia;
        let inertia = Matrix3::new(ixx, ixy, ixz, ixy, iyy, iyz, ixz, iyz, izz);
        body_idx.insert(b.name.as_str(), i);
        bodies.push(BodySpec {
            name: b.name.clone(),
            mass: b.mass,
            com: b.mass_center,
            inertia,
        });
    }
    (bodies, body_idx)
}

/// The model's coordinates as solver coordinates, and their indices by name.
fn spec_coordinates(model: &Model) -> (Vec<CoordinateSpec>, BTreeMap<String, usize>) {
    let mut coordinates = Vec::new();
    let mut coord_idx: BTreeMap<String, usize> = BTreeMap::new();
    for c in model.coordinates() {
        coord_idx.insert(c.name.clone(), coordinates.len());
        coordinates.push(CoordinateSpec {
            name: c.name.clone(),
            default: c.default_value,
            range: c.range,
            clamped: c.clamped,
            locked: c.locked,
        });
    }
    (coordinates, coord_idx)
}

/// The solver joint kind of a model joint (its own coordinates by index).
fn joint_kind(
    j: &crate::osim::model::Joint,
    coord_idx: &BTreeMap<String, usize>,
    ctx: &str,
) -> Result<JointKind> {
    let own: Vec<usize> =
        j.coordinates
            .iter()
            .map(|c| {
                coord_idx.get(&c.name).copied().ok_or_else(|| {
                    Error::invalid(ctx, format!("coordinate '{}' not found", c.name))
                })
            })
            .collect::<Result<_>>()?;
    let need = |n: usize| -> Result<()> {
        if own.len() != n {
            return Err(Error::invalid(
                ctx,
                format!("{} needs {n} coordinates, has {}", j.class, own.len()),
            ));
        }
        Ok(())
    };
    Ok(match (&j.kind, j.class.as_str()) {
        (OJointKind::Weld, _) => JointKind::Weld,
        (OJointKind::Pin, _) => {
            need(1)?;
            JointKind::Pin { coord: own[0] }
        }
        (OJointKind::Free, _) => {
            need(6)?;
            JointKind::Free {
                coords: [own[0], own[1], own[2], own[3], own[4], own[5]],
            }
        }
        (OJointKind::Custom { axes }, _) => custom_axes(axes, coord_idx, ctx)?,
        (OJointKind::Other, "UniversalJoint") => {
            need(2)?;
            JointKind::Universal {
                coords: [own[0], own[1]],
            }
        }
        (OJointKind::Other, "SliderJoint") => {
            need(1)?;
            JointKind::Slider { coord: own[0] }
        }
        (OJointKind::Other, "BallJoint") => {
            need(3)?;
            JointKind::Ball {
                coords: [own[0], own[1], own[2]],
            }
        }
        (OJointKind::Other, "GimbalJoint") => {
            // body-fixed X-Y-Z like BallJoint, but Simbody's Gimbal
            // mobilizer has u = qdot: a plain three-axis rotation
            need(3)?;
            let (x, y, z) = (Vector3::x(), Vector3::y(), Vector3::z());
            JointKind::Custom {
                axes: Box::new([
                    TransformAxis::identity(x, own[0]),
                    TransformAxis::identity(y, own[1]),
                    TransformAxis::identity(z, own[2]),
                    TransformAxis::fixed(x),
                    TransformAxis::fixed(y),
                    TransformAxis::fixed(z),
                ]),
            }
        }
        (_, class) => {
            return Err(Error::invalid(
                ctx,
                format!("joint class {class} is not supported by the solver"),
            ))
        }
    })
}

/// A CustomJoint's six transform axes (one coordinate at most each).
fn custom_axes(
    axes: &[crate::osim::model::TransformAxis],
    coord_idx: &BTreeMap<String, usize>,
    ctx: &str,
) -> Result<JointKind> {
    if axes.len() != 6 {
        return Err(Error::invalid(
            ctx,
            format!(
                "SpatialTransform needs 6 transform axes, has {}",
                axes.len()
            ),
        ));
    }
    let mut out = Vec::with_capacity(6);
    for ta in axes {
        let actx = format!("{ctx}: {}", ta.name);
        let coord = match ta.coordinates.as_slice() {
            [] => None,
            [c] => Some(*coord_idx.get(c).ok_or_else(|| {
                Error::invalid(actx.clone(), format!("coordinate '{c}' not found"))
            })?),
            _ => {
                return Err(Error::invalid(
                    actx,
                    "transform axes driven by several coordinates are not supported",
                ))
            }
        };
        out.push(TransformAxis {
            axis: ta.axis,
            coord,
            function: convert_function(&ta.function, &actx)?,
        });
    }
    let arr: [TransformAxis; 6] = out
        .try_into()
        .map_err(|_| Error::invalid(ctx, "needs 6 axes"))?;
    Ok(JointKind::Custom {
        axes: Box::new(arr),
    })
}
