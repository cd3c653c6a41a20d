//! The whole forward imaging model for one image size: resolution mapping, blur, noise.

use crate::blur::{BlurMode, BlurPlan};
use crate::error::Result;
use crate::image::Image;
use crate::noise::NoiseModel;
use crate::psf_grid::PsfGrid;
use glam::Vec3;

/// `I_abr = PSF ⊛ I_c + n` for images of one size, planned once.
pub struct ImagingModel {
    psf: PsfGrid,
    plan: BlurPlan,
    pub noise: NoiseModel,
}

impl ImagingModel {
    /// `native` is the grid as simulated or loaded; it is mapped onto `width × height` by
    /// the rule of [`crate::resample`] (`sensor_px` overrides the native sensor size).
    pub fn new(
        native: &PsfGrid,
        width: usize,
        height: usize,
        mode: BlurMode,
        sensor_px: Option<usize>,
        noise: NoiseModel,
    ) -> Result<Self> {
        let psf = native.for_image(width, height, sensor_px)?;
        let plan = BlurPlan::new(&psf, width, height, mode)?;
        Ok(Self { psf, plan, noise })
    }

    /// The PSF grid at this image's scale.
    pub fn psf(&self) -> &PsfGrid {
        &self.psf
    }

    pub fn plan(&self) -> &BlurPlan {
        &self.plan
    }

    /// The same model (image size, blur mode, noise) through another grid at this image's
    /// scale.
    pub fn with_psf(&self, psf: PsfGrid) -> Result<Self> {
        self.planned(psf, 1)
    }

    /// The same lens on images `n` times smaller on each side (a remainder of fewer than `n`
    /// rows or columns dropped, as area shrinking does): the PSFs at this scale shrunk by the
    /// area rule, so that blurring a shrunk image approximates shrinking the blurred one
    /// (coarse-to-fine training's `L_abr` at its early resolutions). Noise is kept as it is.
    pub fn shrunk(&self, n: usize) -> Result<Self> {
        if n == 0 {
            return Err(crate::error::AberrationError::BadParameter(
                "a shrink factor of 0".into(),
            ));
        }
        self.planned(self.psf.resampled(1.0 / n as f64), n)
    }

    /// `psf` planned for this model's images `n` times smaller, in its blur mode and noise.
    fn planned(&self, psf: PsfGrid, n: usize) -> Result<Self> {
        let plan = BlurPlan::new(
            &psf,
            self.plan.width() / n,
            self.plan.height() / n,
            self.plan.mode(),
        )?;
        Ok(Self {
            psf,
            plan,
            noise: self.noise,
        })
    }

    /// Blurs through `psf` from now on (a grid at this image's scale, as [`Self::psf`]
    /// returns, e.g. one being refined during training).
    pub fn set_psf(&mut self, psf: PsfGrid) -> Result<()> {
        self.plan.set_psf(&psf)?;
        self.psf = psf;
        Ok(())
    }

    /// Blur only.
    pub fn blur(&self, clean: &Image) -> Result<Image> {
        self.plan.apply(clean)
    }

    /// Blur only, on row-major RGB pixels (the renderer's layout).
    pub fn blur_pixels(&self, clean: &[Vec3]) -> Result<Vec<Vec3>> {
        self.plan.apply_pixels(clean)
    }

    /// Blur, then seeded sensor noise, clipped to [0, 1].
    pub fn capture(&self, clean: &Image, seed: u64) -> Result<Image> {
        Ok(self.noise.apply(&self.blur(clean)?, seed))
    }
}
