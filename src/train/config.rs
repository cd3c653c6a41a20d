//! What a training run does: the mode, the objective's weights, the 3DGS recipe scaled to the
//! run's length, and the budget.

use serde::{Deserialize, Serialize};
use splat::optim::LearningRates;

use crate::settings::MaskUse;
pub use crate::settings::Mode;
use crate::settings::{
    Background, Iters, LambdaFade, MaskChoice, StrategyChoice, Toggle, TrainSettings,
};
use crate::train::coarse::Coarse;
use crate::train::data::Dataset;
use crate::train::iac::IacSource;
use crate::train::psf_refine::PsfRefineConfig;
use crate::train::stop::StopRule;

/// The 3DGS schedule (INRIA defaults at 30k steps) and thresholds.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Recipe {
    pub densify_from: u64,
    pub densify_until: u64,
    pub densify_every: u64,
    /// `None` disables the opacity reset (the paper did for LLFF scenes).
    pub opacity_reset_every: Option<u64>,
    /// Steps between SH band decisions (raise one band, or drop one that did not pay).
    pub sh_every: u64,
    pub grad_threshold: f32,
    /// Clone (rather than split) when the largest scale is below this fraction of the extent.
    pub percent_dense: f32,
    pub prune_opacity: f32,
    /// Per-group learning rates (INRIA defaults; `means` before scaling by the scene extent).
    pub lrs: LearningRates,
    pub position_lr_final_ratio: f32,
    pub dssim_weight: f32,
    /// After the first opacity reset, splats wider than this fraction of the extent are
    /// pruned (3DGS: 0.1).
    #[serde(default = "defaults::max_world_scale")]
    pub max_world_scale: f32,
    /// After the first opacity reset, splats with a larger screen radius (px) are pruned.
    #[serde(default = "defaults::max_screen_radius")]
    pub max_screen_radius: f32,
    /// An SH band stays when dropping it raises the training loss by at least this fraction.
    #[serde(default = "defaults::sh_min_gain")]
    pub sh_min_gain: f64,
}

/// Defaults of the thresholds added to the recipe after the first checkpoints were written,
/// so that those still load (and compare equal to a fresh config).
pub mod defaults {
    pub fn max_world_scale() -> f32 {
        0.1
    }
    pub fn max_screen_radius() -> f32 {
        20.0
    }
    pub fn sh_min_gain() -> f64 {
        1e-3
    }
}

impl Recipe {
    /// The INRIA recipe with its step counts scaled by `iters / 30000` (clamped so short runs
    /// still average densification statistics over several passes through the views).
    pub fn for_iters(iters: u64, opacity_reset: bool) -> Recipe {
        let f = iters as f64 / 30_000.0;
        let scale = |v: f64, lo: u64, hi: u64| ((v * f).round() as u64).clamp(lo, hi);
        let densify_every = scale(100.0, 25, 100);
        Recipe {
            densify_from: scale(500.0, 2 * densify_every, 500),
            densify_until: iters / 2,
            densify_every,
            // Room for the recovery after each reset, and for pruning between two.
            opacity_reset_every: opacity_reset
                .then(|| scale(3000.0, (4 * densify_every).max(2 * RESET_RECOVERY), 3000)),
            sh_every: scale(1000.0, 100, 1000),
            grad_threshold: 2e-4,
            percent_dense: 0.01,
            prune_opacity: 0.005,
            lrs: LearningRates::default(),
            position_lr_final_ratio: 0.01,
            dssim_weight: 0.2,
            max_world_scale: defaults::max_world_scale(),
            max_screen_radius: defaults::max_screen_radius(),
            sh_min_gain: defaults::sh_min_gain(),
        }
    }
}

/// The MCMC strategy's schedule and constants (gsplat's `MCMCStrategy` and the paper's
/// settings at 30k steps).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct McmcRecipe {
    /// Relocation and growth happen after this step, every `refine_every`, until
    /// `refine_until`.
    pub refine_from: u64,
    pub refine_until: u64,
    pub refine_every: u64,
    /// Splats at or below this opacity are dead: they are moved onto live ones.
    pub min_opacity: f32,
    /// Each refinement adds this fraction of the count, up to the budget.
    pub grow_fraction: f32,
    /// Position noise per unit of position learning rate (0: none).
    pub noise_lr: f32,
    /// Opacity of the splats made from the capture's points.
    pub init_opacity: f32,
    /// Their scale, as a fraction of 3DGS's (the distance to the nearest points).
    pub init_scale: f32,
}

impl McmcRecipe {
    /// The 30k-step schedule scaled to `iters`, as [`Recipe::for_iters`] scales 3DGS's.
    pub fn for_iters(iters: u64) -> McmcRecipe {
        let f = iters as f64 / 30_000.0;
        let scale = |v: f64, lo: u64, hi: u64| ((v * f).round() as u64).clamp(lo, hi);
        let refine_every = scale(100.0, 25, 100);
        McmcRecipe {
            refine_from: scale(500.0, 2 * refine_every, 500),
            refine_until: iters * 5 / 6,
            refine_every,
            min_opacity: 0.005,
            grow_fraction: 0.05,
            noise_lr: 5e5,
            init_opacity: 0.5,
            init_scale: 0.1,
        }
    }
}

/// How splats are added and removed.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Strategy {
    /// 3DGS's clone, split and prune, with [`TrainConfig::recipe`]'s schedule (and every
    /// config written before there was a choice).
    #[default]
    Adaptive,
    Mcmc(McmcRecipe),
}

/// The penalties' weight MCMC trains with (the paper's, for opacity and scale alike).
pub const MCMC_REG: f32 = 0.01;

/// A stronger opacity penalty at the start of a run, falling linearly to the run's own weight.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct RegStart {
    /// The weight at step 0.
    pub weight: f32,
    /// The step from which the run's own weight holds.
    pub until: u64,
}

/// MCMC's start from random points: twenty times the paper's opacity penalty, falling to it
/// over the first thousand steps. Random points leave floaters between the cameras and the
/// object that the views' backgrounds hide; the paper's weight fades them over tens of
/// thousands of steps, this one within the first thousand, after which the paper's weight
/// keeps the semi-transparent splats fine detail needs. The length is in steps, not a share
/// of the run: how fast a floater fades is set by the opacity learning rate.
pub const MCMC_REG_START: RegStart = RegStart {
    weight: 20.0 * MCMC_REG,
    until: 1000,
};

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TrainConfig {
    pub mode: Mode,
    pub iters: u64,
    /// Weight of `L(render, I_ac)` in `aware` mode ([`PAPER_LAMBDA`] for LLFF in the paper).
    pub lambda: f32,
    /// Most splats densification may create; pruning keeps the count lower where it can.
    pub max_splats: usize,
    pub max_sh_degree: u32,
    pub seed: u64,
    pub background: [f32; 3],
    /// Held-out evaluation every this many steps (0: only at the end).
    pub eval_every: u64,
    /// Checkpoint every this many steps (0: never).
    pub checkpoint_every: u64,
    pub recipe: Recipe,
    /// Where `I_ac` comes from ([`IacSource::identity`]); None in `plain`.
    #[serde(default)]
    pub i_ac: Option<String>,
    /// The splat scene the run started from (`--init`); None: the capture's points.
    #[serde(default)]
    pub init: Option<String>,
    /// Weight of the mean-opacity penalty (0: none).
    #[serde(default)]
    pub opacity_reg: f32,
    /// A stronger start of the opacity penalty (MCMC from random points, unless
    /// `--opacity-reg` is given); None: the weight holds from step 0.
    #[serde(default)]
    pub opacity_reg_start: Option<RegStart>,
    /// Weight of the mean-scale penalty (0: none).
    #[serde(default)]
    pub scale_reg: f32,
    #[serde(default)]
    pub strategy: Strategy,
    /// When set, λ falls linearly from `lambda` (from step `lambda_hold_until`) to zero at
    /// this step and stays there: with a Wiener stand-in as `I_ac`, whose errors a long run
    /// learns (RESULTS.md, all-around section).
    #[serde(default)]
    pub lambda_fade_until: Option<u64>,
    /// With a fade, λ holds its value until this step and falls from there.
    #[serde(default)]
    pub lambda_hold_until: u64,
    /// What the run trains on ([`capture_fingerprint`]), so that `--resume` on another
    /// capture is refused; None in checkpoints older than the field.
    #[serde(default)]
    pub capture: Option<String>,
    /// Steps after which the splats are kept as they are then (`--save-at`), ascending.
    #[serde(default)]
    pub save_at: Vec<u64>,
    /// The PSF grid learnt with the splats (`--refine-psf`, aware mode).
    #[serde(default)]
    pub refine_psf: Option<PsfRefineConfig>,
    /// The length every schedule was made for, when the run was extended past it
    /// (`--resume --iters N`): densification, λ, SH bands and the PSF keep their steps, and
    /// the position learning rate holds its final value beyond it. None: [`Self::iters`].
    #[serde(default)]
    pub schedule_iters: Option<u64>,
    /// Every training step renders on a colour of its own ([`random_background`]);
    /// [`Self::background`] is then only the renders' and the evaluation's.
    #[serde(default)]
    pub random_background: bool,
    /// What the capture's masks mean (None: it has none).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub masks: Option<MaskUse>,
    /// `--iters auto`: the rule that ends the run once training stops paying; [`Self::iters`]
    /// is then only the most it may run, and [`Self::schedule_iters`] the length its
    /// schedules were made for.
    #[serde(default)]
    pub stop: Option<StopRule>,
    /// `--coarse-to-fine`: the first steps at smaller resolutions; None: every step at full
    /// size (absent from the configs of runs without it, so their fingerprints stay).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub coarse: Option<Coarse>,
    /// What the run decided for its capture and why ([`crate::train::decisions::explain`]):
    /// a record, not a setting (a resume compares everything else).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub decisions: Vec<Decision>,
}

/// One decision of a run.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Decision {
    /// The setting decided, as its flag names it without the dashes (`strategy`,
    /// `background`, …), or what the capture brings (`i_ac`, `undistortion`, `scored`).
    pub setting: String,
    /// What it is, briefly.
    pub value: String,
    /// The decision and its reason, as the sentence `train` prints.
    pub why: String,
}

impl std::fmt::Display for Decision {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.why)
    }
}

/// Steps per training view the schedules of an `--iters auto` run are made for: 150 (how
/// often 3DGS's schedules see each view at 30k steps on a capture of 200), 200 in restored
/// mode. Restored fits the sharp `I_ac` alone and needs the longer densification: on fern
/// `images_8` it ended 0.31 dB below its 7000-step run with 150 and 0.18 with 200, while
/// aware ended above its 7000-step run with either and takes 18 % more time with 200
/// (RESULTS.md, issue 52).
pub fn auto_steps_per_view(mode: Mode) -> u64 {
    match mode {
        Mode::Restored => 200,
        Mode::Aware | Mode::Plain => 150,
    }
}

/// Steps the schedules of an `--iters auto` run are made for: [`auto_steps_per_view`] per
/// training view, from 1000 to 7000.
pub fn auto_horizon(views: usize, mode: Mode) -> u64 {
    (auto_steps_per_view(mode) * views as u64).clamp(1000, 7000)
}

/// How far past its horizon an `--iters auto` run may go while it still pays (the position
/// learning rate holds its final value there).
pub const AUTO_CAP_FACTOR: u64 = 3;

/// The background of training step `step` under `--background random`: uniform in the RGB
/// cube, a function of the seed and the step alone, so that a resumed run draws what the
/// uninterrupted one drew.
pub fn random_background(seed: u64, step: u64) -> [f32; 3] {
    let mut rng = base::rng::SplitMix64::new(base::rng::mix64(seed ^ 0x6267) ^ step);
    [0; 3].map(|_| rng.next_f64() as f32)
}

/// The capture a run trains on, in a sentence ending in a hash of its cameras (names, sizes,
/// intrinsics, poses), its split and its PSF grid: equal for the same capture, different
/// as soon as any of them differs.
pub fn capture_fingerprint(data: &Dataset) -> String {
    capture_fingerprint_with(data, base::hash::tagged)
}

/// Rewrites what a checkpoint written before XXH3 recorded in FNV-1a (the capture's
/// fingerprint, the restorer's weights) as this version writes it, when it names the same
/// capture and weights: such a run resumes instead of being refused for a hash it cannot
/// have known.
pub fn upgrade_fingerprints(recorded: &mut TrainConfig, data: &Dataset) {
    if recorded.capture.as_deref() == Some(legacy_capture_fingerprint(data).as_str()) {
        recorded.capture = Some(capture_fingerprint(data));
    }
    if let (Some(was), Some(source)) = (&recorded.i_ac, &data.restorer)
        && source.was_recorded_as(was)
    {
        recorded.i_ac = Some(source.identity());
    }
}

/// [`capture_fingerprint`] as runs made before XXH3 wrote it (FNV-1a).
pub fn legacy_capture_fingerprint(data: &Dataset) -> String {
    capture_fingerprint_with(data, |bytes| format!("{:016x}", base::hash::fnv1a64(bytes)))
}

fn capture_fingerprint_with(data: &Dataset, hash: impl Fn(&[u8]) -> String) -> String {
    let c = &data.capture;
    let mut bytes = Vec::new();
    for camera in &c.cameras {
        bytes.extend((camera.name.len() as u64).to_le_bytes());
        bytes.extend(camera.name.as_bytes());
        bytes.extend(camera.width.to_le_bytes());
        bytes.extend(camera.height.to_le_bytes());
        let pose = camera.world_to_camera.to_mat4().to_cols_array();
        for v in [camera.fx, camera.fy, camera.cx, camera.cy]
            .iter()
            .chain(&pose)
        {
            bytes.extend(v.to_le_bytes());
        }
    }
    // Undistorted photos are other pixels than the photos as taken (a pinhole capture keeps
    // the fingerprint it had before undistortion existed).
    if c.undistorted() {
        bytes.extend(b"undistorted at load");
    }
    for i in c.split.train.iter().chain(&c.split.test) {
        bytes.extend((*i as u64).to_le_bytes());
    }
    if let Some(model) = &data.imaging {
        let psf = model.psf();
        bytes.extend(
            [psf.grid() as u64, psf.size() as u64]
                .map(u64::to_le_bytes)
                .concat(),
        );
        bytes.extend(psf.planar().iter().flat_map(|v| v.to_le_bytes()));
    }
    format!(
        "{} views of {}x{}{}, fingerprint {}",
        c.len(),
        data.width,
        data.height,
        if data.imaging.is_some() {
            " with a PSF grid"
        } else {
            ""
        },
        hash(&bytes)
    )
}

/// With the Wiener stand-in as `I_ac`, λ holds for this many steps before it fades (to zero by
/// the end of densification): early on the stand-in speeds the fit up, later the model would
/// learn its ringing. Measured on two scenes at four lengths (RESULTS.md, all-around section).
pub const STAND_IN_HOLD: u64 = 1000;

/// Steps after an opacity reset before transparency is grounds for pruning. Recovering from
/// the reset takes a number of Adam steps set by the opacity learning rate, not by the run's
/// length: 3DGS leaves one densification interval of 100 steps, and a schedule scaled to a
/// short run left a quarter of that, so the next prune removed most of the model.
pub const RESET_RECOVERY: u64 = 100;

/// The paper's weight of `L(render, I_ac)` for LLFF scenes with its trained restorer.
pub const PAPER_LAMBDA: f32 = 0.75;

/// λ with the Wiener stand-in as `I_ac`: it is worse than the aberrated input at low
/// resolution and a large λ fits its errors (the demo-scene sweep is in RESULTS.md).
pub const STAND_IN_LAMBDA: f32 = 0.25;

/// λ when the user gives none, for the run's source of `I_ac`: every λ default is here.
pub fn default_lambda(source: Option<&IacSource>) -> f32 {
    match source {
        Some(IacSource::Wiener) => STAND_IN_LAMBDA,
        Some(IacSource::Network { .. }) | None => PAPER_LAMBDA,
    }
}

/// Default budget: one splat per two pixels of a view (≈ 95k at 504×378), the order of
/// what 3DGS keeps for LLFF scenes at that size, and twice that when the cameras surround the
/// scene: a forward-facing capture sees one side of its surfaces, one taken all around sees
/// them from every side (the budget experiment in RESULTS.md measured both).
pub fn default_max_splats(width: u32, height: u32, surrounds: bool) -> usize {
    let per_view = ((width as usize * height as usize) / 2).max(1000);
    if surrounds { 2 * per_view } else { per_view }
}

/// The background `--background auto` gives: for a capture whose cameras surround the scene,
/// the per-channel median of the training photos' outermost pixels (an object photographed
/// all around sits on a backdrop that fills the borders, and rendering empty space in its
/// colour spares the model from painting it with splats that float in front of the object
/// from other sides); black for a forward-facing capture, whose views the scene fills.
pub fn auto_background(data: &Dataset) -> [f32; 3] {
    if !data.capture.surrounds_scene() || data.train.is_empty() {
        return [0.0; 3];
    }
    let (w, h) = (data.width as usize, data.height as usize);
    let mut channels: [Vec<f32>; 3] = Default::default();
    for v in &data.train {
        let border = (0..w)
            .flat_map(|x| [x, (h - 1) * w + x])
            .chain((1..h.saturating_sub(1)).flat_map(|y| [y * w, y * w + w - 1]));
        for i in border {
            if let Some(p) = v.observed.get(i) {
                for (c, ch) in channels.iter_mut().enumerate() {
                    ch.push(p[c]);
                }
            }
        }
    }
    channels.map(|mut ch| {
        if ch.is_empty() {
            return 0.0;
        }
        let mid = ch.len() / 2;
        let (_, m, _) = ch.select_nth_unstable_by(mid, f32::total_cmp);
        m.clamp(0.0, 1.0)
    })
}

/// Whether a capture has an object's masks (a folder of them or `transforms.json`'s
/// `mask_path`), not only the border undistortion leaves without a source or the photos'
/// alpha, which leave pixels out of the loss as they always did.
pub fn has_object_masks(data: &Dataset) -> bool {
    data.capture.has_own_masks()
        && !data.masks_from_undistortion
        && data.train.iter().any(|v| v.mask.is_some())
}

/// What an object's masks mean for a run with `choice` on `data`: `object` unless the user
/// asks for `loss` (measured on the turntable capture, RESULTS.md); None without object
/// masks (other masks leave pixels out of the loss, and the run is scored on whole images).
pub fn mask_use(choice: MaskChoice, data: &Dataset) -> Option<MaskUse> {
    if !has_object_masks(data) {
        return None;
    }
    Some(match choice {
        MaskChoice::Loss => MaskUse::Loss,
        MaskChoice::Object | MaskChoice::Auto => MaskUse::Object,
    })
}

/// The colour behind an object run's splats when the user names none: the one a `scene
/// aberrate` copy was composited over (its photos then need no change), else black.
pub fn object_background(data: &Dataset) -> [f32; 3] {
    data.composited_over.unwrap_or([0.0; 3])
}

impl TrainConfig {
    /// λ at `step`.
    pub fn lambda_at(&self, step: u64) -> f32 {
        let Some(end) = self.lambda_fade_until else {
            return self.lambda;
        };
        let from = self.lambda_hold_until.min(end);
        if step <= from {
            self.lambda
        } else if end > from {
            self.lambda * (1.0 - (step - from) as f32 / (end - from) as f32).max(0.0)
        } else {
            0.0
        }
    }

    /// The opacity penalty's weight at `step`: [`TrainConfig::opacity_reg`], after a start
    /// that falls linearly from a stronger weight when [`TrainConfig::opacity_reg_start`] says
    /// so.
    pub fn opacity_reg_at(&self, step: u64) -> f32 {
        match self.opacity_reg_start {
            Some(RegStart { weight, until }) if step < until => {
                weight + (self.opacity_reg - weight) * step as f32 / until as f32
            }
            _ => self.opacity_reg,
        }
    }

    /// How much the splats' own penalties (opacity, scale) weigh at `step` against the
    /// photometric loss, as multiples of their configured weights: `1 + λ` in aware mode,
    /// whose loss sums a term of weight 1 and one of weight λ, else 1. Penalties weigh against
    /// the loss's total weight as they do against the single term of the other modes; at a
    /// weight of 1 MCMC's penalties were 1.75 times weaker in aware mode and it kept floaters
    /// restored mode removed (RESULTS.md, issue 49). Scaling the penalties rather than
    /// dividing the loss leaves the positional gradients adaptive densification thresholds
    /// as they were (a divided loss densified half as much on fern `images_4`).
    pub fn penalty_weight_at(&self, step: u64) -> f32 {
        match self.mode {
            Mode::Aware => 1.0 + self.lambda_at(step),
            Mode::Plain | Mode::Restored => 1.0,
        }
    }

    /// The config of a run with `settings` on `data`: the one place where defaults that depend
    /// on the capture (budget, λ for the capture's `I_ac`, evaluation and checkpoint cadence)
    /// are decided.
    pub fn build(settings: &TrainSettings, seed: u64, data: &Dataset) -> TrainConfig {
        Self::build_with_horizon(settings, seed, data, None)
    }

    /// [`Self::build`], with an `--iters auto` run's schedules made for `horizon` steps
    /// instead of [`auto_horizon`]'s: a run resumed as it was made by a version whose horizon
    /// differed.
    pub fn build_with_horizon(
        settings: &TrainSettings,
        seed: u64,
        data: &Dataset,
        horizon: Option<u64>,
    ) -> TrainConfig {
        // The length the schedules are made for, and the most the run may take.
        let (iters, cap) = match settings.iters {
            Iters::Steps(n) => (n, n),
            Iters::Auto => {
                let h = horizon.unwrap_or_else(|| auto_horizon(data.train.len(), settings.mode));
                (h, AUTO_CAP_FACTOR * h)
            }
        };
        let random_start = data.initial.is_none()
            && matches!(
                data.capture.point_source,
                scenes::PointSource::Random { .. }
            );
        let strategy = match settings.strategy {
            StrategyChoice::Adaptive => Strategy::Adaptive,
            StrategyChoice::Mcmc => Strategy::Mcmc(McmcRecipe::for_iters(iters)),
            StrategyChoice::Auto if random_start => Strategy::Mcmc(McmcRecipe::for_iters(iters)),
            StrategyChoice::Auto => Strategy::Adaptive,
        };
        let mcmc = matches!(strategy, Strategy::Mcmc(_));
        let reg_default = if mcmc { MCMC_REG } else { 0.0 };
        let recipe = Recipe {
            sh_min_gain: settings.sh_min_gain.unwrap_or_else(defaults::sh_min_gain),
            ..Recipe::for_iters(
                iters,
                match settings.opacity_reset {
                    Toggle::On => true,
                    Toggle::Off => false,
                    // MCMC moves transparent splats instead of resetting and pruning.
                    Toggle::Auto => !mcmc && data.capture.surrounds_scene(),
                },
            )
        };
        let masks = mask_use(settings.mask_mode, data);
        let stand_in = settings.mode == Mode::Aware
            && settings.lambda.is_none()
            && matches!(data.restorer, Some(IacSource::Wiener));
        let mut config = TrainConfig {
            mode: settings.mode,
            iters,
            lambda: settings
                .lambda
                .unwrap_or_else(|| default_lambda(data.restorer.as_ref())),
            max_splats: settings.max_splats.map_or_else(
                || default_max_splats(data.width, data.height, data.capture.surrounds_scene()),
                |m| m as usize,
            ),
            max_sh_degree: settings.max_sh_degree,
            seed,
            background: match (settings.background, masks) {
                (Background::Colour(c), _) => c,
                (_, Some(MaskUse::Object)) => object_background(data),
                (Background::Auto | Background::Random, _) => auto_background(data),
            },
            masks,
            random_background: settings.background == Background::Random,
            schedule_iters: None,
            eval_every: settings.eval_every.unwrap_or((iters / 10).max(1)),
            checkpoint_every: settings.checkpoint_every.unwrap_or((iters / 5).max(100)),
            i_ac: data.restorer.as_ref().map(|r| r.identity()),
            init: settings.init.as_ref().map(|p| p.display().to_string()),
            opacity_reg: settings.opacity_reg.unwrap_or(reg_default),
            opacity_reg_start: (mcmc && random_start && settings.opacity_reg.is_none())
                .then_some(MCMC_REG_START),
            scale_reg: settings.scale_reg.unwrap_or(reg_default),
            strategy,
            lambda_fade_until: match settings.lambda_fade {
                LambdaFade::Auto => stand_in.then_some(recipe.densify_until.max(STAND_IN_HOLD)),
                LambdaFade::Never => None,
                LambdaFade::End => Some(iters),
                LambdaFade::Step(n) => Some(n),
                LambdaFade::Range(_, b) => Some(b),
            },
            lambda_hold_until: match settings.lambda_fade {
                LambdaFade::Auto if stand_in => STAND_IN_HOLD,
                LambdaFade::Range(a, _) => a,
                _ => 0,
            },
            capture: Some(capture_fingerprint(data)),
            refine_psf: settings
                .refine_psf
                .filter(|_| settings.mode == Mode::Aware)
                .map(|m| PsfRefineConfig::for_iters(iters, m)),
            save_at: {
                let mut at = settings.save_at.clone();
                at.sort_unstable();
                at.dedup();
                at
            },
            coarse: Coarse::for_capture(
                settings.coarse_to_fine.levels_for(mcmc),
                settings
                    .coarse_to_fine
                    .steps()
                    .unwrap_or((iters / 10).max(1)),
                data.width,
                data.height,
            ),
            recipe,
            stop: None,
            decisions: Vec::new(),
        };
        if settings.iters == Iters::Auto {
            // No stop while splats are still added and removed, or while λ still falls.
            let densified = match &config.strategy {
                Strategy::Adaptive => config.recipe.densify_until,
                Strategy::Mcmc(m) => m.refine_until,
            };
            let not_before = densified
                .max(config.lambda_fade_until.unwrap_or(0))
                .max(config.coarse.as_ref().map_or(0, Coarse::end));
            config.stop = Some(StopRule::new(data.train.len(), not_before));
            config.schedule_iters = Some(iters);
            config.iters = cap;
        }
        config
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn auto_schedules_follow_the_views_and_give_restored_mode_longer() {
        // Fern `images_8`'s 17 training views, a capture of 3 and one of 60.
        assert_eq!(auto_horizon(17, Mode::Aware), 2550);
        assert_eq!(auto_horizon(17, Mode::Plain), 2550);
        assert_eq!(auto_horizon(17, Mode::Restored), 3400);
        for mode in Mode::ALL {
            assert_eq!(auto_horizon(3, mode), 1000, "{mode}");
            assert_eq!(auto_horizon(60, mode), 7000, "{mode}");
        }
    }
}
