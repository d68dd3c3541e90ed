//! Data: what a case is made of and how it is read, written and synthesised — case folders and
//! their views, clinical DICOM/NIfTI import, vessel trees (SWC, procedural), volumes, meshes,
//! the voxel projector, view masks and the vessel evidence they read, synthetic cases and a finished run's summary read back. Nothing here knows about the method.

pub mod case;
pub mod clinical;
pub mod masks;
pub mod mesh;
pub mod projector;
pub mod run_folder;
pub mod synth;
pub mod tree;
pub mod vessel_evidence;
pub mod volume;
