//! Fuzz the experiment reader: the input is `experiment.toml` text, a line
//! `=====`, then `kinematics.csv` text. Both go through the parsers that
//! `Experiment::read` uses (`parse_experiment_toml`, `parse_kinematics`);
//! pairs are checked against the spine's own adjacency (`lumbar5` on
//! `sacrum`, ...), as a model would. Any input must give Ok or a clean Err.
//! Run: `cargo +nightly fuzz run experiment -- -max_total_time=180`.
#![no_main]

use libfuzzer_sys::fuzz_target;
use osim_spine::calibrate::experiment::{
    parse_cases, parse_experiment_toml, parse_kinematics, PairError,
};
use osim_spine::landmarks::Level;
use std::path::Path;

fn adjacent(u: &str, l: &str) -> Result<(), PairError> {
    let up = Level::from_body_name(u).ok_or_else(|| PairError::UnknownBody {
        body: u.into(),
        column: "upper",
        known: "the spine's bodies".into(),
    })?;
    match up.caudal() {
        Some(c) if c.body_name() == l => Ok(()),
        _ => Err(PairError::NotAdjacent {
            upper: u.into(),
            lower: l.into(),
            parent: None,
        }),
    }
}

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let (toml_text, csv_text) = text.split_once("\n=====\n").unwrap_or((text, ""));
    let _ = parse_cases(toml_text, Path::new("fuzz-loads.toml"));
    let Ok(exp) = parse_experiment_toml(toml_text, Path::new("experiment.toml")) else {
        return;
    };
    if let Ok(rows) = parse_kinematics(
        csv_text,
        Path::new("kinematics.csv"),
        &exp.cases,
        &exp.units,
        &adjacent,
    ) {
        for r in &rows {
            assert!(r.case < exp.cases.len());
            assert!(r.values.iter().flatten().all(|v| v.is_finite()));
        }
    }
    for c in &exp.cases {
        let _ = c.loads(Some(&exp.fixed_body));
    }
});
