//! The method and its data: case folders, vessel trees and phantoms, the voxel projector used to
//! synthesise DSA views, meshes, the shape-completion model (hash-grid field + Gaussians),
//! its initialisation, losses, training loop and outputs, and the evaluation metrics.
//! Units are millimetres in world coordinates (isocentre at the origin), as in `ctadsa-render`.
// `!(x >= y)` is our NaN-rejecting comparison idiom (NaN fails it); keep it.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod case;
pub mod clinical;
pub mod config;
pub mod densify;
pub mod diagnose;
pub mod error;
pub mod eval;
pub mod export;
pub mod extraction;
pub mod icp;
pub mod init;
pub mod loss;
pub mod mesh;
pub mod metrics;
pub mod model;
pub mod ndarray_host;
pub mod optim;
pub mod plot;
pub mod pose;
pub mod projector;
pub mod report;
pub mod surface_distance;
pub mod surface_metrics;
pub mod synth;
pub mod train;
pub mod tree;
pub mod volume;
pub mod working_box;

pub use error::{CoreError, Result};
