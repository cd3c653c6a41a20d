//! What every metasplat crate shares, so that each exists once: the image metrics (PSNR, and
//! SSIM with its gradient), the one way an output file is written, and the seeded mixer behind
//! every reproducible random choice. It knows nothing of splats, optics or networks.

#[doc(hidden)]
pub mod alloc_watch;
pub mod atomic;
pub mod error;
pub mod hash;
pub mod input;
pub mod interrupt;
pub mod isa;
pub mod limits;
pub mod lock;
pub mod metrics;
pub mod npy;
pub mod rng;
#[doc(hidden)]
pub mod ssim_reference;

pub use atomic::{
    WriteError, remove_orphans, temp_prefix, write_atomically, write_atomically_with,
    write_bytes_atomically,
};
pub use error::BaseError;
pub use lock::{FolderLock, LockError};
pub use metrics::{psnr, psnr_rgb, ssim, ssim_planar, ssim_value, sum_pairs};
pub use rng::{SplitMix64, mix64};
