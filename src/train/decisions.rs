//! What a run decided for its capture, each decision with its reason: the defaults that
//! depend on the capture (strategy, background, coarse to fine, opacity resets, masks, λ,
//! the length of `--iters auto`) and what the capture itself brings (`I_ac`, undistortion,
//! what held-out views are scored against). [`explain`] states them once the config is
//! final; `train` prints them, `config.json` records them, and no caller derives them again.

use crate::settings::{Background, MaskChoice, MaskUse, StrategyChoice, Toggle, TrainSettings};
use crate::train::coarse::{Coarse, MIN_COARSE_SIDE};
use crate::train::config::{Decision, Mode, Strategy, TrainConfig};
use crate::train::data::Dataset;
use crate::train::eval::{Against, reference};

fn decision(setting: &str, value: impl ToString, why: impl Into<String>) -> Decision {
    Decision {
        setting: setting.to_string(),
        value: value.to_string(),
        why: why.into(),
    }
}

fn rgb([r, g, b]: [f32; 3]) -> String {
    format!("{r:.3},{g:.3},{b:.3}")
}

/// The decisions of `config` (final: built, and adjusted for a resumed run) for a run asked
/// for with `settings` on `data`, in the order `train` prints them.
pub fn explain(config: &TrainConfig, settings: &TrainSettings, data: &Dataset) -> Vec<Decision> {
    let mut out = Vec::new();
    if let Strategy::Mcmc(m) = &config.strategy {
        out.push(decision(
            "strategy",
            "mcmc",
            format!(
                "Densification as MCMC{}: transparent splats move onto opaque ones every {} steps, and the count grows {:.0} % at a time up to the budget.",
                if settings.strategy == StrategyChoice::Auto {
                    " (the capture has no SfM points, and training starts from random ones)"
                } else {
                    ""
                },
                m.refine_every,
                100.0 * m.grow_fraction
            ),
        ));
    }
    if let (Some(rule), Some(base)) = (&config.stop, config.schedule_iters) {
        let per_view = crate::train::config::auto_steps_per_view(config.mode);
        // A run resumed from an earlier version keeps the length it was made for.
        let made_for = if base == crate::train::config::auto_horizon(data.train.len(), config.mode)
        {
            format!(
                "{per_view} per training view in {} mode, 1000 to 7000",
                config.mode
            )
        } else {
            "the run's own, as it was made".to_string()
        };
        out.push(decision(
            "iters",
            format!("auto, at most {}", config.iters),
            format!(
                "--iters auto: schedules made for {base} steps ({made_for}); from step {} on, the run ends once the training views' PSNR trends up by less than {:.3} dB per {} steps (through the last {} windows, at {} window ends in a row), after a final phase of {} steps at the final position learning rate; at most {} steps.",
                rule.not_before,
                rule.min_gain_db,
                rule.window,
                crate::train::stop::SPAN,
                rule.patience,
                rule.final_steps,
                config.iters
            ),
        ));
    } else if let Some(base) = config.schedule_iters {
        out.push(decision(
            "iters",
            config.iters,
            format!(
                "The run is extended to {} steps; its schedules stay as made for {base} (densification, lambda, SH bands, PSF refinement), and the position learning rate holds its final value after step {base}.",
                config.iters
            ),
        ));
    }
    if config.random_background {
        out.push(decision(
            "background",
            "random",
            format!(
                "Background: a random colour every training step; renders and evaluation use {}.",
                rgb(config.background)
            ),
        ));
    } else if config.background.iter().any(|c| *c >= 5e-4) {
        out.push(decision(
            "background",
            rgb(config.background),
            format!(
                "Background {}{}.",
                rgb(config.background),
                if settings.background == Background::Auto
                    && config.masks == Some(MaskUse::Object)
                {
                    ": the colour the copy's photos were composited over outside their masks"
                } else if settings.background == Background::Auto {
                    ": the median colour of the photos' borders, as the cameras surround an object on its backdrop"
                } else {
                    ""
                }
            ),
        ));
    }
    let asked = settings
        .coarse_to_fine
        .levels_for(matches!(config.strategy, Strategy::Mcmc(_)));
    match &config.coarse {
        Some(c) => out.push(decision(
            "coarse_to_fine",
            c.levels.len(),
            c.describe(data.width, data.height),
        )),
        None if asked == 0 => {}
        None if Coarse::for_capture(asked, 1, data.width, data.height).is_none() => {
            out.push(decision(
                "coarse_to_fine",
                "off",
                format!(
                    "Coarse to fine left out: the {}x{} views leave no level of at least {MIN_COARSE_SIDE} px a side.",
                    data.width, data.height
                ),
            ))
        }
        None => out.push(decision(
            "coarse_to_fine",
            "off",
            "Full size throughout: the run resumed was made so.",
        )),
    }
    if let Some(every) = config.recipe.opacity_reset_every {
        out.push(decision(
            "opacity_reset",
            every,
            format!(
                "Opacities reset every {every} steps{}.",
                match settings.opacity_reset {
                    Toggle::Auto =>
                        ": the cameras surround the scene, and resets clear the floaters such captures grow",
                    _ => "",
                }
            ),
        ));
    }
    if let (Some(g), Some(path)) = (&data.initial, &settings.init) {
        out.push(decision(
            "init",
            path.display(),
            format!(
                "Starting from the {} splats (SH degree {}) of {}.",
                g.len(),
                g.sh_degree,
                path.display()
            ),
        ));
    }
    restorer(config, data, &mut out);
    if let (Some(remap), Some(d)) = (
        data.capture.remaps.iter().flatten().next(),
        data.capture.cameras.iter().find_map(|c| c.distortion),
    ) {
        out.push(decision(
            "undistortion",
            d,
            format!(
                "The photos are undistorted at load onto the pinhole camera of their intrinsics ({d}; {} border pixels of each have no source and leave the loss); --keep-distortion trains on them as taken.",
                remap.invalid_count()
            ),
        ));
    }
    masks(config, settings, data, &mut out);
    match reference(&data.test) {
        Some(Against::Photos) if data.imaging.is_some() => out.push(decision(
            "scored",
            "photos",
            "no clean images: held-out views are compared with their photos, which are aberrated, so the PSNR counts the blur too",
        )),
        Some(Against::Photos) => out.push(decision(
            "scored",
            "photos",
            "held-out views are compared with their photos (the 3DGS report)",
        )),
        Some(Against::Clean) => {}
        None => out.push(decision(
            "scored",
            "nothing",
            "no held-out views: training runs, but nothing is evaluated",
        )),
    }
    out
}

/// Where `I_ac` comes from, and what aware mode does with it: λ, its fade, PSF refinement.
fn restorer(config: &TrainConfig, data: &Dataset, out: &mut Vec<Decision>) {
    if let Some(note) = &data.restorer_note {
        out.push(decision("restorer", "note", note.clone()));
    }
    let Some(r) = &data.restorer else {
        return;
    };
    out.push(decision("i_ac", r.identity(), r.describe()));
    if config.mode != Mode::Aware {
        return;
    }
    let lambda = config.lambda;
    let hold = config
        .lambda_fade_until
        .map(|e| config.lambda_hold_until.min(e));
    let why = match (config.lambda_fade_until, hold) {
        (Some(_), Some(h)) if h >= config.iters => format!("lambda {lambda} for L(render, I_ac)"),
        (Some(end), Some(h)) if h == end => format!(
            "lambda {lambda} for L(render, I_ac) until step {h}, then 0 (the stand-in's ringing would be learnt)"
        ),
        (Some(end), Some(h)) if h > 0 => format!(
            "lambda {lambda} for L(render, I_ac), held until step {h} and falling to 0 by step {end} (the stand-in's ringing would be learnt)"
        ),
        (Some(end), _) => {
            format!("lambda {lambda} for L(render, I_ac), falling to 0 by step {end}")
        }
        (None, _) => format!("lambda {lambda} for L(render, I_ac)"),
    };
    out.push(decision("lambda", lambda, why));
    if let Some(r) = &config.refine_psf {
        out.push(decision(
            "refine_psf",
            r.from,
            format!(
                "The PSF grid is refined with the splats from step {} on, every {} steps (learning rate {}, pull towards the supplied grid {}, smoothness across cells {}).",
                r.from, r.every, r.lr, r.anchor, r.smooth
            ),
        ));
        if config.lambda == 0.0 {
            out.push(decision(
                "refine_psf",
                "lambda 0",
                "With lambda 0 nothing but the pull towards the supplied grid holds the PSF: the refined grid takes up what the splats cannot fit, and drifts from the true one the more views the capture has (RESULTS.md); keep lambda above 0 to refine.",
            ));
        }
    }
}

/// What the capture's masks mean to the run.
fn masks(config: &TrainConfig, settings: &TrainSettings, data: &Dataset, out: &mut Vec<Decision>) {
    let masked = data.train.iter().filter(|v| v.mask.is_some()).count();
    if masked == 0 {
        return;
    }
    let bg = rgb(config.background);
    let (value, why) = match config.masks {
        Some(MaskUse::Object) => (
            "object",
            format!(
                "Masks ({}): the object alone{}: {masked} of {} training views are composited over {} outside their masks, so everything outside the object is learnt as empty and the splats hold the object only; held-out views are scored on the object over {bg}, and inside the masks. --mask-mode loss leaves those pixels out of the loss instead.",
                data.capture.mask_source(),
                if settings.mask_mode == MaskChoice::Auto {
                    " (the default for object masks)"
                } else {
                    ""
                },
                data.train.len(),
                if config.random_background {
                    "each step's random background".to_string()
                } else {
                    format!("the background ({bg})")
                }
            ),
        ),
        Some(MaskUse::Loss) => (
            "loss",
            format!(
                "Masks ({}): {masked} of {} training views leave the pixels outside their masks out of the loss (--mask-mode loss); held-out views are scored on the object over the background, and inside the masks.",
                data.capture.mask_source(),
                data.train.len()
            ),
        ),
        None => (
            "pixels",
            format!(
                "masks: {masked} of {} training views leave pixels out of the loss (held-out views are scored on the pixels their masks keep)",
                data.train.len()
            ),
        ),
    };
    out.push(decision("mask_mode", value, why));
}
