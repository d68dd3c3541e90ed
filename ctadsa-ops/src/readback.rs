//! Device → host reads, counted. Every read the training loop makes goes through here, so that a
//! benchmark can say how many blocking reads a step makes and how many bytes they move (on a GPU
//! each one waits for all queued work: the step's pipeline drains).

use std::sync::atomic::{AtomicU64, Ordering};

use burn::tensor::Tensor;

static READS: AtomicU64 = AtomicU64::new(0);
static READ_BYTES: AtomicU64 = AtomicU64::new(0);
static UPLOADS: AtomicU64 = AtomicU64::new(0);
static UPLOAD_BYTES: AtomicU64 = AtomicU64::new(0);

/// Reads and uploads so far in this process (all threads).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Transfers {
    /// Blocking device → host reads.
    pub reads: u64,
    /// Bytes those reads moved.
    pub read_bytes: u64,
    /// Host → device uploads made by the training loop.
    pub uploads: u64,
    /// Bytes those uploads moved.
    pub upload_bytes: u64,
}

impl Transfers {
    /// The counts now.
    pub fn now() -> Self {
        Self {
            reads: READS.load(Ordering::Relaxed),
            read_bytes: READ_BYTES.load(Ordering::Relaxed),
            uploads: UPLOADS.load(Ordering::Relaxed),
            upload_bytes: UPLOAD_BYTES.load(Ordering::Relaxed),
        }
    }

    /// What happened between `earlier` and `self`.
    pub fn since(self, earlier: Self) -> Self {
        Self {
            reads: self.reads - earlier.reads,
            read_bytes: self.read_bytes - earlier.read_bytes,
            uploads: self.uploads - earlier.uploads,
            upload_bytes: self.upload_bytes - earlier.upload_bytes,
        }
    }
}

fn count_read(values: usize) {
    READS.fetch_add(1, Ordering::Relaxed);
    READ_BYTES.fetch_add(4 * values as u64, Ordering::Relaxed);
}

/// Records an upload of `values` f32 (or i32/i64 counted at 4 bytes each).
pub fn count_upload(values: usize) {
    UPLOADS.fetch_add(1, Ordering::Relaxed);
    UPLOAD_BYTES.fetch_add(4 * values as u64, Ordering::Relaxed);
}

/// A tensor's values on the host as f32 (one counted read).
///
/// Read through a detached, exact copy (`× 1`): burn-ndarray's `into_data` walks a tensor whose
/// buffer is shared — every parameter, held by its `Param` — element by element through a
/// dynamic-rank iterator (≈ 40 ns per value), while the copy is unique and moves out whole.
pub fn host_vec<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    let v = t.detach().mul_scalar(1.0).into_data().convert::<f32>().try_into_vec::<f32>().unwrap_or_default();
    count_read(v.len());
    v
}

/// The one value of a one-element tensor (one counted read).
pub fn scalar(t: Tensor<1>) -> f64 {
    count_read(1);
    t.into_scalar::<f32>() as f64
}
