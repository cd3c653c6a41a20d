//! Checkpoints: everything the loop needs to continue bit for bit (model, Adam moments,
//! densification statistics, SH state, log), in one file written to a temporary name and
//! renamed, so a kill leaves the previous checkpoint intact.
//!
//! Layout: a safetensors file (readable from numpy and PyTorch: `safetensors.numpy.load_file`)
//! whose tensors are the arrays ([`TENSORS`] names them: `model.means` `[N, 3]`, …,
//! `adam_m.*`, `adam_v.*`, `densify.*`, `psf.*`) and whose metadata holds the run's JSON
//! header under `metasplat` and, under `crc32`, the CRC-32 of that header and every tensor's
//! bytes in [`TENSORS`] order. The earlier layouts (magic, u64 header length, JSON header,
//! arrays; version 2 ending in an FNV-1a checksum) still load.

use std::path::Path;

use glam::Vec3;
use serde::{Deserialize, Serialize};
use splat::Gaussians;
use splat::densify::DensifyStats;
use splat::optim::Adam;

use crate::error::{Result, TrainError};
use crate::train::LogRow;
use crate::train::config::TrainConfig;
use crate::train::densify::DensifyState;
use crate::train::psf_refine::PsfRefinement;
use crate::train::sh::ShState;
use crate::train::stop::StopState;
use aberration::refine::RefineState;

/// Version 2 ends with the FNV-1a checksum of everything before it; version 1 (no checksum)
/// still loads.
const MAGIC: &[u8; 16] = b"metasplat-ckpt02";
const MAGIC_V1: &[u8; 16] = b"metasplat-ckpt01";

#[derive(Clone, Debug, Serialize, Deserialize)]
struct Header {
    config: TrainConfig,
    step: u64,
    train_seconds: f64,
    sh: ShState,
    log: Vec<LogRow>,
    splats: usize,
    sh_degree: u32,
    adam_step: u64,
    /// Values of the PSF grid being refined (`--refine-psf`; 0: none), and its steps; the
    /// logits and their two Adam moments follow the other arrays.
    #[serde(default)]
    psf_values: usize,
    #[serde(default)]
    psf_steps: u64,
    /// What `--iters auto`'s rule has seen (empty for other runs and older checkpoints).
    #[serde(default)]
    stop: StopState,
}

impl Header {
    /// What every layout writes before its arrays.
    fn of(config: &TrainConfig, p: &Progress, model: &Gaussians, adam: &Adam) -> Self {
        Header {
            config: config.clone(),
            step: p.step,
            train_seconds: p.train_seconds,
            sh: p.sh.clone(),
            log: p.log.clone(),
            splats: model.len(),
            sh_degree: model.sh_degree,
            adam_step: adam.steps_taken(),
            psf_values: p.psf.as_ref().map_or(0, |r| r.state().logits.len()),
            psf_steps: p.psf.as_ref().map_or(0, |r| r.state().steps),
            stop: p.stop.clone(),
        }
    }

    /// Refuses a degree no splat set can have, before arrays are sized by it.
    fn check_degree(&self, path: &Path) -> Result<()> {
        if self.sh_degree > splat::MAX_SH_DEGREE {
            return Err(TrainError::file(
                path,
                format!("SH degree {} too high", self.sh_degree),
            ));
        }
        Ok(())
    }
}

/// Little-endian 4-byte values, as every layout stores its arrays.
fn le_words<T>(bytes: &[u8], word: fn([u8; 4]) -> T) -> Vec<T> {
    bytes
        .chunks_exact(4)
        .map(|c| word([c[0], c[1], c[2], c[3]]))
        .collect()
}

/// The loop's state between two steps, but for the model and its optimiser (which the
/// trainer holds).
#[derive(Debug)]
pub struct Progress {
    pub step: u64,
    /// Training time so far (evaluation and checkpoint writing excluded).
    pub train_seconds: f64,
    pub densify: DensifyState,
    pub sh: ShState,
    pub log: Vec<LogRow>,
    /// The PSF grid being refined (`--refine-psf`).
    pub psf: Option<PsfRefinement>,
    /// What `--iters auto`'s rule has seen, and the end it decided.
    pub stop: StopState,
}

/// A checkpoint read back: the run's config, its progress, the model and its optimiser.
pub struct State {
    pub config: TrainConfig,
    pub progress: Progress,
    pub model: Gaussians,
    pub adam: Adam,
    /// The refinement's state (`--refine-psf`), for [`PsfRefinement::new`] to continue with
    /// the capture's grid.
    pub psf: Option<RefineState>,
}

/// What a safetensors checkpoint holds beside the arrays.
const HEADER_KEY: &str = "metasplat";
const CRC_KEY: &str = "crc32";

/// The tensors of a checkpoint, in the order the checksum reads them.
pub const TENSORS: [&str; 24] = [
    "model.means",
    "model.log_scales",
    "model.rotations",
    "model.logit_opacities",
    "model.sh_dc",
    "model.sh_rest",
    "adam_m.means",
    "adam_m.log_scales",
    "adam_m.rotations",
    "adam_m.logit_opacities",
    "adam_m.sh_dc",
    "adam_m.sh_rest",
    "adam_v.means",
    "adam_v.log_scales",
    "adam_v.rotations",
    "adam_v.logit_opacities",
    "adam_v.sh_dc",
    "adam_v.sh_rest",
    "densify.grad_norm_sum",
    "densify.count",
    "densify.max_radius",
    "densify.seen",
    "psf.logits",
    "psf.moments",
];

fn le_f32s<'a>(v: impl IntoIterator<Item = &'a f32>) -> Vec<u8> {
    v.into_iter().flat_map(|x| x.to_le_bytes()).collect()
}

fn le_vec3s(v: &[Vec3]) -> Vec<u8> {
    v.iter()
        .flat_map(|p| p.to_array())
        .flat_map(f32::to_le_bytes)
        .collect()
}

/// A tensor of a checkpoint: name, type, shape, little-endian bytes.
type Tensor = (String, safetensors::Dtype, Vec<usize>, Vec<u8>);

/// The six arrays of a splat set (or of its Adam moments) under `prefix`.
fn gaussian_tensors(prefix: &str, g: &Gaussians) -> Vec<Tensor> {
    let n = g.len();
    let f32s = |name: &str, shape: Vec<usize>, bytes: Vec<u8>| {
        (
            format!("{prefix}.{name}"),
            safetensors::Dtype::F32,
            shape,
            bytes,
        )
    };
    vec![
        f32s("means", vec![n, 3], le_vec3s(&g.means)),
        f32s("log_scales", vec![n, 3], le_vec3s(&g.log_scales)),
        f32s(
            "rotations",
            vec![n, 4],
            le_f32s(g.rotations.iter().flatten()),
        ),
        f32s("logit_opacities", vec![n], le_f32s(&g.logit_opacities)),
        f32s("sh_dc", vec![n, 3], le_vec3s(&g.sh_dc)),
        f32s("sh_rest", vec![n, g.rest_count(), 3], le_vec3s(&g.sh_rest)),
    ]
}

/// CRC-32 of the header and of the tensors' bytes in [`TENSORS`] order.
fn checksum<'a>(header: &[u8], tensor: impl Fn(&str) -> Option<&'a [u8]>) -> u32 {
    let mut h = crc32fast::Hasher::new();
    h.update(header);
    for name in TENSORS {
        if let Some(bytes) = tensor(name) {
            h.update(&(bytes.len() as u64).to_le_bytes());
            h.update(bytes);
        }
    }
    h.finalize()
}

pub fn save(
    path: &Path,
    config: &TrainConfig,
    p: &Progress,
    model: &Gaussians,
    adam: &Adam,
) -> Result<()> {
    use safetensors::Dtype::{F32, U8, U32};
    let header = Header::of(config, p, model, adam);
    let json = serde_json::to_string(&header).map_err(|e| TrainError::file(path, e.to_string()))?;
    let n = model.len();
    let (m, v) = adam.moments();
    let mut tensors = gaussian_tensors("model", model);
    tensors.extend(gaussian_tensors("adam_m", m));
    tensors.extend(gaussian_tensors("adam_v", v));
    let st = &p.densify.stats;
    tensors.push((
        "densify.grad_norm_sum".into(),
        F32,
        vec![n],
        le_f32s(&st.grad_norm_sum),
    ));
    tensors.push((
        "densify.count".into(),
        U32,
        vec![n],
        st.count.iter().flat_map(|c| c.to_le_bytes()).collect(),
    ));
    tensors.push((
        "densify.max_radius".into(),
        F32,
        vec![n],
        le_f32s(&st.max_radius),
    ));
    tensors.push((
        "densify.seen".into(),
        U8,
        vec![n],
        p.densify.seen.iter().map(|&b| b as u8).collect(),
    ));
    if let Some(r) = &p.psf {
        let st = r.state();
        let k = st.logits.len();
        tensors.push(("psf.logits".into(), F32, vec![k], le_f32s(&st.logits)));
        tensors.push((
            "psf.moments".into(),
            F32,
            vec![2, k],
            le_f32s(st.m.iter().chain(&st.v)),
        ));
    }
    let crc = checksum(json.as_bytes(), |name| {
        tensors.iter().find(|t| t.0 == name).map(|t| t.3.as_slice())
    });
    let bad = |e: safetensors::SafeTensorError| TrainError::file(path, e.to_string());
    let views = tensors
        .iter()
        .map(|(name, dtype, shape, bytes)| {
            Ok((
                name.as_str(),
                safetensors::tensor::TensorView::new(*dtype, shape.clone(), bytes).map_err(bad)?,
            ))
        })
        .collect::<Result<Vec<_>>>()?;
    let metadata = std::collections::HashMap::from([
        (HEADER_KEY.to_string(), json),
        (CRC_KEY.to_string(), format!("{crc:08x}")),
    ]);
    let out = safetensors::serialize(views, Some(metadata)).map_err(bad)?;
    base::write_bytes_atomically(path, &out).map_err(|e| TrainError::io(path, e))
}

/// A checkpoint that could not be written (a full disk, most often), said with what is left:
/// checkpoints are written atomically, so the previous one, if any, is intact and a resume
/// continues from it once there is room.
pub fn not_written(e: TrainError, path: &Path, step: u64) -> TrainError {
    let left = if path.is_file() {
        format!(
            "{} still holds the previous checkpoint: make room and run the same command with --resume to continue from it",
            path.display()
        )
    } else {
        "no earlier checkpoint was written, so a new run starts from step 0".to_string()
    };
    TrainError::Invalid(format!(
        "cannot write the checkpoint of step {step} ({e}); {left}"
    ))
}

struct Reader<'a> {
    path: &'a Path,
    bytes: &'a [u8],
    at: usize,
}

impl Reader<'_> {
    /// `count` items of `size` bytes, refused (not wrapped) when the count is absurd.
    fn take_n(&mut self, count: usize, size: usize, what: &str) -> Result<&[u8]> {
        let n = count.checked_mul(size).ok_or_else(|| {
            TrainError::file(self.path, format!("{count} items of {what} overflow"))
        })?;
        self.take(n, what)
    }

    fn take(&mut self, n: usize, what: &str) -> Result<&[u8]> {
        let end = self.at.checked_add(n).filter(|&e| e <= self.bytes.len());
        let Some(end) = end else {
            return Err(TrainError::file(
                self.path,
                format!("truncated while reading {what}"),
            ));
        };
        let s = &self.bytes[self.at..end];
        self.at = end;
        Ok(s)
    }

    fn f32s(&mut self, n: usize, what: &str) -> Result<Vec<f32>> {
        Ok(le_words(self.take_n(n, 4, what)?, f32::from_le_bytes))
    }

    fn vec3s(&mut self, n: usize, what: &str) -> Result<Vec<Vec3>> {
        let floats = n.checked_mul(3).ok_or_else(|| {
            TrainError::file(self.path, format!("{n} vectors of {what} overflow"))
        })?;
        Ok(self
            .f32s(floats, what)?
            .chunks_exact(3)
            .map(Vec3::from_slice)
            .collect())
    }

    fn gaussians(&mut self, n: usize, degree: u32, what: &str) -> Result<Gaussians> {
        let mut g = Gaussians::new(degree);
        let rc = g.rest_count();
        g.means = self.vec3s(n, what)?;
        g.log_scales = self.vec3s(n, what)?;
        g.rotations = le_words(self.take_n(n, 16, what)?, f32::from_le_bytes)
            .chunks_exact(4)
            .map(|c| [c[0], c[1], c[2], c[3]])
            .collect();
        g.logit_opacities = self.f32s(n, what)?;
        g.sh_dc = self.vec3s(n, what)?;
        let rest = n
            .checked_mul(rc)
            .ok_or_else(|| TrainError::file(self.path, format!("{n} splats of {what} overflow")))?;
        g.sh_rest = self.vec3s(rest, what)?;
        Ok(g)
    }
}

/// The run config a checkpoint was saved with, read (with the file's integrity checked)
/// without decoding the model: enough to refuse a resume with other settings before anything
/// is written.
pub fn load_config(path: &Path) -> Result<TrainConfig> {
    let file = base::input::read(path).map_err(|e| TrainError::io(path, e))?;
    if is_legacy(&file) {
        let (h, _) = header(path, &file)?;
        return Ok(h.config);
    }
    Ok(SafeCheckpoint::open(path, &file)?.header.config)
}

/// Whether `file` is in one of the layouts before safetensors.
fn is_legacy(file: &[u8]) -> bool {
    matches!(file.get(..MAGIC.len()), Some(m) if m == MAGIC || m == MAGIC_V1)
}

/// A safetensors checkpoint, parsed and checked against its checksum.
struct SafeCheckpoint<'a> {
    path: &'a Path,
    header: Header,
    tensors: safetensors::SafeTensors<'a>,
}

impl<'a> SafeCheckpoint<'a> {
    fn open(path: &'a Path, file: &'a [u8]) -> Result<Self> {
        let not_ours = |why: String| {
            TrainError::file(
                path,
                format!("is damaged or not a metasplat checkpoint (safetensors: {why})"),
            )
        };
        let tensors =
            safetensors::SafeTensors::deserialize(file).map_err(|e| not_ours(e.to_string()))?;
        let (_, meta) =
            safetensors::SafeTensors::read_metadata(file).map_err(|e| not_ours(e.to_string()))?;
        let meta = meta.metadata().clone().unwrap_or_default();
        let (Some(json), Some(crc)) = (meta.get(HEADER_KEY), meta.get(CRC_KEY)) else {
            return Err(not_ours(format!(
                "a safetensors file without the {HEADER_KEY:?} and {CRC_KEY:?} metadata"
            )));
        };
        let sum = checksum(json.as_bytes(), |name| {
            tensors.tensor(name).ok().map(|t| t.data())
        });
        if format!("{sum:08x}") != *crc {
            return Err(TrainError::file(
                path,
                "the checksum does not match: the checkpoint is damaged (truncated, extended or changed)",
            ));
        }
        let header: Header = serde_json::from_str(json)
            .map_err(|e| TrainError::file(path, format!("bad header: {e}")))?;
        Ok(Self {
            path,
            header,
            tensors,
        })
    }

    /// Tensor `name`'s bytes, checked to be of `dtype` and `shape`.
    fn bytes(&self, name: &str, dtype: safetensors::Dtype, shape: &[usize]) -> Result<&'a [u8]> {
        let t = self.tensors.tensor(name).map_err(|_| {
            TrainError::file(self.path, format!("the checkpoint has no tensor {name}"))
        })?;
        if t.dtype() != dtype || t.shape() != shape {
            return Err(TrainError::file(
                self.path,
                format!(
                    "tensor {name} is {:?} {:?}, not {dtype:?} {shape:?}",
                    t.dtype(),
                    t.shape()
                ),
            ));
        }
        Ok(t.data())
    }

    fn f32s(&self, name: &str, shape: &[usize]) -> Result<Vec<f32>> {
        Ok(le_words(
            self.bytes(name, safetensors::Dtype::F32, shape)?,
            f32::from_le_bytes,
        ))
    }

    fn vec3s(&self, name: &str, shape: &[usize]) -> Result<Vec<Vec3>> {
        Ok(self
            .f32s(name, shape)?
            .chunks_exact(3)
            .map(Vec3::from_slice)
            .collect())
    }

    fn gaussians(&self, prefix: &str) -> Result<Gaussians> {
        let (n, degree) = (self.header.splats, self.header.sh_degree);
        let mut g = Gaussians::new(degree);
        let rc = g.rest_count();
        g.means = self.vec3s(&format!("{prefix}.means"), &[n, 3])?;
        g.log_scales = self.vec3s(&format!("{prefix}.log_scales"), &[n, 3])?;
        g.rotations = self
            .f32s(&format!("{prefix}.rotations"), &[n, 4])?
            .chunks_exact(4)
            .map(|c| [c[0], c[1], c[2], c[3]])
            .collect();
        g.logit_opacities = self.f32s(&format!("{prefix}.logit_opacities"), &[n])?;
        g.sh_dc = self.vec3s(&format!("{prefix}.sh_dc"), &[n, 3])?;
        g.sh_rest = self.vec3s(&format!("{prefix}.sh_rest"), &[n, rc, 3])?;
        Ok(g)
    }

    fn state(self) -> Result<(Header, Parts)> {
        let n = self.header.splats;
        self.header.check_degree(self.path)?;
        let psf = if self.header.psf_values > 0 {
            let k = self.header.psf_values;
            let moments = self.f32s("psf.moments", &[2, k])?;
            Some(RefineState {
                logits: self.f32s("psf.logits", &[k])?,
                m: moments[..k].to_vec(),
                v: moments[k..].to_vec(),
                steps: self.header.psf_steps,
            })
        } else {
            None
        };
        let parts = Parts {
            model: self.gaussians("model")?,
            m: self.gaussians("adam_m")?,
            v: self.gaussians("adam_v")?,
            grad_norm_sum: self.f32s("densify.grad_norm_sum", &[n])?,
            count: le_words(
                self.bytes("densify.count", safetensors::Dtype::U32, &[n])?,
                u32::from_le_bytes,
            ),
            max_radius: self.f32s("densify.max_radius", &[n])?,
            seen: self
                .bytes("densify.seen", safetensors::Dtype::U8, &[n])?
                .iter()
                .map(|&b| b != 0)
                .collect(),
            psf,
        };
        Ok((self.header, parts))
    }
}

/// The arrays of a checkpoint, whichever its layout.
struct Parts {
    model: Gaussians,
    m: Gaussians,
    v: Gaussians,
    grad_norm_sum: Vec<f32>,
    count: Vec<u32>,
    max_radius: Vec<f32>,
    seen: Vec<bool>,
    psf: Option<RefineState>,
}

/// The checked body of a checkpoint file: its header and a reader placed after it.
fn header<'a>(path: &'a Path, file: &'a [u8]) -> Result<(Header, Reader<'a>)> {
    let magic = file.get(..MAGIC.len());
    let bytes = if magic == Some(MAGIC) {
        let Some(body_len) = file.len().checked_sub(8) else {
            return Err(TrainError::file(
                path,
                "truncated while reading the checksum",
            ));
        };
        let (body, sum) = file.split_at(body_len);
        let sum = u64::from_le_bytes(sum.try_into().expect("8 bytes"));
        if base::hash::fnv1a64(body) != sum {
            return Err(TrainError::file(
                path,
                "the checksum does not match: the checkpoint is damaged (truncated, extended or changed)",
            ));
        }
        body
    } else if magic == Some(MAGIC_V1) {
        file
    } else {
        return Err(TrainError::file(path, "not a metasplat checkpoint"));
    };
    let mut r = Reader { path, bytes, at: 0 };
    r.take(MAGIC.len(), "the magic")?;
    let len = u64::from_le_bytes(r.take(8, "the header length")?.try_into().expect("8 bytes"));
    let json = r.take(len as usize, "the header")?;
    let h: Header = serde_json::from_slice(json)
        .map_err(|e| TrainError::file(path, format!("bad header: {e}")))?;
    Ok((h, r))
}

/// A checkpoint in the layouts before safetensors.
fn load_legacy(path: &Path, file: &[u8]) -> Result<(Header, Parts)> {
    let (h, mut r) = header(path, file)?;
    h.check_degree(path)?;
    let n = h.splats;
    let model = r.gaussians(n, h.sh_degree, "the model")?;
    let m = r.gaussians(n, h.sh_degree, "Adam's first moments")?;
    let v = r.gaussians(n, h.sh_degree, "Adam's second moments")?;
    let grad_norm_sum = r.f32s(n, "densification statistics")?;
    let count = le_words(
        r.take_n(n, 4, "densification statistics")?,
        u32::from_le_bytes,
    );
    let max_radius = r.f32s(n, "densification statistics")?;
    let seen = r.take(n, "visibility")?.iter().map(|&b| b != 0).collect();
    let psf = if h.psf_values > 0 {
        let what = "the refined PSF grid";
        Some(RefineState {
            logits: r.f32s(h.psf_values, what)?,
            m: r.f32s(h.psf_values, what)?,
            v: r.f32s(h.psf_values, what)?,
            steps: h.psf_steps,
        })
    } else {
        None
    };
    if r.at != r.bytes.len() {
        return Err(TrainError::file(
            path,
            "trailing bytes after the checkpoint",
        ));
    }
    Ok((
        h,
        Parts {
            model,
            m,
            v,
            grad_norm_sum,
            count,
            max_radius,
            seen,
            psf,
        },
    ))
}

pub fn load(path: &Path) -> Result<State> {
    let file = base::input::read(path).map_err(|e| TrainError::io(path, e))?;
    let (h, parts) = if is_legacy(&file) {
        load_legacy(path, &file)?
    } else {
        SafeCheckpoint::open(path, &file)?.state()?
    };
    let Parts {
        model,
        m,
        v,
        grad_norm_sum,
        count,
        max_radius,
        seen,
        psf,
    } = parts;
    // Values are checked as a PLY's are: a file whose checksum was made to match after an
    // edit must still not train a model that overflows or is empty.
    model
        .check_values()
        .map_err(|e| TrainError::file(path, format!("the checkpoint's splats: {e}")))?;
    if !(m.is_finite() && v.is_finite()) {
        return Err(TrainError::file(
            path,
            "the checkpoint's optimiser moments are not finite",
        ));
    }
    let end = h.config.iters;
    if h.step > end {
        return Err(TrainError::file(
            path,
            format!(
                "the checkpoint is at step {}, past the run's {end} steps",
                h.step
            ),
        ));
    }
    let adam = Adam::from_state(h.adam_step, m, v)?;
    let densify = DensifyState {
        stats: DensifyStats {
            grad_norm_sum,
            count,
            max_radius,
        },
        seen,
    };
    Ok(State {
        config: h.config,
        progress: Progress {
            step: h.step,
            train_seconds: h.train_seconds,
            densify,
            sh: h.sh,
            log: h.log,
            psf: None,
            stop: h.stop,
        },
        model,
        adam,
        psf,
    })
}

fn put_f32s(out: &mut Vec<u8>, v: impl IntoIterator<Item = f32>) {
    for x in v {
        out.extend_from_slice(&x.to_le_bytes());
    }
}

fn put_gaussians(out: &mut Vec<u8>, g: &Gaussians) {
    let v3 = |v: &[Vec3]| v.iter().flat_map(|p| p.to_array()).collect::<Vec<f32>>();
    put_f32s(out, v3(&g.means));
    put_f32s(out, v3(&g.log_scales));
    put_f32s(out, g.rotations.iter().flatten().copied());
    put_f32s(out, g.logit_opacities.iter().copied());
    put_f32s(out, v3(&g.sh_dc));
    put_f32s(out, v3(&g.sh_rest));
}

/// Writes the version-2 layout of the checkpoints before safetensors. Nothing saves it any
/// more; it stays so that the test of the reader that keeps old checkpoints loading can make
/// one.
#[doc(hidden)]
pub fn save_v2(
    path: &Path,
    config: &TrainConfig,
    p: &Progress,
    model: &Gaussians,
    adam: &Adam,
) -> Result<()> {
    let header = Header::of(config, p, model, adam);
    let json = serde_json::to_vec(&header).map_err(|e| TrainError::file(path, e.to_string()))?;
    let mut out = Vec::with_capacity(model.param_bytes() * 3 + json.len() + 64);
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&(json.len() as u64).to_le_bytes());
    out.extend_from_slice(&json);
    put_gaussians(&mut out, model);
    let (m, v) = adam.moments();
    put_gaussians(&mut out, m);
    put_gaussians(&mut out, v);
    let st = &p.densify.stats;
    put_f32s(&mut out, st.grad_norm_sum.iter().copied());
    for c in &st.count {
        out.extend_from_slice(&c.to_le_bytes());
    }
    put_f32s(&mut out, st.max_radius.iter().copied());
    out.extend(p.densify.seen.iter().map(|&b| b as u8));
    if let Some(r) = &p.psf {
        let st = r.state();
        for v in [&st.logits, &st.m, &st.v] {
            put_f32s(&mut out, v.iter().copied());
        }
    }
    let sum = base::hash::fnv1a64(&out);
    out.extend_from_slice(&sum.to_le_bytes());
    base::write_bytes_atomically(path, &out).map_err(|e| TrainError::io(path, e))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_checkpoint_not_written_says_whether_an_earlier_one_holds_the_run() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("checkpoint.bin");
        let full = || TrainError::io(&path, std::io::Error::from_raw_os_error(28));
        let none = not_written(full(), &path, 600).to_string();
        assert!(
            none.contains("step 600") && none.contains("from step 0"),
            "{none}"
        );
        assert!(none.contains("No space left"), "{none}");
        std::fs::write(&path, b"an earlier checkpoint").unwrap();
        let earlier = not_written(full(), &path, 1200).to_string();
        assert!(
            earlier.contains("step 1200") && earlier.contains("--resume"),
            "{earlier}"
        );
        assert!(earlier.contains(&path.display().to_string()), "{earlier}");
    }
}
