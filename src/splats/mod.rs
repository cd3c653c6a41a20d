//! The splat side of a run: where its splats start ([`init`]), the procedural scenes made of
//! splats with known ground truth ([`procedural`]; they stay here rather than in `scenes`,
//! which knows nothing of splats), the renderer a run draws with ([`device`]), and the
//! conversions between the member crates' types ([`convert`]).

pub mod convert;
pub mod device;
pub mod init;
pub mod procedural;
