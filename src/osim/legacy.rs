//! Upgrade of OpenSim 1.9/2.x/3.x documents to the 4.x form.
use super::xml::XmlTree;
use crate::error::{Error, Result};
use std::path::Path;

/// Upgrade `tree` (document version `version` < 40000) in place.
pub fn upgrade(tree: &mut XmlTree, version: u32, path: &Path) -> Result<()> {
    let _ = tree;
    Err(Error::parse(
        path,
        "OpenSimDocument",
        format!("legacy version {version} upgrade not yet implemented"),
    ))
}
