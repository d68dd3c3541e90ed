//! Outputs of a run: the completed surface extracted from the trained density, the files a run
//! writes, plots and the HTML report (with its interactive 3-D view).

pub mod arrival;
pub mod centreline;
pub mod centring;
pub mod confidence;
pub mod export;
pub mod extraction;
pub mod plot;
pub mod report;
pub mod viewer;
