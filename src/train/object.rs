//! What a capture's masks mean to a run: pixels outside that leave the loss (`loss`), or an
//! object alone on an empty background (`object`, a turntable capture: only the object agrees
//! with the poses, so everything outside it is learnt as empty and exported as nothing).
//!
//! In `object` mode each training target is the photo composited over the step's background
//! outside the mask, and the render, drawn over the same background, is compared with it on
//! every pixel. Through the lens the composite must be taken before the blur: for a copy that
//! `scene aberrate` composited over a colour `c₀` before blurring, the blur is linear and the
//! PSFs sum to one, so `PSF ⊛ (m·I + (1 − m)·c) = I_abr + (c − c₀)·(1 − PSF ⊛ m)` exactly; for
//! photos taken with the room behind, the object's halo and the room's mix near the mask's
//! edge, and the pixels where they mix (`|PSF ⊛ m − m|`) leave the loss.

use std::borrow::Cow;

use glam::Vec3;
use rayon::prelude::*;

use crate::error::Result;
use crate::settings::MaskUse;
use crate::train::config::TrainConfig;
use crate::train::data::{Dataset, View};

/// `image` over `background` where the mask leaves it out: `m·image + (1 − m)·background`.
pub fn over(image: &[Vec3], mask: &[f32], background: Vec3) -> Vec<Vec3> {
    image
        .iter()
        .zip(mask)
        .map(|(p, &m)| *p * m + background * (1.0 - m))
        .collect()
}

/// What the lens sees of a render on a copy composited over `background` outside its masks
/// before the blur (`scene aberrate`): [`over`] where both are known, else the render as is.
pub fn lens_input<'r>(
    render: &'r [Vec3],
    mask: Option<&[f32]>,
    background: Option<Vec3>,
) -> Cow<'r, [Vec3]> {
    match background.zip(mask) {
        Some((c, m)) => Cow::Owned(over(render, m, c)),
        None => Cow::Borrowed(render),
    }
}

/// How the training views of an `object` run become their targets.
#[derive(Clone, Debug, Default)]
pub struct ObjectTargets {
    /// Compare the re-blurred render with the photo (aware mode).
    pub through_lens: bool,
    /// The colour the photos were composited over before the blur (`scene aberrate` on a
    /// masked capture); None: photos taken as they are, the room behind the object.
    pub composited_over: Option<Vec3>,
    /// Through the lens: per training view, the background's share of each pixel after the
    /// blur, `PSF ⊛ (1 − m)` per colour, where the targets need it
    /// ([`Self::needs_spread`]). Made once, through the grid the run starts with (a refined
    /// grid moves it by a fraction of a pixel).
    pub spread: Vec<Option<Vec<Vec3>>>,
    /// `PSF ⊛ 1`: what the blur leaves of a constant image (less than 1 near the borders).
    pub blur_of_one: Vec<Vec3>,
}

impl ObjectTargets {
    /// The object targets of an `object` run: `PSF ⊛ (1 − mask)` per training view where the targets
    /// need it ([`Self::needs_spread`]); None for any other run.
    pub fn for_run(config: &TrainConfig, data: &Dataset) -> Result<Option<Self>> {
        Self::build(
            config,
            &data.train,
            data.imaging.as_ref(),
            data.composited_over,
        )
    }

    /// [`Self::for_run`] for any training views and the lens planned for their size (a
    /// coarse level's, [`crate::train::coarse`]).
    pub fn build(
        config: &TrainConfig,
        train: &[View],
        imaging: Option<&aberration::ImagingModel>,
        composited_over: Option<[f32; 3]>,
    ) -> Result<Option<Self>> {
        if config.masks != Some(MaskUse::Object) {
            return Ok(None);
        }
        let through_lens = config.mode == crate::settings::Mode::Aware;
        let composited_over = composited_over.map(Vec3::from_array);
        let fixed = (!config.random_background).then(|| Vec3::from_array(config.background));
        let (spread, blur_of_one) = match (
            Self::needs_spread(through_lens, composited_over, fixed),
            imaging,
        ) {
            (true, Some(imaging)) => {
                let spread = train
                    .par_iter()
                    .map(|v| {
                        v.mask
                            .as_deref()
                            .map(|m| {
                                let outside: Vec<Vec3> =
                                    m.iter().map(|&k| Vec3::splat(1.0 - k)).collect();
                                imaging.blur_pixels(&outside)
                            })
                            .transpose()
                    })
                    .collect::<std::result::Result<Vec<_>, _>>()?;
                let n = imaging.plan().width() * imaging.plan().height();
                (spread, imaging.blur_pixels(&vec![Vec3::ONE; n])?)
            }
            _ => (Vec::new(), Vec::new()),
        };
        Ok(Some(Self {
            through_lens,
            composited_over,
            spread,
            blur_of_one,
        }))
    }

    /// Whether training views' targets need [`Self::spread`] at the fixed background `fixed`
    /// (None: a random one each step).
    pub fn needs_spread(
        through_lens: bool,
        composited_over: Option<Vec3>,
        fixed: Option<Vec3>,
    ) -> bool {
        through_lens && (composited_over.is_none() || composited_over != fixed)
    }

    /// The view step training compares its render (drawn over `background`) with: targets
    /// composited over `background`, every pixel counting, except through the lens on photos
    /// taken with the room behind, where the pixels the blur mixes leave the loss. A view
    /// without a mask is returned as it is.
    pub fn view<'v>(&self, index: usize, view: &'v View, background: Vec3) -> Cow<'v, View> {
        let Some(m) = view.mask.as_deref() else {
            return Cow::Borrowed(view);
        };
        let spread = self.spread.get(index).and_then(Option::as_deref);
        let restored = view.restored.as_deref().map(|r| over(r, m, background));
        let (observed, weight) = match (self.through_lens, self.composited_over, spread) {
            (false, ..) => (over(&view.observed, m, background), None),
            (true, Some(c0), _) if c0 == background => (view.observed.clone(), None),
            // The blur is linear: the photo of the object over `background` is the photo
            // over `c0` plus the blurred difference of the backgrounds.
            (true, Some(c0), Some(b)) => (
                view.observed
                    .iter()
                    .zip(b)
                    .map(|(p, b)| *p + (background - c0) * *b)
                    .collect(),
                None,
            ),
            (true, None, Some(b)) => (
                view.observed
                    .iter()
                    .zip(m)
                    .zip(b)
                    .map(|((p, &m), b)| *p * m + background * *b)
                    .collect(),
                Some(
                    m.iter()
                        .zip(b)
                        .zip(&self.blur_of_one)
                        .map(|((&m, b), one)| {
                            // The object's share after the blur against before it.
                            let mixed = (*one - *b - Vec3::splat(m)).abs().element_sum() / 3.0;
                            (1.0 - mixed).clamp(0.0, 1.0)
                        })
                        .collect(),
                ),
            ),
            // Without the spread (not made for this view): the photo as it is inside the
            // mask, which is what `loss` mode compares.
            (true, _, None) => return Cow::Borrowed(view),
        };
        Cow::Owned(View {
            name: view.name.clone(),
            camera: view.camera.clone(),
            observed,
            restored,
            clean: None,
            mask: weight,
        })
    }
}

/// PSNR over the pixels a mask keeps (weighted by it), RGB; None when it keeps none.
pub fn psnr_in_mask(image: &[Vec3], reference: &[Vec3], mask: &[f32]) -> Option<f64> {
    let (mut err, mut weight) = (0.0f64, 0.0f64);
    for ((a, b), &m) in image.iter().zip(reference).zip(mask) {
        let d = (*a - *b).as_dvec3();
        err += m as f64 * d.length_squared();
        weight += 3.0 * m as f64;
    }
    if weight <= 0.0 {
        return None;
    }
    // The same floor as every other PSNR here (100 dB for identical pixels).
    Some(-10.0 * (err / weight).max(base::metrics::PSNR_MSE_FLOOR).log10())
}
