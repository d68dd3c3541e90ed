//! Evaluation against ground truth: exact surface distances and coverage, the paper's
//! point-set convention (with ICP), scoring of a run, where missing vessels are lost (by calibre too, and where
//! the centreline misses what the surface found) and where the new centreline lies.

pub mod calibre;
pub mod centreline_metrics;
pub mod diagnose;
pub mod icp;
pub mod metrics;
pub mod new_centreline;
pub mod new_surface;
pub mod score;
pub mod surface_metrics;
pub mod topology;
pub mod untraced;
