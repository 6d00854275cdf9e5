//! The palpations of a repeated-palpation study, loaded and resolved into
//! landmark sets: what [`super::variability`] analyses and
//! [`super::propagation`] turns into models.

use crate::error::{Error, Result};
use crate::landmarks::LandmarkSet;
use std::collections::BTreeMap;
use std::path::PathBuf;

/// One palpation with a resolved set.
#[derive(Debug, Clone, PartialEq)]
pub struct PalpationSet {
    /// Operator identifier.
    pub operator: String,
    /// Repetition number of that operator.
    pub repetition: u32,
    /// The landmark file.
    pub source: PathBuf,
    /// The landmarks, validated (m, OpenSim frame).
    pub set: LandmarkSet,
}

/// Load palpations from files (one per file, or CSVs with operator and
/// repetition columns). When no file gives operator/repetition (every
/// palpation is operator "1", repetition 1), the files are taken as
/// repetitions 1, 2, ... of one operator in the order given.
pub fn load_palpations(paths: &[PathBuf]) -> Result<Vec<PalpationSet>> {
    // The same file (by content) twice would be a perfect repeatability.
    let mut contents: BTreeMap<Vec<u8>, &PathBuf> = BTreeMap::new();
    for p in paths {
        let bytes = crate::util::read_bytes_capped(
            p,
            crate::landmarks::io::MAX_FILE_BYTES,
            "landmark files",
        )?;
        if let Some(first) = contents.insert(bytes, p) {
            return Err(Error::invalid(
                p.display().to_string(),
                format!(
                    "the same content as {}: a palpation given twice would show a perfect agreement (ICC 1) that was never measured",
                    first.display()
                ),
            ));
        }
    }
    let mut out = Vec::new();
    for p in paths {
        for pal in crate::landmarks::io::read_palpations(p)? {
            let set = pal.raw.to_set()?;
            out.push(PalpationSet {
                operator: pal.operator,
                repetition: pal.repetition,
                source: p.clone(),
                set,
            });
        }
    }
    if out.len() > 1 && out.iter().all(|p| p.operator == "1" && p.repetition == 1) {
        for (i, p) in out.iter_mut().enumerate() {
            p.repetition = i as u32 + 1;
        }
    }
    let mut seen = BTreeMap::new();
    for p in &out {
        if let Some(prev) = seen.insert((p.operator.clone(), p.repetition), p.source.clone()) {
            return Err(Error::invalid(
                p.source.display().to_string(),
                format!(
                    "operator `{}` repetition {} appears twice (also in {})",
                    p.operator,
                    p.repetition,
                    prev.display()
                ),
            ));
        }
    }
    Ok(out)
}
