//! The weights we trained and ship inside the binary (`restore/weights/`, with the record of
//! how they were made in `restore/weights/README.md`), and the choice `--restorer auto` makes
//! with them.

use crate::error::Result;
use crate::infer::Restorer;
use crate::weights::{self, Header};
use aberration::PsfGrid;
use std::path::Path;

/// The `tiny` network trained on the default simulated PSF grid
/// (`metasplat psf simulate`, 9×9 grid of 135 px PSFs).
pub const TINY: &[u8] = include_bytes!("../weights/tiny.bin");

/// The name the shipped weights go by in messages.
pub const TINY_NAME: &str = "restore/weights/tiny.bin (shipped)";

/// The shipped network's header.
pub fn header() -> Result<Header> {
    Ok(weights::parse(TINY, Path::new(TINY_NAME))?.0)
}

/// What `auto` makes of a capture: the shipped network and why it serves, or why not.
pub enum Choice {
    Network(Box<Restorer>, String),
    Declined(String),
}

/// Whether the shipped network serves a capture whose native grid is `native` and whose PSFs
/// are `psf_px` wide at its images' size (None: any size), and why.
pub fn verdict(header: &Header, native: &PsfGrid, psf_px: Option<usize>) -> (bool, String) {
    let name = format!("the shipped restorer ('{}')", header.config.name);
    let lens = match header.serves(native) {
        Ok(why) => why,
        Err(why) => return (false, format!("{name} does not serve this lens: {why}")),
    };
    let range = match header.trained_psf_px {
        Some([lo, hi]) => format!("{lo}-{hi} px PSFs"),
        None => "PSFs of unrecorded size".into(),
    };
    match psf_px {
        Some(px) if !header.fits_psf_px(px) => (
            false,
            format!(
                "{name} was trained on {range} (serves {}); this capture's are {px} px",
                header
                    .served_psf_px()
                    .map_or("any".into(), |[lo, hi]| format!("{lo}-{hi} px")),
            ),
        ),
        Some(px) => (
            true,
            format!("{name}: {lens}, on {range}; this capture's are {px} px"),
        ),
        None => (true, format!("{name}: {lens}")),
    }
}

/// [`for_capture_on`] on the CPU.
pub fn for_capture(native: &PsfGrid, psf_px: Option<usize>) -> Result<Choice> {
    for_capture_on(native, psf_px, burn::tensor::Device::flex())
}

/// The shipped restorer for a capture, on a device, or why it does not serve it.
pub fn for_capture_on(
    native: &PsfGrid,
    psf_px: Option<usize>,
    device: burn::tensor::Device,
) -> Result<Choice> {
    let header = header()?;
    Ok(match verdict(&header, native, psf_px) {
        (true, why) => {
            let r = Restorer::from_bytes_on(TINY, Path::new(TINY_NAME), native, device)?;
            Choice::Network(Box::new(r), why)
        }
        (false, why) => Choice::Declined(why),
    })
}

/// The shipped restorer when it serves the lens of `native` (any blur scale); `Ok(None)` for
/// another lens.
pub fn for_psf(native: &PsfGrid) -> Result<Option<Restorer>> {
    for_psf_on(native, burn::tensor::Device::flex())
}

/// [`for_psf`] on a given device.
pub fn for_psf_on(native: &PsfGrid, device: burn::tensor::Device) -> Result<Option<Restorer>> {
    Ok(match for_capture_on(native, None, device)? {
        Choice::Network(r, _) => Some(*r),
        Choice::Declined(_) => None,
    })
}
