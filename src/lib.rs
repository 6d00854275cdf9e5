//! osim-spine: patient-specific scoliotic OpenSim spine models.
//!
//! The library follows the modelling pipeline; the `osim-spine` binary is a thin
//! clap shell over it (see `src/cli/`). Internally every quantity is SI
//! (m, kg, s, rad); units are converted at the edges (file readers/writers).
//!
//! Modules in pipeline order (each uses only those above it; see
//! ARCHITECTURE.md and `tests/layering.rs`):
//!
//! | module | pipeline stage |
//! |---|---|
//! | [`error`], [`util`] | the error type; input gate, atomic output, shared helpers, figures |
//! | [`osim`] | OpenSim document I/O: lossless XML tree, typed views, legacy upgrade |
//! | [`mesh`] | triangle meshes and their file formats (VTP, STL, OBJ, PLY) |
//! | [`anatomy`] | vertebral levels and their dimensions |
//! | [`landmarks`] | palpated landmark sets: reading, checking, metrics, statistics |
//! | [`palpation`] | the palpation engine: the protocol's landmarks on a vertebra mesh |
//! | [`segmentation`] | landmarks from per-level meshes or label maps (`palpate`) |
//! | [`embedded`] | the default base model and templates compiled in |
//! | [`solver`] | rigid-body system (immutable) + workspace, statics, dynamics |
//! | [`base`] | base model from a generic OpenSim model |
//! | [`procedural`] | the embedded default spine from published anatomy |
//! | [`generate`] | patient-specific model from landmarks |
//! | [`evaluate`] | model accuracy against patient truth (thesis metrics) |
//! | [`personalise`] | intervertebral stiffness tables and forms written into models |
//! | [`calibrate`] | experiments, stiffness calibration, sensitivity studies |
//! | [`flexibility`] | the patient's own relative stiffness from frontal bending films |
//! | [`diagnose`] | sim-to-real gap diagnosis |
//! | [`cli`] | the command line |

// Module docs name the private named steps of each stage (they resolve with
// `cargo doc --document-private-items`), so a reader sees the stage's order.
#![allow(rustdoc::private_intra_doc_links)]

pub mod anatomy;
pub mod base;
pub mod calibrate;
pub mod cli;
pub mod diagnose;
pub mod embedded;
pub mod error;
pub mod evaluate;
pub mod flexibility;
pub mod generate;
pub mod landmarks;
pub mod mesh;
pub mod osim;
pub mod palpation;
pub mod personalise;
pub mod procedural;
pub mod segmentation;
pub mod solver;
pub mod util;

pub use error::{Error, Result};
