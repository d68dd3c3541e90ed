//! Large host buffers filled by all of rayon's threads: a training step allocates tens of MB
//! at a time (the encoding, its Jacobian, the MLP's activations and gradients), and a single
//! thread's `memset` of them left the other cores waiting.

use std::mem::MaybeUninit;

use rayon::prelude::*;

/// Elements per parallel task.
const CHUNK: usize = 1 << 16;

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
    fn zeroed_holds_what_the_serial_constructor_gives() {
        for n in [0, 1, 7, 3 * CHUNK + 5] {
            assert_eq!(zeroed(n), vec![0.0f32; n]);
        }
    }
}
