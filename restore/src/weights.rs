//! The weights file: the network's tensors with a short JSON header (configuration, the PSF
//! grid the network was trained for, how it was made). One file, written atomically.
//!
//! Layout (version 4): a safetensors file, readable from numpy and PyTorch
//! (`safetensors.numpy.load_file`), whose tensors are the network's parameters named by
//! their path in the module (burn's store) and whose metadata holds the header under
//! `metasplat`, the format under `format` and, under `crc32`, the CRC-32 of the header and
//! of every tensor (name, length, bytes) in name order, and under `param_ids` each tensor's
//! parameter id (burn's, which AdamW's state is keyed by, so a resumed training run finds its
//! moments). Older files still load: magic line,
//! u64 header length, JSON header, burn's burnpack record and (version 3) the XXH3 checksum of
//! everything before it; version 2 ends in an FNV-1a checksum, version 1 (such as the shipped
//! `tiny.bin`) has none. Where there is a checksum, a flipped byte or appended bytes are
//! refused naming the file.

use crate::config::RestorerConfig;
use crate::error::{RestoreError, Result};
use crate::net::RestorerNet;
use aberration::PsfGrid;
use burn::module::{Module, ModuleVisitor, Param};
use burn::store::{ModuleRecord, ModuleSnapshot, SafetensorsStore};
use burn::tensor::{Bytes, Device, Tensor};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// The format a version 4 (safetensors) file names in its metadata.
const FORMAT: &str = "metasplat-restorer 4";
const FORMAT_KEY: &str = "format";
const HEADER_KEY: &str = "metasplat";
const CRC_KEY: &str = "crc32";
const IDS_KEY: &str = "param_ids";
/// Every version before 4 starts with this.
const MAGIC_PREFIX: &[u8] = b"METASPLAT-RESTORER ";
/// The third version, ending in an XXH3 checksum; still read.
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
    let json = serde_json::to_string(header).map_err(|e| bad(path, e.to_string()))?;
    let mut store = SafetensorsStore::from_bytes(None);
    net.save_into(&mut store)
        .map_err(|e| bad(path, format!("cannot collect the tensors: {e}")))?;
    let raw = store
        .get_bytes()
        .map_err(|e| bad(path, format!("cannot serialise the tensors: {e}")))?;
    let ids: std::collections::BTreeMap<String, u64> = net
        .collect(None, None, false)
        .into_iter()
        .filter_map(|t| Some((t.name, t.param_id?)))
        .collect();
    let ids = serde_json::to_string(&ids).map_err(|e| bad(path, e.to_string()))?;
    let bytes = with_header(&raw, &json, &ids).map_err(|e| bad(path, e))?;
    base::write_bytes_atomically(path, &bytes)
        .map_err(|e| RestoreError::Io(path.to_path_buf(), e))?;
    Ok(fingerprint(&bytes))
}

/// CRC-32 of the header and of every tensor (name, byte length, bytes), in name order.
fn crc(header: &str, tensors: &[(String, safetensors::tensor::TensorView<'_>)]) -> u32 {
    let mut h = crc32fast::Hasher::new();
    h.update(header.as_bytes());
    for (name, view) in tensors {
        h.update(name.as_bytes());
        h.update(&(view.data().len() as u64).to_le_bytes());
        h.update(view.data());
    }
    h.finalize()
}

/// The tensors of a safetensors file, in name order.
fn sorted<'a>(
    file: &safetensors::SafeTensors<'a>,
) -> Vec<(String, safetensors::tensor::TensorView<'a>)> {
    let mut t = file.tensors();
    t.sort_by(|a, b| a.0.cmp(&b.0));
    t
}

/// The safetensors file burn's store wrote (`raw`), again with our metadata: the header, the
/// format, the parameter ids and the checksum.
fn with_header(raw: &[u8], header: &str, ids: &str) -> std::result::Result<Vec<u8>, String> {
    let file = safetensors::SafeTensors::deserialize(raw).map_err(|e| e.to_string())?;
    let tensors = sorted(&file);
    let metadata = std::collections::HashMap::from([
        (FORMAT_KEY.to_string(), FORMAT.to_string()),
        (HEADER_KEY.to_string(), header.to_string()),
        (IDS_KEY.to_string(), ids.to_string()),
        (
            CRC_KEY.to_string(),
            format!("{:08x}", crc(header, &tensors)),
        ),
    ]);
    safetensors::serialize(tensors, Some(metadata)).map_err(|e| e.to_string())
}

/// The tensors of a version 4 file as burn's store applies them, each with the parameter id
/// it was saved with (a file without ids gives fresh ones).
fn pack_tensors(bytes: &[u8]) -> std::result::Result<Vec<burn::store::burn_pack::Tensor>, String> {
    use burn::store::burn_pack::{Bytes as PackBytes, DType};
    let file = safetensors::SafeTensors::deserialize(bytes).map_err(|e| e.to_string())?;
    let (_, metadata) =
        safetensors::SafeTensors::read_metadata(bytes).map_err(|e| e.to_string())?;
    let ids: std::collections::BTreeMap<String, u64> =
        match metadata.metadata().as_ref().and_then(|m| m.get(IDS_KEY)) {
            Some(json) => serde_json::from_str(json).map_err(|e| format!("bad {IDS_KEY}: {e}"))?,
            None => Default::default(),
        };
    file.tensors()
        .into_iter()
        .map(|(name, view)| {
            if view.dtype() != safetensors::Dtype::F32 {
                return Err(format!("tensor {name} is {:?}, not f32", view.dtype()));
            }
            let id = ids.get(&name).copied();
            Ok(burn::store::burn_pack::Tensor::new(
                name,
                DType::F32,
                view.shape().to_vec(),
                id,
                PackBytes::from_bytes_vec(view.data().to_vec()),
            ))
        })
        .collect()
}

/// The network's parameters as a file holds them.
pub enum Record {
    /// Version 4: the whole safetensors file.
    Safetensors(Vec<u8>),
    /// Versions 1 to 3: burn's burnpack record.
    Burnpack(Vec<u8>),
}

/// Reads a weights file: its header and the record.
pub fn read(path: &Path) -> Result<(Header, Record)> {
    let bytes = base::input::read(path).map_err(|e| RestoreError::Io(path.to_path_buf(), e))?;
    parse(&bytes, path)
}

/// Splits the bytes of a weights file (`path` names it in errors) into header and record.
pub fn parse(bytes: &[u8], path: &Path) -> Result<(Header, Record)> {
    if !bytes.starts_with(MAGIC_PREFIX) {
        return parse_safetensors(bytes, path);
    }
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
    Ok((header, Record::Burnpack(bytes[start + n..].to_vec())))
}

/// [`parse`] for a version 4 file: the checksum checked, the header read.
fn parse_safetensors(bytes: &[u8], path: &Path) -> Result<(Header, Record)> {
    let not_ours = |why: String| {
        bad(
            path,
            format!("not a metasplat restorer weights file ({why})"),
        )
    };
    let unreadable = |e: safetensors::SafeTensorError| {
        bad(
            path,
            format!(
                "not a restorer weights file: no metasplat magic line, and not a whole safetensors file ({e}: damaged, truncated or with bytes appended?)"
            ),
        )
    };
    let file = safetensors::SafeTensors::deserialize(bytes).map_err(unreadable)?;
    let (_, metadata) = safetensors::SafeTensors::read_metadata(bytes).map_err(unreadable)?;
    let meta = metadata.metadata().clone().unwrap_or_default();
    if meta.get(FORMAT_KEY).map(String::as_str) != Some(FORMAT) {
        return Err(not_ours(format!(
            "a safetensors file whose metadata does not name the format '{FORMAT}'"
        )));
    }
    let (Some(json), Some(stored)) = (meta.get(HEADER_KEY), meta.get(CRC_KEY)) else {
        return Err(bad(path, "the metadata has no header or no checksum"));
    };
    if format!("{:08x}", crc(json, &sorted(&file))) != *stored {
        return Err(bad(
            path,
            "checksum mismatch: the file is damaged, truncated or has bytes changed",
        ));
    }
    let header: Header =
        serde_json::from_str(json).map_err(|e| bad(path, format!("bad header: {e}")))?;
    header.config.validate().map_err(|e| bad(path, e))?;
    Ok((header, Record::Safetensors(bytes.to_vec())))
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

/// For fine-tuning (`restorer train --init`): the weights at `path` in a network of `cfg`,
/// which may differ from theirs in the switches without parameters (the bank's K, the
/// residual base: [`RestorerConfig::same_parameters`]); another network is refused naming
/// both. The header returned is the file's.
pub fn load_into(
    path: &Path,
    device: &Device,
    cfg: &RestorerConfig,
) -> Result<(RestorerNet, Header)> {
    let (header, record) = read(path)?;
    if !cfg.same_parameters(&header.config) {
        return Err(other_config(path, &header.config, cfg));
    }
    Ok((assemble(cfg, record, path, device)?, header))
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

/// The refusal of weights of config `theirs` where `expected` was asked for.
fn other_config(path: &Path, theirs: &RestorerConfig, expected: &RestorerConfig) -> RestoreError {
    bad(
        path,
        format!(
            "weights are of config '{}' ({} parameters), expected '{}' ({} parameters)",
            theirs.name,
            theirs.analytic_params(),
            expected.name,
            expected.analytic_params()
        ),
    )
}

fn build(
    header: Header,
    record: Record,
    path: &Path,
    device: &Device,
    expected: Option<&RestorerConfig>,
    psf: Option<&PsfGrid>,
) -> Result<(RestorerNet, Header)> {
    if let Some(cfg) = expected
        && !cfg.same_network(&header.config)
    {
        return Err(other_config(path, &header.config, cfg));
    }
    if let Some(psf) = psf
        && let Err(why) = header.serves(psf)
    {
        return Err(bad(path, why));
    }
    Ok((assemble(&header.config, record, path, device)?, header))
}

/// A network of `cfg` holding `record`'s weights, refused when they do not fit it or hold a
/// value that is not finite.
fn assemble(
    cfg: &RestorerConfig,
    record: Record,
    path: &Path,
    device: &Device,
) -> Result<RestorerNet> {
    let fresh = RestorerNet::new(cfg, device);
    let unfit = |e: String| {
        bad(
            path,
            format!("weights do not fit config '{}': {e}", cfg.name),
        )
    };
    let net = match record {
        Record::Burnpack(record) => {
            let record = ModuleRecord::from_bytes(Bytes::from_bytes_vec(record))
                .map_err(|e| bad(path, format!("bad record: {e}")))?;
            fresh
                .try_load_record(record)
                .map_err(|e| unfit(e.to_string()))?
        }
        Record::Safetensors(bytes) => {
            let mut net = fresh;
            let applied = net.apply(pack_tensors(&bytes).map_err(unfit)?, None, None, false);
            if !applied.is_success() || !applied.missing.is_empty() || !applied.unused.is_empty() {
                return Err(unfit(format!(
                    "{} tensors missing, {} unused, {} not applied",
                    applied.missing.len(),
                    applied.unused.len(),
                    applied.errors.len()
                )));
            }
            net
        }
    };
    let bad_tensors = non_finite_tensors(&net);
    if bad_tensors > 0 {
        return Err(bad(
            path,
            format!("{bad_tensors} weight tensors hold NaN or infinite values"),
        ));
    }
    Ok(net)
}
