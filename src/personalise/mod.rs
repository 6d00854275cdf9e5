//! Intervertebral stiffness: tables (uniform, per level, ratios), forms
//! (linear, non-linear, coupled) and their writing into .osim models.
//!
//! | file | what lives there |
//! |---|---|
//! | `linear` | [`linear::set_linear_bushing_stiffness`]: BushingForce stiffness values into a document |

pub mod linear;
