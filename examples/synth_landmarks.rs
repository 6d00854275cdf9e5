//! Write a synthetic landmark set (fixture generator).
//!
//! `cargo run --example synth_landmarks -- OUT.csv [normal|lumbar|thoracic] [NOISE_MM] [SEED] [TOP]`

use osim_spine::landmarks::io::write_csv;
use osim_spine::landmarks::synth::{generate, SpineShape, SynthOptions};
use osim_spine::landmarks::{Frame, Level, Units};
use std::path::PathBuf;

fn main() -> anyhow::Result<()> {
    let a: Vec<String> = std::env::args().skip(1).collect();
    let out = PathBuf::from(a.first().map(String::as_str).unwrap_or("synthetic.csv"));
    let shape = match a.get(1).map(String::as_str).unwrap_or("lumbar") {
        "normal" => SpineShape::normal(),
        "thoracic" => SpineShape::thoracic_scoliosis(55.0),
        _ => SpineShape::lumbar_scoliosis(75.0),
    };
    let noise_mm: f64 = a.get(2).map(|s| s.parse()).transpose()?.unwrap_or(1.0);
    let seed: u64 = a.get(3).map(|s| s.parse()).transpose()?.unwrap_or(1);
    let top: Level = a
        .get(4)
        .map(|s| s.parse().map_err(|_| anyhow::anyhow!("bad level {s}")))
        .transpose()?
        .unwrap_or(Level::T1);
    let set = generate(&SynthOptions {
        top,
        shape,
        noise_sd: noise_mm * 1e-3,
        seed,
    })?;
    write_csv(&set, &out, Units::Millimetre, Frame::Lps)?;
    println!("wrote {} ({} landmarks)", out.display(), set.len());
    Ok(())
}
