//! Experiments (`../shared/formats/experiment.md`) and stiffness calibration.

pub mod experiment;
