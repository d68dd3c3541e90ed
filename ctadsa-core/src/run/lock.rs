//! A folder taken by one process at a time: a lock file created exclusively, naming the holder
//! (`pid P on HOST`), refreshed by its holder every [`HEARTBEAT`] and removed when the holder is
//! dropped. A second process on the same folder — a requeued SLURM task beside the first, a
//! command started twice — is refused instead of writing over the first one's checkpoints and
//! outputs. A lock is taken over when it was left behind: by a process of this machine that is
//! gone (killed with SIGKILL), or by another machine that has not refreshed it for
//! [`STALE_AFTER`] (a node that crashed or lost power; its process cannot be checked from here).

use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::sync::mpsc;
use std::thread::JoinHandle;
use std::time::{Duration, SystemTime};

use crate::error::{CoreError, Result, read_file};

/// How often a held lock's modification time is refreshed.
pub const HEARTBEAT: Duration = Duration::from_secs(30);

/// Another machine's lock not refreshed for this long is taken as left by a node that is gone
/// (twenty heartbeats: room for clock skew between nodes and a stalled shared file system).
pub const STALE_AFTER: Duration = Duration::from_secs(600);

/// A held lock; dropping it stops the heartbeat and releases the folder.
#[derive(Debug)]
pub struct FolderLock {
    path: PathBuf,
    /// Dropped to stop the heartbeat thread.
    stop: Option<mpsc::Sender<()>>,
    heartbeat: Option<JoinHandle<()>>,
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
                    let (stop, heartbeat) = start_heartbeat(&path);
                    return Ok(Self { path, stop, heartbeat });
                }
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {
                    let other = read_file(&path).map(|b| String::from_utf8_lossy(&b).into_owned()).unwrap_or_default();
                    if lock_is_stale(&other, &path) {
                        let _ = std::fs::remove_file(&path);
                        continue;
                    }
                    let age = lock_age(&path).map(|a| format!(", refreshed {} s ago", a.as_secs())).unwrap_or_default();
                    return Err(CoreError::format(
                        &path,
                        format!(
                            "{what} is being run by {}{age} (another machine's lock not refreshed for {} min \
                             is taken over; remove this file if no such process runs)",
                            if other.is_empty() { "another process".to_string() } else { other },
                            STALE_AFTER.as_secs() / 60
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
        drop(self.stop.take());
        if let Some(h) = self.heartbeat.take() {
            let _ = h.join();
        }
        let _ = std::fs::remove_file(&self.path);
    }
}

/// A thread that refreshes the lock's modification time every [`HEARTBEAT`] until its sender is
/// dropped. Without a thread (none could be started) the lock still holds on this machine; another
/// machine takes it over after [`STALE_AFTER`].
fn start_heartbeat(path: &Path) -> (Option<mpsc::Sender<()>>, Option<JoinHandle<()>>) {
    let (stop, stopped) = mpsc::channel::<()>();
    let path = path.to_path_buf();
    let thread = std::thread::Builder::new().name("lock-heartbeat".into()).spawn(move || {
        while let Err(mpsc::RecvTimeoutError::Timeout) = stopped.recv_timeout(HEARTBEAT) {
            refresh(&path);
        }
    });
    match thread {
        Ok(h) => (Some(stop), Some(h)),
        Err(_) => (None, None),
    }
}

/// Sets the lock's modification time to now (never creates it).
fn refresh(path: &Path) {
    if let Ok(f) = std::fs::OpenOptions::new().write(true).open(path) {
        let _ = f.set_modified(SystemTime::now());
    }
}

/// How long ago a regular lock file was last refreshed (`None` for anything else, or a time in
/// the future: another node's clock ahead of ours).
fn lock_age(path: &Path) -> Option<Duration> {
    let meta = std::fs::symlink_metadata(path).ok().filter(|m| m.is_file())?;
    SystemTime::now().duration_since(meta.modified().ok()?).ok()
}

/// This machine's name, as locks record it.
pub fn hostname() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .map(|h| h.trim().to_string())
        .ok()
        .filter(|h| !h.is_empty())
        .unwrap_or_else(|| "this machine".into())
}

/// Whether the lock at `path`, reading `text`, was left behind: `pid P on <this host>` for a
/// process that no longer exists (Linux), or a regular file of any other holder not refreshed
/// for [`STALE_AFTER`]. A live process of this machine keeps its lock however old (a suspended
/// job refreshes nothing).
fn lock_is_stale(text: &str, path: &Path) -> bool {
    let this_host = text
        .strip_prefix("pid ")
        .and_then(|rest| rest.split_once(" on "))
        .and_then(|(pid, host)| Some((pid.parse::<u32>().ok()?, host)))
        .filter(|(_, host)| *host == hostname());
    match this_host {
        Some((pid, _)) if Path::new("/proc/self").exists() => !Path::new(&format!("/proc/{pid}")).exists(),
        _ => lock_age(path).is_some_and(|age| age > STALE_AFTER),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_holder_at_a_time_and_left_locks_are_taken_over() {
        let temp = tempfile::tempdir().unwrap();
        let dir = temp.path().to_path_buf();
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
        // Another machine's lock is kept while it is refreshed, taken over once it is not.
        let other = dir.join("x.lock");
        std::fs::write(&other, format!("pid {} on another-host", u32::MAX - 1)).unwrap();
        let err = FolderLock::take(&dir, "x.lock", "the folder").unwrap_err().to_string();
        assert!(err.contains("another-host") && err.contains("refreshed 0 s ago"), "{err}");
        let set_age = |age: Duration| {
            let f = std::fs::OpenOptions::new().write(true).open(&other).unwrap();
            f.set_modified(SystemTime::now() - age).unwrap();
        };
        set_age(STALE_AFTER - Duration::from_secs(60));
        assert!(FolderLock::take(&dir, "x.lock", "the folder").is_err(), "refreshed within the limit");
        set_age(STALE_AFTER + Duration::from_secs(60));
        let lock = FolderLock::take(&dir, "x.lock", "the folder").expect("a crashed node's lock is taken over");
        // The holder's heartbeat keeps its own lock fresh; dropping it does not wait a heartbeat.
        set_age(Duration::from_secs(3600));
        refresh(&other);
        assert!(lock_age(&other).is_some_and(|a| a < Duration::from_secs(60)));
        let t = std::time::Instant::now();
        drop(lock);
        assert!(t.elapsed() < Duration::from_secs(5) && !other.exists());
        // An empty lock (a holder that died between creating and writing it) follows the age rule.
        std::fs::write(&other, "").unwrap();
        assert!(FolderLock::take(&dir, "x.lock", "the folder").is_err());
        set_age(STALE_AFTER * 2);
        drop(FolderLock::take(&dir, "x.lock", "the folder").expect("an old empty lock is taken over"));
    }
}
