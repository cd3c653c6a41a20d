//! The weights we trained and ship inside the binary (`restore/weights/`, with the record of
//! how they were made in `restore/weights/README.md`).

use crate::error::Result;
use crate::infer::Restorer;
use crate::weights;
use aberration::PsfGrid;
use std::path::Path;

/// The `tiny` network trained on the default simulated PSF grid
/// (`metasplat psf simulate`, 9×9 grid of 135 px PSFs).
pub const TINY: &[u8] = include_bytes!("../weights/tiny.bin");

/// The name the shipped weights go by in messages.
pub const TINY_NAME: &str = "restore/weights/tiny.bin (shipped)";

/// The shipped restorer when it was trained for `native`; `Ok(None)` for another grid.
pub fn for_psf(native: &PsfGrid) -> Result<Option<Restorer>> {
    for_psf_on(native, burn::tensor::Device::flex())
}

/// [`for_psf`] on a given device.
pub fn for_psf_on(native: &PsfGrid, device: burn::tensor::Device) -> Result<Option<Restorer>> {
    let name = Path::new(TINY_NAME);
    let (header, _) = weights::parse(TINY, name)?;
    if !header.psf.names(native) {
        return Ok(None);
    }
    Restorer::from_bytes_on(TINY, name, native, device).map(Some)
}
