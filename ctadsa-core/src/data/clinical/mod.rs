//! Clinical inputs: DSA runs from DICOM (mask/fill subtraction, frame choice, MIP, positioner
//! geometry), the prior from a CTA label volume, and their assembly into a case folder.

mod dicom_scan;
pub mod dsa;
pub mod import;
pub mod prior;
pub mod simulate;
pub mod timing;
pub mod xa;
