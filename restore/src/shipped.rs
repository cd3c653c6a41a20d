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

/// The `tiny` network fine-tuned over the lens family around the default one, at PSFs of
/// 15-140 px (`restore/weights/README.md`): `auto`'s choice where [`TINY`] does not serve.
pub const FAMILY: &[u8] = include_bytes!("../weights/family_tiny_5.bin");

/// The name the general weights go by in messages.
pub const FAMILY_NAME: &str = "restore/weights/family_tiny_5.bin (shipped)";

/// The general network fine-tuned on the family's widest blur only, PSFs of 85-140 px
/// (`restore/weights/README.md`): `auto`'s choice there, before [`FAMILY`].
pub const LARGE: &[u8] = include_bytes!("../weights/large_tiny_9.bin");

/// The name the wide-blur weights go by in messages.
pub const LARGE_NAME: &str = "restore/weights/large_tiny_9.bin (shipped)";

/// Weights shipped inside the binary.
#[derive(Clone, Copy, Debug)]
pub struct Shipped {
    pub bytes: &'static [u8],
    pub name: &'static str,
}

/// What `auto` tries, in order (those trained on the capture's scale first,
/// [`for_capture_on`]): the network trained on the default lens at the scale it was
/// made for, then the family's for the widest blur (85-140 px, 0.20-0.29 dB above the general
/// one at 113-135 px), then the one trained over the lens family at every scale (1-5 dB above
/// the Wiener image: RESULTS.md).
pub const SHIPPED: [Shipped; 3] = [
    Shipped {
        bytes: TINY,
        name: TINY_NAME,
    },
    Shipped {
        bytes: LARGE,
        name: LARGE_NAME,
    },
    Shipped {
        bytes: FAMILY,
        name: FAMILY_NAME,
    },
];

/// The general network `--any-grid` measures outside what every shipped one covers.
pub const GENERAL: Shipped = SHIPPED[2];

/// The first shipped network's header ([`TINY`]).
pub fn header() -> Result<Header> {
    header_of(SHIPPED[0])
}

/// A shipped network's header.
pub fn header_of(s: Shipped) -> Result<Header> {
    Ok(weights::parse(s.bytes, Path::new(s.name))?.0)
}

/// What `auto` makes of a capture: a shipped network, why it serves and its name, or why
/// none does.
pub enum Choice {
    Network(Box<Restorer>, String, &'static str),
    Declined(String),
}

/// Whether the shipped network serves a capture whose native grid is `native` and whose PSFs
/// are `psf_px` wide at its images' size (None: any size), and why.
pub fn verdict(header: &Header, native: &PsfGrid, psf_px: Option<usize>) -> (bool, String) {
    // Two shipped networks are of the family: their scales tell them apart.
    let name = match (&header.family, header.trained_psf_px) {
        (Some(_), Some([lo, hi])) => format!(
            "the shipped general restorer ('{}', a lens family, {lo}-{hi} px)",
            header.config.name
        ),
        (Some(_), None) => format!(
            "the shipped general restorer ('{}', a lens family)",
            header.config.name
        ),
        (None, _) => format!("the shipped restorer ('{}')", header.config.name),
    };
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

/// The [`SHIPPED`] restorer `auto` takes for a capture, on a device, or why none serves: of
/// those that serve its lens and scale, the first trained on its very scale, else the first
/// that reaches it through the margin around its trained scales (a network trained at 55-57
/// px serves 44-71 px, but one trained across 15-140 px saw 60 px itself, and scored above
/// it from 38 to 85 px: restore/README.md).
pub fn for_capture_on(
    native: &PsfGrid,
    psf_px: Option<usize>,
    device: burn::tensor::Device,
) -> Result<Choice> {
    let mut declined = Vec::new();
    let mut serving = Vec::new();
    for s in SHIPPED {
        let header = header_of(s)?;
        match verdict(&header, native, psf_px) {
            (true, why) => serving.push((s, trained_on(&header, psf_px), why)),
            (false, why) => declined.push(why),
        }
    }
    let chosen = serving
        .iter()
        .position(|(_, on_scale, _)| *on_scale)
        .unwrap_or(0);
    match serving.into_iter().nth(chosen) {
        Some((s, _, why)) => {
            let r = Restorer::from_bytes_on(s.bytes, Path::new(s.name), native, device)?;
            Ok(Choice::Network(Box::new(r), why, s.name))
        }
        None => Ok(Choice::Declined(declined.join("; "))),
    }
}

/// Whether `header`'s weights were trained on PSFs of `psf_px` (any scale when either is
/// unknown).
fn trained_on(header: &Header, psf_px: Option<usize>) -> bool {
    match (header.trained_psf_px, psf_px) {
        (Some([lo, hi]), Some(px)) => (lo..=hi).contains(&px),
        _ => true,
    }
}

/// The shipped restorer when it serves the lens of `native` (any blur scale); `Ok(None)` for
/// another lens.
pub fn for_psf(native: &PsfGrid) -> Result<Option<Restorer>> {
    for_psf_on(native, burn::tensor::Device::flex())
}

/// [`for_psf`] on a given device.
pub fn for_psf_on(native: &PsfGrid, device: burn::tensor::Device) -> Result<Option<Restorer>> {
    Ok(match for_capture_on(native, None, device)? {
        Choice::Network(r, ..) => Some(*r),
        Choice::Declined(_) => None,
    })
}
