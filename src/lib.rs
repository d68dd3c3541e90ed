//! ctadsa — 3-D cerebrovascular shape completion from DSA views and a CTA prior.
//!
//! This umbrella crate re-exports the two libraries and owns the end-to-end tests (`tests/`):
//! - [`render`]: the differentiable cone-beam X-ray Gaussian renderer (a burn op);
//! - [`core`]: cases, phantoms, the projector, the model, training, meshes and metrics.

pub use ctadsa_core as core;
pub use ctadsa_render as render;
