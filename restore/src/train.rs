//! Training: random crops of on-the-fly aberrated photos, L1 loss on the restored image,
//! AdamW with a cosine schedule, periodic validation and checkpoints.

use crate::compute::Compute;
use crate::config::RestorerConfig;
use crate::data::{TrainSet, bank_images};
use crate::error::Result;
use crate::infer::Restorer;
use crate::net::RestorerNet;
use crate::train_state::{self, TrainState, state_path};
use crate::weights::{self, Header, PsfFingerprint};
use aberration::wiener::BANK_SIZE;
use aberration::{BlurMode, Image, ImagingModel, NoiseModel, PsfGrid};
use burn::module::Module;
use burn::optim::grad_clipping::GradientClippingConfig;
use burn::optim::{AdamWConfig, GradientsParams, OptimizerRecord};
use burn::tensor::{Tensor, TensorData};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use std::path::Path;
use std::time::Instant;

/// What defines a run's optimisation, saved with its state so `--resume` continues the same
/// schedule whatever the command line of the resuming call says.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Schedule {
    pub steps: usize,
    pub batch: usize,
    pub lr: f64,
    pub weight_decay: f32,
    /// Per-parameter gradient L2-norm clip (burn's `GradientClippingConfig::Norm`).
    pub clip: f32,
    pub seed: u64,
    /// Re-aberrate the photos (new noise, new random PSF positions) every this many steps;
    /// 0: one set for the whole run. (States written before it existed did not refresh.)
    #[serde(default)]
    pub refresh_every: usize,
    /// The pixel loss. (States written before it existed trained with L1.)
    #[serde(default)]
    pub loss: Loss,
}

/// The loss on the restored image against the clean one.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Loss {
    /// Mean absolute error, as Restormer and the paper train.
    #[default]
    L1,
    /// Mean squared error: PSNR's own measure, for a last fine-tune towards it (an L1 optimum
    /// is the pixels' median, an L2 one their mean, which PSNR scores higher).
    L2,
}

impl Loss {
    /// The loss of `restored` against `clean`, a scalar tensor.
    pub fn of(self, restored: Tensor<4>, clean: Tensor<4>) -> Tensor<1> {
        let d = restored - clean;
        match self {
            Loss::L1 => d.abs().mean(),
            Loss::L2 => d.clone().mul(d).mean(),
        }
    }
}

#[derive(Clone, Debug)]
pub struct TrainOptions {
    pub schedule: Schedule,
    /// Validate (and checkpoint weights and training state) every this many steps; 0: only
    /// at the end.
    pub val_every: usize,
    pub noise: NoiseModel,
    pub compute: Compute,
    /// End this invocation, with a checkpoint, after this many steps of it, or at the first
    /// step that ends past this many seconds: the run is then continued with `Start::Resume`.
    pub stop_after_steps: Option<usize>,
    pub stop_after_seconds: Option<f64>,
    /// The lens family the pairs are drawn from, written into the weights header so that
    /// loading accepts its grids; None: the pairs come through `native` alone.
    pub family: Option<crate::coverage::Family>,
}

/// Seed of the training pairs of refresh round `round` (round 0: the run's seed).
pub fn round_seed(seed: u64, round: usize) -> u64 {
    if round == 0 {
        return seed;
    }
    // Mixed, so neighbouring rounds get unrelated streams.
    seed ^ base::mix64((round as u64).wrapping_add(base::rng::GOLDEN_GAMMA))
}

impl Schedule {
    /// The refresh round `step` falls in.
    pub fn round(&self, step: usize) -> usize {
        step.checked_div(self.refresh_every).unwrap_or(0)
    }
}

impl Default for Schedule {
    fn default() -> Self {
        Self {
            steps: 2000,
            batch: 8,
            lr: 3e-4,
            weight_decay: 1e-4,
            clip: 1.0,
            seed: 0,
            refresh_every: 200,
            loss: Loss::L1,
        }
    }
}

impl Default for TrainOptions {
    fn default() -> Self {
        Self {
            schedule: Schedule::default(),
            val_every: 250,
            noise: NoiseModel::default(),
            compute: Compute::Cpu,
            stop_after_steps: None,
            stop_after_seconds: None,
            family: None,
        }
    }
}

/// Learning rate at `step`: linear warm-up over 2% of training, then cosine to 1% of `lr`.
pub fn learning_rate(lr: f64, step: usize, steps: usize) -> f64 {
    let warm = (steps / 50).max(1);
    if step < warm {
        return lr * (step + 1) as f64 / warm as f64;
    }
    let t = (step - warm) as f64 / (steps - warm).max(1) as f64;
    lr * (0.01 + 0.99 * 0.5 * (1.0 + (std::f64::consts::PI * t).cos()))
}

/// PSF sides (px) a family run validates at, one per photo in turn: the scales
/// `restorer eval --psf-px` reports.
pub const FAMILY_VAL_PSF_PX: [usize; 6] = [19, 38, 57, 85, 113, 135];

/// The grid and sensor size (None: the grid's own) validation photo `i` is blurred through.
type Through<'g> = dyn Fn(usize, &Image) -> Result<(&'g PsfGrid, Option<usize>)> + 'g;

/// Validation images: each aberrated once through the whole grid with a fixed seed.
#[derive(Default)]
pub struct ValSet {
    pub names: Vec<String>,
    pub banks: Vec<Vec<Image>>,
    pub clean: Vec<Image>,
    /// Per photo, the group its figure is also reported in (a family run's PSF scale, e.g.
    /// "19 px"); empty where the set has one group.
    pub groups: Vec<String>,
}

impl ValSet {
    /// `crop`: validate on the centred `crop × crop` region (whole images when `None`); the
    /// Wiener images are computed on the whole photo either way.
    pub fn build(
        photos: &[(String, Image)],
        native: &PsfGrid,
        cfg: &RestorerConfig,
        noise: NoiseModel,
        crop: Option<usize>,
    ) -> Result<Self> {
        Self::build_through(photos, &|_, _| Ok((native, None)), cfg, noise, crop)
    }

    /// Validation over a lens family: photo `i` with PSFs of [`FAMILY_VAL_PSF_PX`]`[i % 6]` px
    /// at its size, through lens `(i / 6) % lenses.len()` (each of the first lenses at every
    /// scale, the centre first), so that the figure follows the range a family network serves.
    pub fn build_family(
        photos: &[(String, Image)],
        lenses: &[PsfGrid],
        cfg: &RestorerConfig,
        noise: NoiseModel,
        crop: Option<usize>,
    ) -> Result<Self> {
        if lenses.is_empty() {
            return Err(crate::error::RestoreError::BadInput(
                "a lens family of no lenses".into(),
            ));
        }
        let through = |i: usize, img: &Image| {
            let n = FAMILY_VAL_PSF_PX.len();
            let lens = &lenses[(i / n) % lenses.len()];
            let px = FAMILY_VAL_PSF_PX[i % n];
            Ok((
                lens,
                Some(lens.sensor_for_psf_px(img.width, img.height, px)),
            ))
        };
        let mut v = Self::build_through(photos, &through, cfg, noise, crop)?;
        v.groups = (0..v.names.len())
            .map(|i| format!("{} px", FAMILY_VAL_PSF_PX[i % FAMILY_VAL_PSF_PX.len()]))
            .collect();
        Ok(v)
    }

    /// Validation on captured pairs (`(name, captured, clean)`): each captured photo's bank
    /// through `native`, against its clean photo.
    pub fn from_pairs(
        pairs: &[(String, Image, Image)],
        native: &PsfGrid,
        cfg: &RestorerConfig,
        crop: Option<usize>,
    ) -> Result<Self> {
        let mut v = ValSet::default();
        for (name, captured, clean) in pairs {
            let psf = native.for_image(captured.width, captured.height, None)?;
            let bank = bank_images(captured, &psf, cfg.adaptive_k)?;
            v.push(name, bank, clean, crop);
        }
        Ok(v)
    }

    /// Adds one photo's bank and clean image, cropped to the centred `crop²` when asked.
    fn push(&mut self, name: &str, bank: Vec<Image>, img: &Image, crop: Option<usize>) {
        let (bank, clean) = match crop {
            Some(s) if s < img.width.min(img.height) => {
                let (x0, y0) = ((img.width - s) / 2, (img.height - s) / 2);
                (
                    bank.iter().map(|b| crop_image(b, x0, y0, s)).collect(),
                    crop_image(img, x0, y0, s),
                )
            }
            _ => (bank, img.clone()),
        };
        self.names.push(name.to_string());
        self.banks.push(bank);
        self.clean.push(clean);
    }

    /// Each photo through the grid and sensor `through(index, photo)` gives.
    fn build_through<'g>(
        photos: &[(String, Image)],
        through: &Through<'g>,
        cfg: &RestorerConfig,
        noise: NoiseModel,
        crop: Option<usize>,
    ) -> Result<Self> {
        let mut v = ValSet::default();
        for (i, (name, img)) in photos.iter().enumerate() {
            let (native, sensor) = through(i, img)?;
            let model = ImagingModel::new(
                native,
                img.width,
                img.height,
                BlurMode::Tiled,
                sensor,
                noise,
            )?;
            let blurred = model.capture(img, 0x5EED_0000 + i as u64)?;
            let bank = bank_images(&blurred, model.psf(), cfg.adaptive_k)?;
            v.push(name, bank, img, crop);
        }
        Ok(v)
    }
}

pub fn crop_image(img: &Image, x0: usize, y0: usize, s: usize) -> Image {
    Image::from_fn(s, s, |x, y| {
        std::array::from_fn(|c| img.get(x0 + x, y0 + y, c))
    })
}

/// Mean PSNR and SSIM ([`aberration::compare`]) of a restorer on a validation set.
pub fn validate(restorer: &Restorer, val: &ValSet) -> Result<(f64, f64)> {
    Ok(validate_groups(restorer, val)?.0)
}

/// Mean PSNR (dB) of each validation group, by name, in the order they first appear.
pub type GroupPsnr = Vec<(String, f64)>;

/// [`validate`], and the mean PSNR of each of the set's groups ([`ValSet::groups`]) in the
/// order they first appear (none for a set of one group).
pub fn validate_groups(restorer: &Restorer, val: &ValSet) -> Result<((f64, f64), GroupPsnr)> {
    let mut acc = (0.0, 0.0);
    let mut groups: Vec<(String, f64, usize)> = Vec::new();
    for (i, (bank, clean)) in val.banks.iter().zip(&val.clean).enumerate() {
        let (p, s) = aberration::compare(&restorer.restore_bank(bank), clean)?;
        acc.0 += p;
        acc.1 += s;
        if let Some(name) = val.groups.get(i) {
            match groups.iter_mut().find(|g| g.0 == *name) {
                Some(g) => {
                    g.1 += p;
                    g.2 += 1;
                }
                None => groups.push((name.clone(), p, 1)),
            }
        }
    }
    let n = val.banks.len().max(1) as f64;
    let groups = groups
        .into_iter()
        .map(|(name, sum, count)| (name, sum / count as f64))
        .collect();
    Ok(((acc.0 / n, acc.1 / n), groups))
}

/// What training reports as it goes.
pub enum Event {
    /// Training pairs made for a refresh round.
    Pairs {
        round: usize,
        samples: usize,
        seconds: f64,
    },
    Step {
        step: usize,
        loss: f32,
        lr: f64,
    },
    Val {
        step: usize,
        psnr: f64,
        ssim: f64,
        seconds: f64,
        /// Mean PSNR of each validation group (a family run's PSF scales); empty for one.
        groups: GroupPsnr,
    },
}

/// How a run begins.
pub enum Start {
    /// Fresh weights from the backend's seed.
    Fresh,
    /// These weights, a new optimizer and schedule.
    Init(RestorerNet),
    /// Continue a run exactly: its weights (loaded with their parameter ids, which key the
    /// optimizer state) and its saved state. The schedule comes from the state, not `opts`.
    Resume(RestorerNet, Box<TrainState>, OptimizerRecord),
}

/// What a training run works with.
pub struct TrainRun<'a> {
    pub config: &'a RestorerConfig,
    /// The PSF grid the pairs were aberrated with (its fingerprint goes into the weights).
    pub native: &'a PsfGrid,
    /// `pairs(round)` makes the training pairs of a refresh round ([`Schedule::round`]; seed
    /// them with [`round_seed`]): the round of the first step, then each later one.
    pub pairs: &'a dyn Fn(usize) -> Result<TrainSet>,
    pub val: &'a ValSet,
    pub options: &'a TrainOptions,
    /// The weights file, written at every validation and at the end, with the training
    /// state beside it (`out.state`, see [`crate::train_state`]) so the run can be resumed.
    pub out: &'a Path,
    /// The weights file's provenance record at `(step, seconds, (val PSNR, val SSIM))`
    /// (see [`crate::provenance`]).
    pub provenance: &'a dyn Fn(usize, f64, (f64, f64)) -> serde_json::Value,
}

/// Trains a network as `run` says. Returns the trained network, the last validation metrics
/// and the step reached (below the schedule's steps when a `stop_after_*` ended the
/// invocation early).
pub fn train(
    run: &TrainRun<'_>,
    start: Start,
    on_event: &mut dyn FnMut(Event),
) -> Result<(RestorerNet, (f64, f64), usize)> {
    let &TrainRun {
        config: cfg,
        native,
        pairs,
        val,
        options: opts,
        out,
        provenance,
    } = run;
    let inner = opts.compute.device()?;
    let device = inner.clone().autodiff();
    let mut sched = opts.schedule.clone();
    device.seed(sched.seed);
    let mut rng = ChaCha8Rng::seed_from_u64(sched.seed);
    let (mut net, record, first, seconds_before, mut val_log) = match start {
        Start::Fresh => (RestorerNet::new(cfg, &device), None, 0, 0.0, vec![]),
        Start::Init(net) => (net, None, 0, 0.0, vec![]),
        Start::Resume(net, state, record) => {
            sched = state.schedule.clone();
            rng = ChaCha8Rng::seed_from_u64(sched.seed);
            rng.set_word_pos(state.rng_word_pos.parse().map_err(|_| {
                crate::error::RestoreError::BadInput(format!(
                    "bad sampler position '{}'",
                    state.rng_word_pos
                ))
            })?);
            (net, Some(record), state.step, state.seconds, state.val_log)
        }
    };
    let mut optim = AdamWConfig::new()
        .with_weight_decay(sched.weight_decay)
        .with_grad_clipping(Some(GradientClippingConfig::Norm(sched.clip)))
        .init();
    if let Some(record) = record {
        optim = optim.load_record(record);
    }
    let sched = sched;
    let make = |round: usize, on_event: &mut dyn FnMut(Event)| -> Result<TrainSet> {
        let t = Instant::now();
        let set = pairs(round)?;
        on_event(Event::Pairs {
            round,
            samples: set.samples.len(),
            seconds: t.elapsed().as_secs_f64(),
        });
        Ok(set)
    };
    let mut set = make(sched.round(first), on_event)?;
    let s = cfg.crop;
    let mut last = val_log
        .last()
        .map_or((f64::NAN, f64::NAN), |&(_, _, p, s)| (p, s));
    let state_file = state_path(out);
    let invocation = Instant::now();
    let mut reached = first;
    for step in first..sched.steps {
        if step != first && sched.round(step) != sched.round(step - 1) {
            set = make(sched.round(step), on_event)?;
        }
        let (x, y) = set.batch(&mut rng, sched.batch, s);
        let x = Tensor::<4>::from_data(
            TensorData::new(x, [sched.batch, 3 * BANK_SIZE, s, s]),
            &device,
        );
        let y = Tensor::<4>::from_data(TensorData::new(y, [sched.batch, 3, s, s]), &device);
        let loss = sched.loss.of(net.forward(x), y);
        let grads = GradientsParams::from_grads(loss.backward(), &net);
        let lr = learning_rate(sched.lr, step, sched.steps);
        net = optim.step(lr, net, grads);
        let l: f32 = loss.into_scalar::<f32>();
        reached = step + 1;
        on_event(Event::Step {
            step: step + 1,
            loss: l,
            lr,
        });
        // A Ctrl-C stops as a time budget does: weights and state saved, resumable.
        let stop = base::interrupt::requested()
            || opts.stop_after_steps.is_some_and(|n| step + 1 - first >= n)
            || opts
                .stop_after_seconds
                .is_some_and(|t| invocation.elapsed().as_secs_f64() >= t);
        let done = step + 1 == sched.steps;
        if done || stop || (opts.val_every > 0 && (step + 1) % opts.val_every == 0) {
            let mut header = Header {
                config: cfg.clone(),
                psf: PsfFingerprint::of(native),
                trained_psf_px: Some(set.psf_px),
                family: opts.family.clone(),
                provenance: serde_json::Value::Null,
            };
            let r = Restorer::new(net.valid(), header.clone(), inner.clone());
            let groups;
            (last, groups) = validate_groups(&r, val)?;
            let seconds = seconds_before + invocation.elapsed().as_secs_f64();
            on_event(Event::Val {
                step: step + 1,
                psnr: last.0,
                ssim: last.1,
                seconds,
                groups,
            });
            val_log.push((step + 1, seconds, last.0, last.1));
            header.provenance = provenance(step + 1, seconds, last);
            let weights_hash = weights::save(&net.valid(), &header, out)?;
            let state = TrainState {
                step: step + 1,
                schedule: sched.clone(),
                rng_word_pos: rng.get_word_pos().to_string(),
                seconds,
                weights_hash,
                val_log: val_log.clone(),
            };
            train_state::save(&state, optim.to_record(), &state_file)?;
        }
        if stop {
            break;
        }
    }
    Ok((net.valid(), last, reached))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_losses_are_the_mean_absolute_and_the_mean_squared_error() {
        let device = burn::tensor::Device::flex();
        let t = |v: [f32; 4]| {
            Tensor::<4>::from_data(TensorData::new(v.to_vec(), [1, 1, 2, 2]), &device)
        };
        let (restored, clean) = (t([0.5, 1.0, -2.0, 3.0]), t([0.0, 1.0, 1.0, 1.0]));
        // Differences 0.5, 0, -3, 2: |d| sums to 5.5, d² to 13.25.
        let got = |loss: Loss| {
            loss.of(restored.clone(), clean.clone())
                .into_scalar::<f32>()
        };
        assert!(
            (got(Loss::L1) - 5.5 / 4.0).abs() < 1e-6,
            "{}",
            got(Loss::L1)
        );
        assert!(
            (got(Loss::L2) - 13.25 / 4.0).abs() < 1e-6,
            "{}",
            got(Loss::L2)
        );
    }
}
