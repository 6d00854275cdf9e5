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
//!
//! # Examples
//!
//! A patient model from the example landmark set on the embedded default
//! base model (what `osim-spine generate --landmarks ... --out ...` does,
//! without writing files):
//!
//! ```
//! use osim_spine::embedded::BaseModel;
//! use osim_spine::generate::{generate, GenerateOptions};
//! use std::path::Path;
//!
//! let base = BaseModel::locate(None)?.read()?;
//! let set = osim_spine::landmarks::io::load(Path::new("fixtures/example-scoliosis.csv"))?;
//! let opts = GenerateOptions { views: false, ..GenerateOptions::default() };
//! let model = generate(&base, &set, "example-scoliosis.csv", &opts, None)?;
//! // T9..L5 placed from the landmarks, the levels above from the base
//! assert_eq!(model.report.levels_from_landmarks.len(), 9);
//! assert!(model.report.levels_from_base.contains(&osim_spine::anatomy::Level::T1));
//! # Ok::<(), osim_spine::Error>(())
//! ```
//!
//! Static equilibrium of the base model (no gravity) under a 2 N*m moment
//! on T1 about ground's Z axis (the sagittal bending axis: flexion), with
//! the tool's own solver:
//!
//! ```
//! use nalgebra::Vector3;
//! use osim_spine::embedded::BaseModel;
//! use osim_spine::solver::{Load, LoadFrame, StaticOptions, System, SystemSpec, Workspace};
//!
//! let model = BaseModel::locate(None)?.read()?.model()?;
//! let mut spec = SystemSpec::from_model(&model)?;
//! spec.gravity = Vector3::zeros();
//! let sys = System::new(&spec)?;
//! let mut ws = Workspace::new(&sys);
//! let moment = Load::Moment {
//!     body: "thoracic1".into(),
//!     vec: Vector3::new(0.0, 0.0, 2.0),
//!     frame: LoadFrame::Ground,
//! };
//! let loads = sys.prepare_loads(&[moment])?;
//! let q0 = sys.default_q();
//! let sol = sys.solve_static(&loads, q0.as_slice(), &mut ws, &StaticOptions::default())?;
//! // In equilibrium the bushings carry the moment: every joint bent a little.
//! assert!(sol.residual_norm < 1e-8);
//! assert!((&sol.q - &q0).amax() > 1e-4);
//! # Ok::<(), osim_spine::Error>(())
//! ```

#![warn(missing_docs, unreachable_pub)]
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
pub mod simulate;
pub mod solver;
pub mod util;

pub use error::{Error, Result};
