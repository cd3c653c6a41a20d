//! The Gaussian scene, stored structure-of-arrays.
//!
//! Parameters are stored in the unconstrained form the optimiser works on (INRIA / gsplat
//! layout): log-scales, unnormalised rotation quaternions `(w, x, y, z)`, logit opacities and
//! SH coefficients. SH storage is coefficient-major with RGB innermost: Gaussian `i` owns
//! `sh_rest[i * rest_count .. (i + 1) * rest_count]`, entry `k` being the RGB weight of basis
//! function `k + 1` (basis order as in [`crate::sh`]).

use glam::Vec3;

use crate::error::SplatError;

/// Highest SH degree the crate supports (16 coefficients per channel).
pub const MAX_SH_DEGREE: u32 = 3;

/// Number of non-DC SH coefficients per channel for `degree`.
pub const fn sh_rest_count(degree: u32) -> usize {
    ((degree + 1) * (degree + 1) - 1) as usize
}

/// Bytes one splat of SH degree `degree` takes in memory as [`Gaussians`].
pub const fn splat_bytes(degree: u32) -> u64 {
    4 * (3 + 3 + 4 + 1 + 3 * (1 + sh_rest_count(degree) as u64))
}

/// The most memory a splat file may ask for once read: 4 GiB as [`Gaussians`] (17 M splats
/// of degree 3, 67 M of degree 0; scenes of a few million are usual).
pub const MAX_LOADED_BYTES: u64 = 4 << 30;

/// Refuses a splat count (from a header) whose splats would take more than
/// [`MAX_LOADED_BYTES`], before anything is reserved for them.
pub fn check_splat_count(n: u64, degree: u32) -> Result<(), String> {
    let per = splat_bytes(degree.min(MAX_SH_DEGREE));
    if n.saturating_mul(per) > MAX_LOADED_BYTES {
        return Err(format!(
            "{n} splats of SH degree {degree} declared: {} GiB once read, more than the {} GiB a splat file may take",
            n.saturating_mul(per) >> 30,
            MAX_LOADED_BYTES >> 30
        ));
    }
    Ok(())
}

#[derive(Clone, Debug, Default, PartialEq)]
pub struct Gaussians {
    pub means: Vec<Vec3>,
    pub log_scales: Vec<Vec3>,
    /// `(w, x, y, z)`, any non-zero length; normalised on use.
    pub rotations: Vec<[f32; 4]>,
    pub logit_opacities: Vec<f32>,
    pub sh_dc: Vec<Vec3>,
    /// `len() * sh_rest_count(sh_degree)` entries, see the module docs.
    pub sh_rest: Vec<Vec3>,
    /// Degree of the stored SH coefficients; the rendered degree is a render setting `<=` this.
    pub sh_degree: u32,
}

impl Gaussians {
    pub fn new(sh_degree: u32) -> Self {
        Self {
            sh_degree: sh_degree.min(MAX_SH_DEGREE),
            ..Default::default()
        }
    }

    /// `n` Gaussians with every parameter zero (used for gradients and optimiser moments).
    pub fn zeros(n: usize, sh_degree: u32) -> Self {
        Self {
            means: vec![Vec3::ZERO; n],
            log_scales: vec![Vec3::ZERO; n],
            rotations: vec![[0.0; 4]; n],
            logit_opacities: vec![0.0; n],
            sh_dc: vec![Vec3::ZERO; n],
            sh_rest: vec![Vec3::ZERO; n * sh_rest_count(sh_degree)],
            sh_degree,
        }
    }

    /// Room for `n` more splats in every parameter, reserved exactly (readers call it once
    /// a count is proven by the data, so nothing grows by doubling from an untrusted count).
    pub fn reserve_exact(&mut self, n: usize) {
        let rc = self.rest_count();
        self.means.reserve_exact(n);
        self.log_scales.reserve_exact(n);
        self.rotations.reserve_exact(n);
        self.logit_opacities.reserve_exact(n);
        self.sh_dc.reserve_exact(n);
        self.sh_rest.reserve_exact(n * rc);
    }

    pub fn len(&self) -> usize {
        self.means.len()
    }

    pub fn is_empty(&self) -> bool {
        self.means.is_empty()
    }

    pub fn rest_count(&self) -> usize {
        sh_rest_count(self.sh_degree)
    }

    pub fn sh_rest_of(&self, i: usize) -> &[Vec3] {
        let r = self.rest_count();
        &self.sh_rest[i * r..(i + 1) * r]
    }

    /// Appends one Gaussian; `sh_rest` must hold `rest_count()` entries.
    #[allow(clippy::too_many_arguments)]
    pub fn push(
        &mut self,
        mean: Vec3,
        log_scale: Vec3,
        rotation: [f32; 4],
        logit_opacity: f32,
        sh_dc: Vec3,
        sh_rest: &[Vec3],
    ) {
        assert_eq!(sh_rest.len(), self.rest_count(), "sh_rest length");
        self.means.push(mean);
        self.log_scales.push(log_scale);
        self.rotations.push(rotation);
        self.logit_opacities.push(logit_opacity);
        self.sh_dc.push(sh_dc);
        self.sh_rest.extend_from_slice(sh_rest);
    }

    /// Appends Gaussian `i` of `src` (same SH degree).
    pub fn push_from(&mut self, src: &Gaussians, i: usize) {
        self.push(
            src.means[i],
            src.log_scales[i],
            src.rotations[i],
            src.logit_opacities[i],
            src.sh_dc[i],
            src.sh_rest_of(i),
        );
    }

    /// New model holding `indices` of `self`, in that order (indices may repeat).
    pub fn gather(&self, indices: &[usize]) -> Gaussians {
        let mut out = Gaussians::new(self.sh_degree);
        for &i in indices {
            out.push_from(self, i);
        }
        out
    }

    /// Changes the stored SH degree: new bands start at zero (rendering is unchanged), dropped
    /// bands are discarded. Lets a trainer store only the bands a scene uses.
    pub fn set_sh_degree(&mut self, degree: u32) {
        let degree = degree.min(MAX_SH_DEGREE);
        let (old, new) = (self.rest_count(), sh_rest_count(degree));
        if old != new {
            let mut rest = Vec::with_capacity(self.len() * new);
            for i in 0..self.len() {
                let src = &self.sh_rest[i * old..(i + 1) * old];
                rest.extend_from_slice(&src[..old.min(new)]);
                rest.extend(std::iter::repeat_n(Vec3::ZERO, new.saturating_sub(old)));
            }
            self.sh_rest = rest;
        }
        self.sh_degree = degree;
    }

    /// Bytes held by the parameters (what a trainer reports as model memory).
    pub fn param_bytes(&self) -> usize {
        self.len() * (3 + 3 + 4 + 1 + 3 + 3 * self.rest_count()) * std::mem::size_of::<f32>()
    }

    /// Every parameter is finite, logit opacities excepted (±∞ is a fully opaque or
    /// transparent splat, which formats storing the opacity itself can represent).
    pub fn finite_except_opacity(&self) -> bool {
        self.means
            .iter()
            .chain(&self.log_scales)
            .chain(&self.sh_dc)
            .chain(&self.sh_rest)
            .all(|v| v.is_finite())
            && self.rotations.iter().flatten().all(|v| v.is_finite())
    }

    /// Every parameter is finite.
    pub fn is_finite(&self) -> bool {
        self.finite_except_opacity() && self.logit_opacities.iter().all(|v| v.is_finite())
    }

    /// The parameters Gaussian by Gaussian: mean, log-scale, quaternion, logit opacity,
    /// SH DC, SH rest (coefficient-major, RGB innermost); `14 + 3 · rest_count` per Gaussian.
    pub fn packed(&self) -> Vec<f32> {
        let mut out = Vec::with_capacity(self.len() * (14 + 3 * self.rest_count()));
        for i in 0..self.len() {
            out.extend(self.means[i].to_array());
            out.extend(self.log_scales[i].to_array());
            out.extend(self.rotations[i]);
            out.push(self.logit_opacities[i]);
            out.extend(self.sh_dc[i].to_array());
            for c in self.sh_rest_of(i) {
                out.extend(c.to_array());
            }
        }
        out
    }

    /// The inverse of [`Gaussians::packed`]: `data` holds whole Gaussians of `sh_degree`.
    pub fn from_packed(data: &[f32], sh_degree: u32) -> Result<Self, SplatError> {
        let rc = sh_rest_count(sh_degree.min(MAX_SH_DEGREE));
        let stride = 14 + 3 * rc;
        if !data.len().is_multiple_of(stride) {
            return Err(SplatError::InvalidInput(format!(
                "{} packed values are not whole Gaussians of {stride}",
                data.len()
            )));
        }
        let n = data.len() / stride;
        let v3 = |s: &[f32]| Vec3::new(s[0], s[1], s[2]);
        let mut g = Gaussians::zeros(0, sh_degree.min(MAX_SH_DEGREE));
        g.means.reserve(n);
        g.sh_rest.reserve(n * rc);
        for p in data.chunks_exact(stride) {
            g.means.push(v3(&p[0..3]));
            g.log_scales.push(v3(&p[3..6]));
            g.rotations.push([p[6], p[7], p[8], p[9]]);
            g.logit_opacities.push(p[10]);
            g.sh_dc.push(v3(&p[11..14]));
            g.sh_rest.extend(p[14..].chunks_exact(3).map(v3));
        }
        Ok(g)
    }

    /// Checks the values a file gave, as the PLY reader does vertex by vertex: every value
    /// finite, and no log scale past [`MAX_LOG_SCALE`] (its scale would overflow). The
    /// problem in words, naming the first splat.
    pub fn check_values(&self) -> Result<(), String> {
        if let Some(i) = (0..self.len()).find(|&i| {
            !(self.means[i].is_finite()
                && self.log_scales[i].is_finite()
                && self.rotations[i].iter().all(|r| r.is_finite())
                && self.logit_opacities[i].is_finite()
                && self.sh_dc[i].is_finite()
                && self.sh_rest_of(i).iter().all(|r| r.is_finite()))
        }) {
            return Err(format!("splat {i} has a value that is not finite"));
        }
        if let Some(i) = (0..self.len()).find(|&i| self.log_scales[i].max_element() > MAX_LOG_SCALE)
        {
            return Err(format!(
                "splat {i} has log scale {}: its scale overflows (at most {MAX_LOG_SCALE})",
                self.log_scales[i].max_element()
            ));
        }
        Ok(())
    }

    /// Checks that all arrays agree in length (fields are public, so this can be violated).
    pub fn validate(&self) -> Result<(), SplatError> {
        let n = self.len();
        let check = |what: &'static str, got: usize, expected: usize| {
            if got == expected {
                Ok(())
            } else {
                Err(SplatError::SizeMismatch {
                    what,
                    expected,
                    got,
                })
            }
        };
        if self.sh_degree > MAX_SH_DEGREE {
            return Err(SplatError::InvalidModel(format!(
                "sh_degree {} exceeds {MAX_SH_DEGREE}",
                self.sh_degree
            )));
        }
        check("log_scales", self.log_scales.len(), n)?;
        check("rotations", self.rotations.len(), n)?;
        check("logit_opacities", self.logit_opacities.len(), n)?;
        check("sh_dc", self.sh_dc.len(), n)?;
        check("sh_rest", self.sh_rest.len(), n * self.rest_count())?;
        Ok(())
    }
}

/// Largest log scale read from a file: e^80 is far beyond any scene and still finite in f32
/// (e^89 is not).
pub const MAX_LOG_SCALE: f32 = 80.0;

/// Logistic function, written so neither branch overflows for large |x|.
#[inline]
pub fn sigmoid(x: f32) -> f32 {
    if x >= 0.0 {
        1.0 / (1.0 + (-x).exp())
    } else {
        let e = x.exp();
        e / (1.0 + e)
    }
}

/// Inverse of [`sigmoid`], clamped so `p` of 0 or 1 stays finite.
pub fn logit(p: f32) -> f32 {
    let p = p.clamp(1e-7, 1.0 - 1e-7);
    (p / (1.0 - p)).ln()
}
