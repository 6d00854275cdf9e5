//! Regenerate `fixtures/example-scoliosis.csv` and
//! `fixtures/example-scoliosis-centres.csv` from `base_model/` (see
//! `osim_spine::generate::example`). Run from the repository root:
//! `cargo run --example example_scoliosis`.

use osim_spine::generate::example::example_scoliosis;
use osim_spine::osim::Document;
use std::path::Path;

fn main() -> anyhow::Result<()> {
    let base = Document::read("base_model/base.osim")?;
    let ex = example_scoliosis(&base)?;
    osim_spine::util::write_atomic(
        Path::new("fixtures/example-scoliosis.csv"),
        ex.landmarks_csv.as_bytes(),
    )?;
    osim_spine::util::write_atomic(
        Path::new("fixtures/example-scoliosis-centres.csv"),
        ex.centres_csv.as_bytes(),
    )?;
    println!("wrote fixtures/example-scoliosis.csv and fixtures/example-scoliosis-centres.csv");
    Ok(())
}
