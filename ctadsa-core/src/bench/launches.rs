//! Kernel launches on a CubeCL device (wgpu), counted per kernel and optionally timed on the
//! device (timestamp queries), through CubeCL's process-wide launch observer.
//!
//! Counts are what the host issued: the same on every adapter (a GPU or Mesa lavapipe). Device
//! times come from the adapter's timestamp queries where it has them; each timed launch costs a
//! round trip to the device thread, so a timed pass runs slower than an untimed one, but each
//! kernel's device time is its own.

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use super::KernelLaunches;
use burn_cubecl::cubecl::logging::{LaunchObservation, LaunchObserver, ProfileDuration, TimingRequest};

#[derive(Default)]
struct Recorded {
    counts: BTreeMap<&'static str, u64>,
    pending: Vec<(&'static str, ProfileDuration)>,
    device_time: BTreeMap<&'static str, Duration>,
}

struct Observer {
    timed: bool,
    recorded: Mutex<Recorded>,
}

impl LaunchObserver for Observer {
    fn launched(&self, kernel: &'static str) {
        if let Ok(mut r) = self.recorded.lock() {
            *r.counts.entry(kernel).or_default() += 1;
        }
    }

    fn timing(&self) -> TimingRequest {
        if self.timed { TimingRequest::Deferred } else { TimingRequest::None }
    }

    fn profiled(&self, kernel: &'static str, profile: ProfileDuration) {
        if let Ok(mut r) = self.recorded.lock() {
            r.pending.push((kernel, profile));
        }
    }

    fn timed(&self, kernel: &'static str, duration: Duration, _method: burn_cubecl::cubecl::logging::TimingMethod) {
        if let Ok(mut r) = self.recorded.lock() {
            *r.device_time.entry(kernel).or_default() += duration;
        }
    }
}

/// Watches every kernel launch of this process while it lives.
#[must_use = "launches are counted only while the watch lives"]
pub struct LaunchWatch {
    observer: Arc<Observer>,
    _observation: LaunchObservation,
}

impl LaunchWatch {
    /// Starts counting launches; `timed`: also time each on the device.
    pub fn start(timed: bool) -> Self {
        let observer = Arc::new(Observer { timed, recorded: Mutex::new(Recorded::default()) });
        let observation = LaunchObservation::new(observer.clone());
        Self { observer, _observation: observation }
    }

    /// What was launched since the start (or the last `take`), and resets. Waits for the timed
    /// launches to finish on the device.
    pub fn take(&self) -> KernelLaunches {
        let recorded = self.observer.recorded.lock().map(|mut r| std::mem::take(&mut *r)).unwrap_or_default();
        let short = |name: &str| {
            let base = name.split('<').next().unwrap_or(name);
            base.rsplit("::").next().unwrap_or(base).to_string()
        };
        let mut out = KernelLaunches::default();
        for (k, c) in recorded.counts {
            *out.counts.entry(short(k)).or_default() += c;
        }
        for (k, d) in recorded.device_time {
            *out.device_time.entry(short(k)).or_default() += d;
        }
        for (k, profile) in recorded.pending {
            if let Some(ticks) = burn::backend::read_sync(profile.resolve()) {
                *out.device_time.entry(short(k)).or_default() += ticks.duration();
            }
        }
        out
    }
}
