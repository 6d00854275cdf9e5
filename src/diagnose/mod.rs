//! Sim-to-real gap diagnosis (`osim-spine diagnose`).
pub mod design;
pub mod family;
pub mod fit;
pub mod select;
pub mod sim;
