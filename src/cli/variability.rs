//! `osim-spine variability FILES... --out DIR`: repeated-palpation
//! statistics (`variability.json`, `iqr_boxplot.svg`).

use crate::landmarks::variability;
use std::path::PathBuf;

/// Arguments of `variability`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Palpation files: one set per file (operator/repetition from
    /// `# operator:` / `# repetition:` comments, else repetitions of one
    /// operator in the order given) or CSVs with `operator,repetition` columns.
    #[arg(required = true)]
    pub files: Vec<PathBuf>,
    /// Output folder.
    #[arg(long)]
    pub out: PathBuf,
}

/// Run; returns the exit code.
pub fn run(args: &Args) -> anyhow::Result<i32> {
    let r = variability::run(&args.files, &args.out)?;
    println!(
        "{} palpations, {} operators, {} landmarks; wrote {} and {}",
        r.palpations,
        r.operators.len(),
        r.landmarks.len(),
        args.out.join("variability.json").display(),
        args.out.join("iqr_boxplot.svg").display()
    );
    for s in r.summary.iter().filter(|s| s.group == "all") {
        println!(
            "  IQR {:<9} median {:.2} mm, IQR of IQRs {:.2} mm, max {:.2} mm",
            s.axis, s.median_mm, s.iqr_mm, s.max_mm
        );
    }
    for n in &r.notes {
        println!("  note: {n}");
    }
    Ok(0)
}
