//! Intervertebral stiffness: tables (uniform, per level, ratios), forms
//! (linear, non-linear, coupled) and their writing into .osim models.
