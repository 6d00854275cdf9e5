//! osim-spine: patient-specific scoliotic OpenSim spine models.
//!
//! The library follows the modelling pipeline; the `osim-spine` binary is a thin
//! clap shell over it (see `src/cli/`). Internally every quantity is SI
//! (m, kg, s, rad); units are converted at the edges (file readers/writers).
//!
//! | module | pipeline stage |
//! |---|---|
//! | [`osim`] | OpenSim document I/O: lossless XML tree, typed views, legacy upgrade |
//! | [`mesh`] | triangle meshes and their file formats (VTP, STL, OBJ, PLY) |
//! | [`landmarks`] | palpated landmark sets: reading, checking, variability statistics |
//! | [`build`] | base-model building, procedural anatomy, patient model generation |
//! | [`personalise`] | intervertebral stiffness tables and forms written into models |
//! | [`solver`] | rigid-body system (immutable) + workspace, statics, dynamics |
//! | [`calibrate`] | experiments, stiffness calibration, sensitivity studies |
//! | [`evaluate`] | model accuracy against patient truth (thesis metrics) |
//! | [`diagnose`] | sim-to-real gap diagnosis |
//! | [`util`] | atomic output, small shared helpers |

// Module docs name the private named steps of each stage (they resolve with
// `cargo doc --document-private-items`), so a reader sees the stage's order.
#![allow(rustdoc::private_intra_doc_links)]

pub mod anatomy;
pub mod build;
pub mod calibrate;
pub mod cli;
pub mod diagnose;
pub mod embedded;
pub mod error;
pub mod evaluate;
pub mod landmarks;
pub mod mesh;
pub mod osim;
pub mod palpation;
pub mod personalise;
pub mod segmentation;
pub mod solver;
pub mod util;

pub use error::{Error, Result};
