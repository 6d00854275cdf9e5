//! OpenSim document I/O: a lossless XML tree of the .osim file, typed views of
//! the components the tool works on, and the upgrade of 2.x/3.x documents.
//!
//! | module | what lives there |
//! |---|---|
//! | [`xml`] | lossless XML element tree (quick-xml), hostile-input limits, deterministic tab-indented writer |
//! | [`document`] | [`Document`]: read/parse/write, component sets, property get/set, typed property helpers |
//! | [`builders`] | new elements: Body, PhysicalOffsetFrame, CustomJoint, Coordinate, BushingForce, Marker, WrapSphere, PathWrap |
//! | [`function`] | OpenSim functions (Constant, Linear, Polynomial, Multiplier, SimmSpline, NaturalCubicSpline, PiecewiseLinear) with d/dx, d2/dx2 |
//! | [`model`] | [`Model`]: typed, validated, SI snapshot; socket path resolution; joint frames |
//! | [`legacy`] | upgrade of OpenSim 1.9/2.x/3.x documents to the 4.x form on read |
//! | [`geometry`] | mesh file resolution like OpenSim (model folder, `Geometry/`, extra folders) |

pub mod builders;
pub mod document;
pub mod function;
pub mod geometry;
pub mod legacy;
pub mod model;
pub mod physics;
pub mod xml;

pub use document::{Document, CURRENT_VERSION};
pub use function::Function;
pub use model::Model;
