//! The shape completion as a library, in the order the data flows:
//! [`data`] (cases, trees, volumes, meshes, the projector, clinical import, synthetic cases) →
//! [`method`] (model, initialisation, losses, densification, training, pose refinement) →
//! [`eval`] (metrics against ground truth) → [`output`] (extracted surface, files, report) →
//! [`run`] (a completion run in its folder, an experiment matrix's cells).
//! [`config`] holds a run's settings and [`error`] the library's error type.
//! Units are millimetres in world coordinates (isocentre at the origin), as in `ctadsa-render`.
// `!(x >= y)` is our NaN-rejecting comparison idiom (NaN fails it); keep it.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod bench;
pub mod config;
pub mod data;
pub mod error;
pub mod eval;
pub mod method;
pub mod output;
pub mod run;
pub mod stats;

pub use error::{CoreError, Result};
