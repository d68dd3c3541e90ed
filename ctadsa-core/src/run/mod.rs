//! The jobs the binary runs, as library code so that the CLI only parses and prints and the
//! tests call the same code: one completion run in its output folder (start, resume,
//! checkpoints, stop, outputs), an ensemble of finished runs, the cells of an experiment matrix, and the lock that keeps one
//! process per folder.

pub mod completion;
pub mod ensemble;
pub mod experiment;
pub mod lock;
pub mod results;
