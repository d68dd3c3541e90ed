//! Reading a finished run's folder as data (for the tools that look at runs afterwards).

use std::path::Path;

use crate::error::{CoreError, Result, read_file};

/// The file every finished `ctadsa complete` writes last into its run folder.
pub const SUMMARY_FILE: &str = "summary.json";

/// A finished run's `summary.json`, read as JSON; a folder without one is named as not a
/// finished run folder (or as missing) rather than by the OS's "No such file".
pub fn read_run_summary(run_dir: &Path) -> Result<serde_json::Value> {
    let summary_path = run_dir.join(SUMMARY_FILE);
    if !summary_path.exists() {
        let what = if run_dir.is_dir() { "is not a finished run folder" } else { "does not exist" };
        return Err(CoreError::format(
            run_dir,
            format!(
                "{what}: no {SUMMARY_FILE} (every finished `ctadsa complete` writes one; resume an unfinished run \
                 with --resume)"
            ),
        ));
    }
    serde_json::from_slice(&read_file(&summary_path)?)
        .map_err(|e| CoreError::format(&summary_path, format!("invalid run summary: {e}")))
}
