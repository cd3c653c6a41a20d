//! The weights file: a short JSON header (configuration, the PSF grid the network was trained
//! for, how it was made) followed by burn's burnpack record. One file, written atomically.
//!
//! Layout: magic line, u64 header length, JSON header, record, and (version 3) the XXH3
//! checksum of everything before it, little-endian. Older files still load: version 2 ends in
//! an FNV-1a checksum, version 1 (such as the shipped `tiny.bin`) has none. Where there is a
//! checksum, a flipped byte or appended bytes are refused naming the file.

use crate::config::RestorerConfig;
use crate::error::{RestoreError, Result};
use crate::net::RestorerNet;
use aberration::PsfGrid;
use burn::module::{Module, ModuleVisitor, Param};
use burn::store::ModuleRecord;
use burn::tensor::{Bytes, Device, Tensor};
use serde::{Deserialize, Serialize};
use std::path::Path;

const MAGIC: &[u8] = b"METASPLAT-RESTORER 3\n";
/// The second version, ending in an FNV-1a checksum; still read.
const MAGIC_V2: &[u8] = b"METASPLAT-RESTORER 2\n";
/// The first version, without the checksum; still read.
const MAGIC_V1: &[u8] = b"METASPLAT-RESTORER 1\n";
/// Length of the trailing checksum of a version 2 or 3 file.
const CHECKSUM: usize = 8;

/// Which PSF grid a network was trained for: its shape and a hash of its values.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct PsfFingerprint {
    pub grid: usize,
    pub size: usize,
    /// [`base::hash::tagged`] of the f32 bit patterns (bare FNV-1a hex in older files).
    pub hash: String,
}

impl Header {
    /// True when PSFs of `px` pixels are within the scales seen in training (±25%); true
    /// when the file does not say.
    pub fn fits_psf_px(&self, px: usize) -> bool {
        self.trained_psf_px
            .is_none_or(|[lo, hi]| px as f64 >= lo as f64 * 0.8 && px as f64 <= hi as f64 * 1.25)
    }

    /// The PSF sides (px) these weights serve: the trained range widened as
    /// [`Self::fits_psf_px`] widens it; None when the file does not say.
    pub fn served_psf_px(&self) -> Option<[usize; 2]> {
        self.trained_psf_px.map(|[lo, hi]| {
            [
                (lo as f64 * 0.8).ceil() as usize,
                (hi as f64 * 1.25).floor() as usize,
            ]
        })
    }

    /// Whether these weights serve the native PSF grid `psf`: why they do (the grid they were
    /// trained on, or a grid inside their lens family), or what they cover and what the grid
    /// is.
    pub fn serves(&self, psf: &PsfGrid) -> std::result::Result<String, String> {
        if self.psf.names(psf) {
            return Ok("trained on this PSF grid".into());
        }
        let grid = format!(
            "this grid is {}x{} of {} px (hash {})",
            psf.grid(),
            psf.grid(),
            psf.size(),
            PsfFingerprint::of(psf).hash
        );
        match &self.family {
            Some(family) => match family.envelope.holds(psf) {
                Ok(()) => Ok(format!(
                    "this PSF grid is inside the lens family it was trained on ({})",
                    family.drawn
                )),
                Err(outside) => Err(format!(
                    "weights cover a family of {}x{} lenses ({}); {grid}, outside it: {outside}",
                    family.envelope.grid, family.envelope.grid, family.drawn
                )),
            },
            None => Err(format!(
                "weights were trained for one {}x{} grid of {} px PSFs (hash {}); {grid}",
                self.psf.grid, self.psf.grid, self.psf.size, self.psf.hash
            )),
        }
    }
}

impl PsfFingerprint {
    pub fn of(psf: &PsfGrid) -> Self {
        Self {
            grid: psf.grid(),
            size: psf.size(),
            hash: base::hash::tagged(&Self::bytes(psf)),
        }
    }

    /// Whether `psf` is the grid this fingerprint was taken of, in the hash it was taken with.
    pub fn names(&self, psf: &PsfGrid) -> bool {
        self.grid == psf.grid()
            && self.size == psf.size()
            && base::hash::names(&self.hash, &Self::bytes(psf))
    }

    fn bytes(psf: &PsfGrid) -> Vec<u8> {
        psf.planar()
            .iter()
            .flat_map(|v| v.to_bits().to_le_bytes())
            .collect()
    }
}

/// The fingerprint of a weights file's bytes ([`base::hash::tagged`]): what a training state
/// and an `I_ac` cache record of the network.
pub fn fingerprint(bytes: &[u8]) -> String {
    base::hash::tagged(bytes)
}

/// Everything the file says about the network besides its weights.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Header {
    pub config: RestorerConfig,
    pub psf: PsfFingerprint,
    /// Smallest and largest PSF side (px) the grid had at the training photos' sizes: the
    /// blur scales the network has seen.
    #[serde(default)]
    pub trained_psf_px: Option<[usize; 2]>,
    /// The lens family the network was trained on ([`crate::coverage`]); None: only the grid
    /// of [`Self::psf`].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub family: Option<crate::coverage::Family>,
    /// Free-form record of how the weights were made (command, steps, seed, time, metrics).
    pub provenance: serde_json::Value,
}

fn bad(path: &Path, message: impl Into<String>) -> RestoreError {
    RestoreError::Weights {
        path: path.to_path_buf(),
        message: message.into(),
    }
}

/// How many of the network's parameter tensors hold a NaN or an infinity: weights that can
/// only restore garbage, whatever their checksum says.
pub fn non_finite_tensors(net: &RestorerNet) -> usize {
    struct Count(usize);
    impl ModuleVisitor for Count {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            if !param.val().is_finite().all().into_scalar::<bool>() {
                self.0 += 1;
            }
        }
    }
    let mut count = Count(0);
    net.visit(&mut count);
    count.0
}

/// Writes `net` with its header to `path` (temporary name, then rename); returns the
/// [`fingerprint`] of the bytes written, the hash a training state records. Weights with a
/// non-finite value are refused, not written.
pub fn save(net: &RestorerNet, header: &Header, path: &Path) -> Result<String> {
    let bad_tensors = non_finite_tensors(net);
    if bad_tensors > 0 {
        return Err(bad(
            path,
            format!(
                "not written: {bad_tensors} weight tensors hold NaN or infinite values (training diverged; lower the learning rate)"
            ),
        ));
    }
    let json = serde_json::to_vec(header).map_err(|e| bad(path, e.to_string()))?;
    let record = net
        .clone()
        .into_record()
        .into_bytes()
        .map_err(|e| bad(path, format!("cannot serialise the record: {e}")))?;
    let mut bytes = Vec::with_capacity(MAGIC.len() + 8 + json.len() + record.len() + CHECKSUM);
    bytes.extend_from_slice(MAGIC);
    bytes.extend_from_slice(&(json.len() as u64).to_le_bytes());
    bytes.extend_from_slice(&json);
    bytes.extend_from_slice(&record);
    let sum = base::hash::xxh3(&bytes);
    bytes.extend_from_slice(&sum.to_le_bytes());
    base::write_bytes_atomically(path, &bytes)
        .map_err(|e| RestoreError::Io(path.to_path_buf(), e))?;
    Ok(fingerprint(&bytes))
}

/// Reads a weights file: its header and the record bytes.
pub fn read(path: &Path) -> Result<(Header, Vec<u8>)> {
    let bytes = base::input::read(path).map_err(|e| RestoreError::Io(path.to_path_buf(), e))?;
    parse(&bytes, path)
}

/// Splits the bytes of a weights file (`path` names it in errors) into header and record.
pub fn parse(bytes: &[u8], path: &Path) -> Result<(Header, Vec<u8>)> {
    let checksum: Option<fn(&[u8]) -> u64> = if bytes.starts_with(MAGIC) {
        Some(base::hash::xxh3)
    } else if bytes.starts_with(MAGIC_V2) {
        Some(base::hash::fnv1a64)
    } else {
        None
    };
    let bytes = if let Some(checksum) = checksum {
        let Some(body_len) = bytes.len().checked_sub(CHECKSUM) else {
            return Err(bad(path, "truncated: no checksum"));
        };
        let (body, sum) = bytes.split_at(body_len);
        let stored = u64::from_le_bytes(sum.try_into().map_err(|_| bad(path, "no checksum"))?);
        if body.len() < MAGIC.len() + 8 || checksum(body) != stored {
            return Err(bad(
                path,
                "checksum mismatch: the file is damaged, truncated or has bytes appended",
            ));
        }
        body
    } else if bytes.starts_with(MAGIC_V1) && bytes.len() >= MAGIC_V1.len() + 8 {
        bytes
    } else {
        return Err(bad(path, "not a metasplat restorer weights file"));
    };
    let n = u64::from_le_bytes(
        bytes[MAGIC.len()..MAGIC.len() + 8]
            .try_into()
            .expect("8 bytes"),
    );
    let start = MAGIC.len() + 8;
    if n > (bytes.len() - start) as u64 {
        return Err(bad(path, "truncated header"));
    }
    let n = n as usize;
    let header: Header = serde_json::from_slice(&bytes[start..start + n])
        .map_err(|e| bad(path, format!("bad header: {e}")))?;
    header.config.validate().map_err(|e| bad(path, e))?;
    Ok((header, bytes[start + n..].to_vec()))
}

/// Loads a network. With `expected`, a file of another configuration is refused naming both;
/// with `psf`, weights that do not serve that native grid ([`Header::serves`]) are refused
/// saying what they cover and what the grid is.
pub fn load(
    path: &Path,
    device: &Device,
    expected: Option<&RestorerConfig>,
    psf: Option<&PsfGrid>,
) -> Result<(RestorerNet, Header)> {
    let (header, record) = read(path)?;
    build(header, record, path, device, expected, psf)
}

/// [`load`] from bytes already in memory (`path` names them in errors).
pub fn load_bytes(
    bytes: &[u8],
    path: &Path,
    device: &Device,
    expected: Option<&RestorerConfig>,
    psf: Option<&PsfGrid>,
) -> Result<(RestorerNet, Header)> {
    let (header, record) = parse(bytes, path)?;
    build(header, record, path, device, expected, psf)
}

fn build(
    header: Header,
    record: Vec<u8>,
    path: &Path,
    device: &Device,
    expected: Option<&RestorerConfig>,
    psf: Option<&PsfGrid>,
) -> Result<(RestorerNet, Header)> {
    if let Some(cfg) = expected
        && !cfg.same_network(&header.config)
    {
        return Err(bad(
            path,
            format!(
                "weights are of config '{}' ({} parameters), expected '{}' ({} parameters)",
                header.config.name,
                header.config.analytic_params(),
                cfg.name,
                cfg.analytic_params()
            ),
        ));
    }
    if let Some(psf) = psf
        && let Err(why) = header.serves(psf)
    {
        return Err(bad(path, why));
    }
    let record = ModuleRecord::from_bytes(Bytes::from_bytes_vec(record))
        .map_err(|e| bad(path, format!("bad record: {e}")))?;
    let net = RestorerNet::new(&header.config, device)
        .try_load_record(record)
        .map_err(|e| {
            bad(
                path,
                format!("weights do not fit config '{}': {e}", header.config.name),
            )
        })?;
    let bad_tensors = non_finite_tensors(&net);
    if bad_tensors > 0 {
        return Err(bad(
            path,
            format!("{bad_tensors} weight tensors hold NaN or infinite values"),
        ));
    }
    Ok((net, header))
}
