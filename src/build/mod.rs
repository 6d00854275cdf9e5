//! Model building: base model from a generic model, procedural anatomy for
//! the embedded default, and patient-specific model generation.

pub use crate::anatomy;
pub mod base;
pub mod generate;
pub mod procedural;
