//! Experiments (`../shared/formats/experiment.md`) and stiffness calibration.
