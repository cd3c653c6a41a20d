//! Checkpoints: everything the loop needs to continue bit for bit (model, Adam moments,
//! densification statistics, SH state, log), in one file written to a temporary name and
//! renamed, so a kill leaves the previous checkpoint intact.
//!
//! Layout: magic, u64 header length, JSON header, then little-endian arrays in a fixed order.

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

pub fn save(
    path: &Path,
    config: &TrainConfig,
    p: &Progress,
    model: &Gaussians,
    adam: &Adam,
) -> Result<()> {
    let header = Header {
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
    };
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
        Ok(self
            .take_n(n, 4, what)?
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect())
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
        g.rotations = self
            .take_n(n, 16, what)?
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect::<Vec<f32>>()
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
    let file = std::fs::read(path).map_err(|e| TrainError::io(path, e))?;
    let (h, _) = header(path, &file)?;
    Ok(h.config)
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

pub fn load(path: &Path) -> Result<State> {
    let file = std::fs::read(path).map_err(|e| TrainError::io(path, e))?;
    let (h, mut r) = header(path, &file)?;
    if h.sh_degree > splat::MAX_SH_DEGREE {
        return Err(TrainError::file(
            path,
            format!("SH degree {} too high", h.sh_degree),
        ));
    }
    let n = h.splats;
    let model = r.gaussians(n, h.sh_degree, "the model")?;
    let m = r.gaussians(n, h.sh_degree, "Adam's first moments")?;
    let v = r.gaussians(n, h.sh_degree, "Adam's second moments")?;
    let grad_norm_sum = r.f32s(n, "densification statistics")?;
    let count = r
        .take_n(n, 4, "densification statistics")?
        .chunks_exact(4)
        .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
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
    if !model.means.iter().all(|p| p.is_finite()) {
        return Err(TrainError::file(path, "non-finite splat positions"));
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
        },
        model,
        adam,
        psf,
    })
}
