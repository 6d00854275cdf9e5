//! Palpated landmark sets (`../shared/formats/landmarks.md`): reading CSV, TRC
//! and JSON, units and frame handling, checks and variability statistics.
