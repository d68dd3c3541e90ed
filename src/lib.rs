pub use ctadsa_render as render;
