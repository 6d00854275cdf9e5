//! OpenSim document I/O: a lossless XML tree of the .osim file, typed views of
//! the components the tool works on, and the upgrade of 2.x/3.x documents.
//!
//! | module | what lives there |
//! |---|---|
//! | [`xml`] | lossless XML element tree (quick-xml), hostile-input limits, deterministic tab-indented writer |
//! | [`props`] | typed property helpers on elements (read with file and element in errors, write shortest round-trip) |
//! | [`document`] | [`Document`]: read/parse/write, component sets, property get/set |
//! | [`builders`] | new elements: Body, PhysicalOffsetFrame, CustomJoint, Coordinate, BushingForce, Marker, WrapSphere, PathWrap |
//! | [`function`] | OpenSim functions (Constant, Linear, Polynomial, Multiplier, SimmSpline, NaturalCubicSpline, PiecewiseLinear) with d/dx, d2/dx2 |
//! | [`model`] | [`Model`]: typed, validated, SI snapshot; socket path resolution; joint frames |
//! | [`legacy`] | the format versions; upgrade of OpenSim 1.9/2.x/3.x documents to the 4.x form on read |
//! | [`physics`] | what a model must be to be physical (refused on read), and the suspicious (warned) |
//! | [`lint`] | the suspicious in a whole model: named warnings |
//! | [`geometry`] | mesh file resolution like OpenSim (model folder, `Geometry/`, extra folders) |

pub mod builders;
pub mod document;
pub mod function;
pub mod geometry;
pub mod legacy;
pub mod lint;
pub mod model;
pub mod physics;
pub mod props;
pub mod xml;

pub use document::Document;
pub use function::Function;
pub use legacy::CURRENT_VERSION;
pub use model::Model;
