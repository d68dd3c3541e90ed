//! Host access to burn-ndarray tensors without copies where possible (the renderer's helpers).

pub use ctadsa_render::kernels::{host, with_host};
