//! A folder taken by one process at a time: a lock file created exclusively, naming the holder
//! (`pid P on HOST`), removed when the holder is dropped. A second process on the same folder —
//! a requeued SLURM task beside the first, a command started twice — is refused instead of
//! writing over the first one's checkpoints and outputs. A lock left by a process of this
//! machine that is gone (killed with SIGKILL) is taken over; another machine's cannot be checked
//! from here and is reported.

use std::io::Write as _;
use std::path::{Path, PathBuf};

use crate::error::{CoreError, Result, read_file};

/// A held lock; dropping it releases the folder.
#[derive(Debug)]
pub struct FolderLock {
    path: PathBuf,
}

impl FolderLock {
    /// Takes `dir/file_name` (creating `dir`); `what` names the folder in the refusal
    /// ("the cell", "the run folder").
    pub fn take(dir: &Path, file_name: &str, what: &str) -> Result<Self> {
        std::fs::create_dir_all(dir).map_err(|e| CoreError::io(dir, e))?;
        let path = dir.join(file_name);
        let holder = format!("pid {} on {}", std::process::id(), hostname());
        for _ in 0..2 {
            match std::fs::OpenOptions::new().write(true).create_new(true).open(&path) {
                Ok(mut f) => {
                    f.write_all(holder.as_bytes()).map_err(|e| CoreError::io(&path, e))?;
                    return Ok(Self { path });
                }
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {
                    let other = read_file(&path).map(|b| String::from_utf8_lossy(&b).into_owned()).unwrap_or_default();
                    if lock_is_stale(&other) {
                        let _ = std::fs::remove_file(&path);
                        continue;
                    }
                    return Err(CoreError::format(
                        &path,
                        format!(
                            "{what} is being run by {} (remove this file if no such process runs)",
                            if other.is_empty() { "another process".to_string() } else { other }
                        ),
                    ));
                }
                Err(e) => return Err(CoreError::io(&path, e)),
            }
        }
        Err(CoreError::format(&path, format!("cannot take the lock of {what}")))
    }
}

impl Drop for FolderLock {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.path);
    }
}

/// This machine's name, as locks record it.
pub fn hostname() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .map(|h| h.trim().to_string())
        .ok()
        .filter(|h| !h.is_empty())
        .unwrap_or_else(|| "this machine".into())
}

/// Whether a lock reads `pid P on <this host>` for a process that no longer exists (Linux).
fn lock_is_stale(text: &str) -> bool {
    let Some(rest) = text.strip_prefix("pid ") else { return false };
    let Some((pid, host)) = rest.split_once(" on ") else { return false };
    let Ok(pid) = pid.parse::<u32>() else { return false };
    host == hostname() && Path::new("/proc/self").exists() && !Path::new(&format!("/proc/{pid}")).exists()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_holder_at_a_time_and_a_dead_holder_is_taken_over() {
        let dir = std::env::temp_dir().join(format!("ctadsa-lock-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let lock = FolderLock::take(&dir, "x.lock", "the folder").unwrap();
        let err = FolderLock::take(&dir, "x.lock", "the folder").unwrap_err().to_string();
        assert!(err.contains("the folder is being run by pid") && err.contains("x.lock"), "{err}");
        drop(lock);
        assert!(!dir.join("x.lock").exists(), "released when dropped");
        // Process 1 always runs; a pid past the kernel's limit never does.
        std::fs::write(dir.join("x.lock"), format!("pid 1 on {}", hostname())).unwrap();
        assert!(FolderLock::take(&dir, "x.lock", "the folder").is_err(), "a live holder keeps it");
        std::fs::write(dir.join("x.lock"), format!("pid {} on {}", u32::MAX - 1, hostname())).unwrap();
        drop(FolderLock::take(&dir, "x.lock", "the folder").expect("a dead holder's lock is taken over"));
        std::fs::write(dir.join("x.lock"), format!("pid {} on another-host", u32::MAX - 1)).unwrap();
        assert!(FolderLock::take(&dir, "x.lock", "the folder").is_err(), "another machine's is kept");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
