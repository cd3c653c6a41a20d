//! Metalens phase profiles and the meta-atom dispersion model of Tseng et al. 2021.

use std::f64::consts::TAU;

/// The designed phase `φ(r)` over the aperture, before wrapping and dispersion.
#[derive(Clone, Debug, PartialEq)]
pub enum PhaseProfile {
    /// `φ(ρ) = Σ_i a_i ρ^(2i)`, `i = 1..`, `ρ = r / R` (radians).
    EvenPolynomial(Vec<f64>),
    /// The ideal focusing phase `−(2π/λ_d)(√(r² + f²) − f)` at a design wavelength (nm).
    Hyperbolic { design_nm: f64 },
}

impl PhaseProfile {
    /// The optimised ("neural nano-optics") coefficients published with Tseng et al. 2021,
    /// the lens the paper fabricated: a₂…a₁₆ = [−0.3494864, −0.00324192, −1 × 6] × 1000 rad.
    pub fn neural() -> Self {
        let mut a = vec![-0.3494864, -0.00324192];
        a.extend([-1.0; 6]);
        Self::EvenPolynomial(a.into_iter().map(|v| v * 1000.0).collect())
    }

    /// Designed phase at radius `r_um` for aperture radius `radius_um` and focal length.
    pub fn phase(&self, r_um: f64, radius_um: f64, focal_um: f64) -> f64 {
        match self {
            Self::EvenPolynomial(a) => {
                let rho2 = (r_um / radius_um).powi(2);
                // Horner in ρ²: Σ a_i ρ^(2i) = ρ²(a_1 + ρ²(a_2 + …)).
                a.iter().rev().fold(0.0, |acc, ai| (acc + ai) * rho2)
            }
            Self::Hyperbolic { design_nm } => {
                let k = TAU / (design_nm * 1e-3);
                -k * ((r_um * r_um + focal_um * focal_um).sqrt() - focal_um)
            }
        }
    }
}

/// How the designed phase becomes the phase a wavelength actually sees.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Dispersion {
    /// The designed phase is applied unchanged at every wavelength (an ideal,
    /// dispersion-free element; used for the Airy check).
    None,
    /// Tseng's meta-atom proxy: the wrapped phase picks a pillar duty cycle
    /// `d = −0.1484u² + 0.6809u + 0.2923` (`u = φ/2π`), whose phase at wavelength λ (nm) is
    /// `2π(6.051 − 0.02033λ + 2.26d + 1.371e-5λ² − 0.002947λd + 0.797d²)`.
    MetaAtom,
    /// The simpler model: the wrapped phase scaled by `λ_design / λ`.
    ScaledWrapped { design_nm: f64 },
}

/// Wraps a phase to [0, 2π).
pub fn wrap(phi: f64) -> f64 {
    phi.rem_euclid(TAU)
}

/// Pillar duty cycle for a wrapped phase fraction `u` in [0, 1).
pub fn meta_atom_duty(u: f64) -> f64 {
    -0.1484 * u * u + 0.6809 * u + 0.2923
}

/// Phase (rad) of a pillar of duty cycle `d` at wavelength `lambda_nm`.
pub fn meta_atom_phase(lambda_nm: f64, d: f64) -> f64 {
    let l = lambda_nm;
    TAU * (6.051 - 0.02033 * l + 2.26 * d + 1.371e-5 * l * l - 0.002947 * l * d + 0.797 * d * d)
}

impl Dispersion {
    pub fn phase_at(&self, designed: f64, lambda_nm: f64) -> f64 {
        match *self {
            Self::None => designed,
            Self::MetaAtom => meta_atom_phase(lambda_nm, meta_atom_duty(wrap(designed) / TAU)),
            Self::ScaledWrapped { design_nm } => wrap(designed) * design_nm / lambda_nm,
        }
    }
}

/// A rotationally symmetric metalens.
#[derive(Clone, Debug, PartialEq)]
pub struct Lens {
    pub aperture_um: f64,
    pub focal_um: f64,
    /// Meta-atom pitch: the sampling of the phase profile and of the propagation grid.
    pub pitch_um: f64,
    pub profile: PhaseProfile,
    pub dispersion: Dispersion,
}

impl Default for Lens {
    /// The lens of Tseng et al. 2021 used by the paper: 0.5 mm aperture, f = 1 mm, 350 nm
    /// pitch, the published optimised profile, meta-atom dispersion.
    fn default() -> Self {
        Self {
            aperture_um: 500.0,
            focal_um: 1000.0,
            pitch_um: 0.35,
            profile: PhaseProfile::neural(),
            dispersion: Dispersion::MetaAtom,
        }
    }
}

impl Lens {
    /// The same design scaled to focal length `scale · f` at the same aperture: the designed
    /// phase is scaled by `1 / scale` (a paraxial lens's phase is inversely proportional to
    /// its focal length; the hyperbolic profile follows `focal_um` itself). What a lens whose
    /// focal length came out a few percent off looks like.
    pub fn with_focal_scale(&self, scale: f64) -> Self {
        let mut lens = self.clone();
        lens.focal_um *= scale;
        if let PhaseProfile::EvenPolynomial(a) = &mut lens.profile {
            a.iter_mut().for_each(|v| *v /= scale);
        }
        lens
    }

    /// An ideal lens: hyperbolic at `design_nm`, no dispersion.
    pub fn ideal(aperture_um: f64, focal_um: f64, pitch_um: f64, design_nm: f64) -> Self {
        Self {
            aperture_um,
            focal_um,
            pitch_um,
            profile: PhaseProfile::Hyperbolic { design_nm },
            dispersion: Dispersion::None,
        }
    }

    /// Phase at radius `r_um` seen by wavelength `lambda_nm`.
    pub fn phase(&self, r_um: f64, lambda_nm: f64) -> f64 {
        let designed = self
            .profile
            .phase(r_um, self.aperture_um / 2.0, self.focal_um);
        self.dispersion.phase_at(designed, lambda_nm)
    }
}
