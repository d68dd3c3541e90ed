//! Large host buffers filled by all of rayon's threads: a training step allocates tens of MB
//! at a time (the encoding, its Jacobian, the MLP's activations and gradients), and a single
//! thread's `memset` of them left the other cores waiting.

use std::mem::MaybeUninit;

use rayon::prelude::*;

/// Elements per parallel task.
const CHUNK: usize = 1 << 16;

/// `n` copies of `row`, one after another: `[n · row.len()]`.
pub(crate) fn repeated_rows(row: &[f32], n: usize) -> Vec<f32> {
    let width = row.len();
    let mut values: Vec<f32> = Vec::with_capacity(n * width);
    if width > 0 {
        values.spare_capacity_mut().par_chunks_mut(width * CHUNK.div_ceil(width)).for_each(|chunk| {
            for slot in chunk.chunks_mut(width) {
                for (dst, &src) in slot.iter_mut().zip(row) {
                    *dst = MaybeUninit::new(src);
                }
            }
        });
    }
    // SAFETY: the capacity is `n · width`, and every element was initialised above (the chunks
    // cover the spare capacity, which is exactly that long, with whole rows).
    unsafe { values.set_len(n * width) };
    values
}

/// `len` zeros.
pub(crate) fn zeroed(len: usize) -> Vec<f32> {
    let mut values: Vec<f32> = Vec::with_capacity(len);
    values.spare_capacity_mut().par_chunks_mut(CHUNK).for_each(|c| c.fill(MaybeUninit::new(0.0)));
    // SAFETY: the capacity is `len`, and every one of its elements was initialised just above.
    unsafe { values.set_len(len) };
    values
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn buffers_hold_what_the_serial_constructors_give() {
        for n in [0, 1, 7, 3 * CHUNK + 5] {
            assert_eq!(zeroed(n), vec![0.0f32; n]);
            let row = [1.5f32, -2.0, 3.25];
            let serial: Vec<f32> = (0..n).flat_map(|_| row).collect();
            assert_eq!(repeated_rows(&row, n), serial);
            assert!(repeated_rows(&[], n).is_empty());
        }
    }
}
