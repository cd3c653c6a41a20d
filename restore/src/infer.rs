//! Restoring images with trained weights: the library call the splat trainer and
//! `metasplat restore` use.

use crate::config::RestorerConfig;
use crate::data::bank_images;
use crate::ensemble;
use crate::error::{RestoreError, Result};
use crate::net::RestorerNet;
use crate::tiles::{Planes, round_up, tiled};
use crate::weights::{self, Header};
use aberration::wiener::BANK_SIZE;
use aberration::{Image, PsfGrid};
use burn::tensor::{Device, Tensor, TensorData};
use std::path::Path;

/// Runs the network on one padded tile of Wiener planes (39 channels).
pub fn run_tile(net: &RestorerNet, x: &Planes, device: &Device) -> Planes {
    let t = Tensor::<4>::from_data(TensorData::new(x.data.clone(), [1, x.c, x.h, x.w]), device);
    let y: Vec<f32> = net
        .forward(t)
        .try_into_vec_as::<f32>()
        .expect("flex tensors read back");
    Planes {
        c: 3,
        h: x.h,
        w: x.w,
        data: y,
    }
}

/// The 13 Wiener images as network input planes (filter-major).
pub fn bank_planes(bank: &[Image]) -> Planes {
    let (w, h) = (bank[0].width, bank[0].height);
    let mut data = Vec::with_capacity(BANK_SIZE * 3 * w * h);
    for img in bank {
        data.extend_from_slice(&img.data);
    }
    Planes {
        c: 3 * bank.len(),
        h,
        w,
        data,
    }
}

/// A frozen restorer.
pub struct Restorer {
    pub net: RestorerNet,
    pub header: Header,
    pub device: Device,
    /// [`weights::fingerprint`] of the weights file it was loaded from (None for a network
    /// built in memory): lets a splat checkpoint tell whether `I_ac` would come from the same
    /// network.
    pub weights_hash: Option<String>,
    /// The same file's FNV-1a hex, as splat checkpoints written before XXH3 recorded it.
    pub weights_fnv1a: Option<String>,
    /// Tile side and overlap for large images (multiples of the config's padding unit).
    pub tile: usize,
    pub overlap: usize,
    /// Members of the self-ensemble (1: one pass; see [`crate::ensemble`]).
    pub ensemble: usize,
}

/// Memory a tile may take in inference.
const TILE_BUDGET_BYTES: f64 = 1.5e9;

/// The largest tile side (a multiple of the config's padding unit) whose MAFG attention fits
/// [`TILE_BUDGET_BYTES`]: 13 filters × key-window logits per pixel, about three live copies
/// (logits, softmax, a temporary). 512 px for `tiny`, 256 px for `paper`.
pub fn default_tile(cfg: &RestorerConfig) -> usize {
    let bytes_per_px = (BANK_SIZE * cfg.key_window().pow(2) * 4 * 3) as f64;
    let side = (TILE_BUDGET_BYTES / bytes_per_px).sqrt() as usize;
    let m = cfg.multiple();
    (side / m * m).max(m)
}

impl Restorer {
    pub fn new(net: RestorerNet, header: Header, device: Device) -> Self {
        let m = header.config.multiple();
        let tile = default_tile(&header.config);
        Self {
            net,
            header,
            device,
            weights_hash: None,
            weights_fnv1a: None,
            tile,
            overlap: m,
            ensemble: 1,
        }
    }

    /// Loads weights that serve `native` (the PSF grid as simulated, before mapping to an
    /// image size: the grid they were trained on, or one inside their lens family); another
    /// grid is refused.
    pub fn load(path: &Path, native: &PsfGrid) -> Result<Self> {
        Self::load_on(path, native, Device::flex())
    }

    /// [`Restorer::load`] on a given device (see [`crate::Compute`]).
    pub fn load_on(path: &Path, native: &PsfGrid, device: Device) -> Result<Self> {
        let bytes = base::input::read(path).map_err(|e| RestoreError::Io(path.to_path_buf(), e))?;
        Self::from_bytes_on(&bytes, path, native, device)
    }

    /// [`Restorer::load`] from the bytes of a weights file (`name` names them in errors).
    pub fn from_bytes(bytes: &[u8], name: &Path, native: &PsfGrid) -> Result<Self> {
        Self::from_bytes_on(bytes, name, native, Device::flex())
    }

    /// [`Restorer::from_bytes`] on a given device (see [`crate::Compute`]).
    pub fn from_bytes_on(
        bytes: &[u8],
        name: &Path,
        native: &PsfGrid,
        device: Device,
    ) -> Result<Self> {
        Self::from_bytes_checked_on(bytes, name, Some(native), device)
    }

    /// Weights from a file whatever grid they were trained for (`restorer eval --any-grid`:
    /// to measure them on a lens they do not cover); a damaged file is still refused.
    pub fn load_any_grid_on(path: &Path, device: Device) -> Result<Self> {
        let bytes = base::input::read(path).map_err(|e| RestoreError::Io(path.to_path_buf(), e))?;
        Self::from_bytes_checked_on(&bytes, path, None, device)
    }

    /// [`Self::load_any_grid_on`] from bytes in memory.
    pub fn from_bytes_any_grid_on(bytes: &[u8], name: &Path, device: Device) -> Result<Self> {
        Self::from_bytes_checked_on(bytes, name, None, device)
    }

    fn from_bytes_checked_on(
        bytes: &[u8],
        name: &Path,
        native: Option<&PsfGrid>,
        device: Device,
    ) -> Result<Self> {
        let (net, header) = weights::load_bytes(bytes, name, &device, None, native)?;
        let mut r = Self::new(net, header, device);
        r.weights_hash = Some(weights::fingerprint(bytes));
        r.weights_fnv1a = Some(format!("{:016x}", base::hash::fnv1a64(bytes)));
        Ok(r)
    }

    pub fn config(&self) -> &RestorerConfig {
        &self.header.config
    }

    /// Sets the tile side and overlap: the tile a positive multiple of the config's padding
    /// unit, the overlap below half a tile.
    pub fn with_tiling(mut self, tile: usize, overlap: usize) -> Result<Self> {
        let m = self.config().multiple();
        if tile == 0 || !tile.is_multiple_of(m) || 2 * overlap >= tile {
            return Err(RestoreError::BadInput(format!(
                "tile {tile} px with overlap {overlap} px: config '{}' needs a tile that is a \
                 positive multiple of {m} px and an overlap under half of it",
                self.config().name
            )));
        }
        self.tile = tile;
        self.overlap = overlap;
        Ok(self)
    }

    /// Averages the network's answers on the bank mirrored and turned by the first `n` of
    /// [`ensemble::members`] (1, 2, 4 or 8); `n` times the network's time.
    pub fn with_ensemble(mut self, n: usize) -> Result<Self> {
        if !ensemble::SIZES.contains(&n) {
            return Err(RestoreError::BadInput(format!(
                "a self-ensemble of {n}: it takes 1, 2, 4 or 8 members"
            )));
        }
        self.ensemble = n;
        Ok(self)
    }

    /// The network as reports name it: its config, and the self-ensemble when it has more
    /// than one member (`tiny, 8-member ensemble`).
    pub fn label(&self) -> String {
        match self.ensemble {
            0 | 1 => self.config().name.clone(),
            n => format!("{}, {n}-member ensemble", self.config().name),
        }
    }

    /// Restores 13 Wiener images of one aberrated image; output clamped to [0, 1].
    pub fn restore_bank(&self, bank: &[Image]) -> Image {
        let (w, h) = (bank[0].width, bank[0].height);
        let mut img = if self.ensemble <= 1 {
            self.network_pass(bank)
        } else {
            let members = ensemble::members(self.ensemble);
            let mut sum = Image::new(w, h);
            for s in members {
                let turned: Vec<Image> = bank.iter().map(|b| s.apply(b)).collect();
                let answer = s.undo(&self.network_pass(&turned), w, h);
                for (a, b) in sum.data.iter_mut().zip(&answer.data) {
                    *a += b;
                }
            }
            let scale = 1.0 / members.len() as f32;
            sum.data.iter_mut().for_each(|v| *v *= scale);
            sum
        };
        // A non-finite output (never seen; guards the splat trainer) falls back to the median.
        if !img.is_finite() {
            img = bank[aberration::wiener::BANK_MEDIAN].clone();
        }
        img.clamp01();
        img
    }

    /// The network's answer on the bank as it is, tiled, before any clamping.
    fn network_pass(&self, bank: &[Image]) -> Image {
        let (w, h) = (bank[0].width, bank[0].height);
        let m = self.config().multiple();
        let x = bank_planes(bank).padded(round_up(h, m), round_up(w, m));
        let y = tiled(&x, self.tile, self.overlap, |t| {
            Ok::<_, std::convert::Infallible>(run_tile(&self.net, t, &self.device))
        })
        .unwrap_or_else(|e| match e {})
        .cropped(h, w);
        Image {
            width: w,
            height: h,
            data: y.data,
        }
    }

    /// Restores an aberrated image whose PSF grid at its scale is `psf`.
    pub fn restore(&self, blurred: &Image, psf: &PsfGrid) -> Result<Image> {
        let bank = bank_images(blurred, psf, self.config().adaptive_k)?;
        Ok(self.restore_bank(&bank))
    }
}
