//! `osim-spine check FILES... [--format text|json|github] [--strict]`:
//! validate landmark sets (codes in `docs/check-codes.md`).
//! Exit code 0 clean, 1 errors, 2 warnings only (1 with `--strict`).

use crate::landmarks::check::{check_file, exit_code, format_github, format_json, format_text};
use std::path::PathBuf;

/// Output formats.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
#[allow(missing_docs)] // clap prints variant doc comments in --help; the names say it
pub enum Format {
    Text,
    Json,
    Github,
}

/// Arguments of `check`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Landmark files (.csv, .trc, .json).
    #[arg(required = true)]
    pub files: Vec<PathBuf>,
    /// Output format (github: GitHub Actions annotations).
    #[arg(long, value_enum, default_value = "text")]
    pub format: Format,
    /// Warnings fail too (exit 1).
    #[arg(long)]
    pub strict: bool,
}

/// Run; returns the exit code.
pub fn run(args: &Args) -> anyhow::Result<i32> {
    let reports: Vec<_> = args.files.iter().map(|f| check_file(f)).collect();
    let out = match args.format {
        Format::Text => format_text(&reports),
        Format::Json => format_json(&reports),
        Format::Github => format_github(&reports),
    };
    crate::out!("{out}");
    if args.format == Format::Json {
        crate::outln!();
    }
    Ok(exit_code(&reports, args.strict))
}
