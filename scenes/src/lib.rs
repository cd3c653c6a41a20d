//! Scene captures for metasplat: LLFF and COLMAP readers, train/test splits, initial point
//! clouds, an LLFF writer, and the aberrated-capture maker ([`aberrated`]).
//!
//! Start at [`open`], which detects the capture layout and returns a [`Capture`]: cameras in
//! the OpenCV convention documented in [`camera`], lazily loaded images, per-image near/far
//! bounds, the initial point cloud and the split. [`Capture::summary`] is what
//! `metasplat scene info` prints.

pub mod aberrated;
mod atomic;
pub mod cache_entry;
pub mod camera;
pub mod capture;
pub mod colmap;
pub mod error;
pub mod images;
pub mod limits;
pub mod llff;
pub mod nerfstudio;
pub mod photo_cache;
pub mod point_ply;
pub mod points;
pub mod spiral;
pub mod split;
pub mod summary;
pub mod undistort;

pub use aberrated::{AberrateOptions, AberrateReport, AberrationRecord, make_aberrated};
pub use camera::{Bounds, Camera, CameraModel, Distortion, Projection, Rigid};
pub use capture::{Capture, CaptureFormat, OpenOptions, PointSource, Resolution, open};
pub use error::{Result, SceneError};
pub use images::{BitDepth, Photo};
pub use llff::{LlffPose, LlffWriter, write_llff};
pub use points::{Normalization, PointCloud, random_in_frusta};
pub use split::{LLFFHOLD, Split, split};
pub use summary::SceneSummary;
