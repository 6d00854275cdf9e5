//! `osim-spine stiffness MODEL (--table TABLE --out OUT | --list [--format F] [--out FILE])`:
//! assign intervertebral stiffness from a TOML/CSV table
//! (`docs/stiffness-table.md`), or list the model's current stiffness in the
//! same format. Everything is validated before anything is written; outputs
//! are written atomically.

use crate::osim::Document;
use crate::personalise::{self, table};
use crate::util::write_atomic;
use clap::{Args as ClapArgs, ValueEnum};
use std::path::PathBuf;

/// Table format for `--list`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
#[allow(missing_docs)] // clap prints variant doc comments in --help; the names say it
pub enum TableFormat {
    Toml,
    Csv,
}

/// Arguments of `stiffness`.
#[derive(Debug, ClapArgs)]
pub struct Args {
    /// The model (.osim).
    pub model: PathBuf,
    /// Stiffness table to apply (.toml, or .csv for linear tables).
    #[arg(long, value_name = "TABLE", conflicts_with = "list")]
    pub table: Option<PathBuf>,
    /// Output: the new model (with --table), or the listed table (with --list; default stdout).
    #[arg(long, value_name = "OUT")]
    pub out: Option<PathBuf>,
    /// Print the model's current stiffness as a table (the format --table reads).
    #[arg(long)]
    pub list: bool,
    /// Table format of --list (default: from the --out extension, else toml).
    #[arg(long, value_enum, requires = "list")]
    pub format: Option<TableFormat>,
    /// Accept non-monotone (softening) curves.
    #[arg(long)]
    pub allow_softening: bool,
    /// Allow --out to overwrite an input (the model or the table).
    #[arg(long)]
    pub force: bool,
}

/// `--out` may not overwrite the model or the table (after symlinks)
/// unless `--force`; with `--list` it must be a table file (.toml/.csv).
fn check_out(args: &Args) -> anyhow::Result<()> {
    let Some(out) = &args.out else {
        return Ok(());
    };
    let mut protected = crate::util::guard::Protected::default().file(&args.model);
    if let Some(t) = &args.table {
        protected = protected.file(t);
    }
    crate::util::guard::check_outputs(&[out], &protected, args.force)?;
    let ext = out
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    let want = match (args.list, ext.as_deref()) {
        (true, Some("toml" | "csv")) | (false, Some("osim")) => return Ok(()),
        (true, _) => "a .toml or .csv table",
        (false, _) => "a .osim model",
    };
    anyhow::bail!("{}: --out must be {want}", out.display())
}

/// Run `stiffness`; returns the exit code.
pub fn run(args: Args) -> anyhow::Result<i32> {
    check_out(&args)?;
    let doc = Document::read(&args.model)?;
    doc.model()?;
    if args.list {
        let laws = personalise::list(&doc)?;
        let fmt = args.format.unwrap_or(match &args.out {
            Some(p) if table::is_csv(p) => TableFormat::Csv,
            _ => TableFormat::Toml,
        });
        let name = args
            .model
            .file_name()
            .map(|n| n.to_string_lossy().to_string())
            .unwrap_or_default();
        let text = match fmt {
            TableFormat::Toml => table::write_toml(&name, &laws),
            TableFormat::Csv => table::write_csv(&laws)?,
        };
        match &args.out {
            Some(p) => write_atomic(p, text.as_bytes())?,
            None => crate::out!("{text}"),
        }
        return Ok(0);
    }
    let (Some(tpath), Some(out)) = (&args.table, &args.out) else {
        anyhow::bail!(
            "give --table TABLE and --out OUT.osim to assign stiffness, or --list to print it"
        );
    };
    let tab = table::read_table(tpath)?;
    let laws = personalise::resolve(&tab, &doc, args.allow_softening)?;
    let mut new = doc.clone();
    let changed = personalise::apply(&mut new, &laws)?;
    // the written model must still be a valid model the solver can read
    let model = new.model()?;
    crate::solver::SystemSpec::from_model(&model)?;
    // The input model with new stiffness only: mesh references are kept
    // even when found nowhere (so --list then --table is byte-identical).
    let missing = new.write_with_meshes(out, &[], true)?;
    super::warn_missing_meshes(out, &missing, true);
    crate::errln!(
        "{} of {} levels set from {}, {} bushing(s) rewritten -> {}",
        laws.len(),
        personalise::levels(&doc)?.len(),
        tpath.display(),
        changed.len(),
        out.display()
    );
    Ok(0)
}
