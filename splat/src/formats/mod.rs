//! Splat files: PLY (the 3DGS layout), glTF/GLB (`KHR_gaussian_splatting`) and SPZ, read
//! and written through [`files`], which picks the format by extension and writes atomically.

pub mod files;
pub mod glb;
pub mod ply;
pub mod spz;
