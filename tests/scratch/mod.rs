//! Scratch folders of the integration tests, under Cargo's tmp folder for them
//! (`CARGO_TARGET_TMPDIR`, inside the build cache).
//!
//! A test binary keeps its folders together, `<tmp>/<test binary>/<name>-<process id>`, and its
//! first call removes the folders that processes no longer running left there: a failed run's
//! outputs stay to be looked at until the binary runs again, and a build cache kept between CI
//! runs does not grow with every run.

use std::path::{Path, PathBuf};
use std::sync::Once;

/// The scratch folder `name` of this test process (not created).
pub fn scratch(name: &str) -> PathBuf {
    static SWEPT: Once = Once::new();
    let root = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(env!("CARGO_CRATE_NAME"));
    SWEPT.call_once(|| remove_ended(&root));
    root.join(format!("{name}-{}", std::process::id()))
}

/// Removes the folders under `root` whose process (the number after the name's last `-`) has
/// ended (no `/proc/<id>`; where there is no `/proc`, every other process's).
fn remove_ended(root: &Path) {
    let Ok(entries) = std::fs::read_dir(root) else { return };
    let own = std::process::id();
    for entry in entries.flatten() {
        let name = entry.file_name();
        let id = name.to_str().and_then(|n| n.rsplit_once('-')).and_then(|(_, id)| id.parse::<u32>().ok());
        if let Some(id) = id
            && id != own
            && !Path::new(&format!("/proc/{id}")).exists()
        {
            let _ = std::fs::remove_dir_all(entry.path());
        }
    }
}
