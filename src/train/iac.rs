//! Where `I_ac` comes from: the user's choice ([`RestorerChoice`]) resolved for a capture's
//! PSF grid and scale into a source ([`IacSource`]): the MAFG + STAF network (`restore`) or the
//! Wiener stand-in.

use aberration::PsfGrid;

use crate::error::Result;
use crate::settings::RestorerChoice;

/// Where a run's `I_ac` comes from.
#[derive(Clone, Debug, PartialEq)]
pub enum IacSource {
    /// The Wiener filter with `metasplat deconvolve`'s default constant (no trained weights
    /// for this PSF grid). It replaced the median of the MAFG bank, which at low resolution is
    /// worse than the aberrated input and whose ringing long runs learned (RESULTS.md).
    Wiener,
    /// The MAFG + STAF transformer: its config name, where its weights came from, and a
    /// fingerprint of the weights file (`legacy_weights`: the FNV-1a hex that runs made
    /// before XXH3 recorded).
    Network {
        config: String,
        source: String,
        weights: String,
        legacy_weights: String,
    },
}

impl IacSource {
    pub fn describe(&self) -> String {
        match self {
            IacSource::Wiener => {
                "I_ac = Wiener image, K = 1e-2 (stand-in: no trained restorer fits this PSF grid and scale)"
                    .into()
            }
            IacSource::Network { config, source, .. } => {
                format!("I_ac = MAFG + STAF restorer, config '{config}', weights {source}")
            }
        }
    }

    /// What makes `I_ac` what it is, independent of where the weights file lies: a resumed
    /// run must get its `I_ac` from the same source.
    pub fn identity(&self) -> String {
        match self {
            IacSource::Wiener => "Wiener K=1e-2".into(),
            IacSource::Network {
                config, weights, ..
            } => format!("{config} network, weights {weights}"),
        }
    }

    /// [`Self::identity`] as runs made before XXH3 wrote it (the weights' FNV-1a).
    pub fn legacy_identity(&self) -> String {
        match self {
            IacSource::Wiener => self.identity(),
            IacSource::Network {
                config,
                legacy_weights,
                ..
            } => format!("{config} network, weights fnv1a {legacy_weights}"),
        }
    }

    /// Whether `recorded` is this source's [`Self::identity`], or what a run made before
    /// XXH3 recorded for it.
    pub fn was_recorded_as(&self, recorded: &str) -> bool {
        recorded == self.identity() || recorded == self.legacy_identity()
    }
}

/// A loaded network and where its weights came from.
pub(crate) type OpenedRestorer = (restore::Restorer, String);

/// Resolves a restorer choice for the capture's PSF grid (`native`, as simulated) whose PSFs
/// are `psf_px` wide at the capture's size. Also returns a note: with `auto`, which network
/// serves and why, or why none does and the Wiener image stands in; with given weights, a
/// warning when they never saw this blur scale.
pub(crate) fn open_restorer(
    choice: &RestorerChoice,
    native: &PsfGrid,
    psf_px: usize,
) -> Result<(Option<OpenedRestorer>, Option<String>)> {
    Ok(match choice {
        RestorerChoice::Wiener => (None, None),
        RestorerChoice::Auto => match restore::shipped::for_capture(native, Some(psf_px))? {
            restore::shipped::Choice::Network(r, why, name) => (
                Some((*r, name.to_string())),
                Some(format!("--restorer auto: using {why}")),
            ),
            restore::shipped::Choice::Declined(why) => (
                None,
                Some(format!(
                    "--restorer auto: {why}; using the Wiener image instead"
                )),
            ),
        },
        RestorerChoice::Weights(p) => {
            let r = restore::Restorer::load(p, native)?;
            let note = (!r.header.fits_psf_px(psf_px)).then(|| {
                let [lo, hi] = r.header.trained_psf_px.unwrap_or([0, 0]);
                format!(
                    "warning: {} was trained on {lo}-{hi} px PSFs; this capture's are {psf_px} px",
                    p.display()
                )
            });
            (Some((r, p.display().to_string())), note)
        }
    })
}

#[cfg(test)]
mod tests {
    use super::IacSource;

    #[test]
    fn a_source_knows_what_runs_before_xxh3_recorded_for_it() {
        let net = IacSource::Network {
            config: "tiny".into(),
            source: "shipped".into(),
            weights: "xxh3:00000000000000aa".into(),
            legacy_weights: "00000000000000bb".into(),
        };
        assert!(net.was_recorded_as("tiny network, weights xxh3:00000000000000aa"));
        assert!(net.was_recorded_as("tiny network, weights fnv1a 00000000000000bb"));
        assert!(!net.was_recorded_as("tiny network, weights fnv1a 00000000000000cc"));
        assert!(!net.was_recorded_as("small network, weights fnv1a 00000000000000bb"));
        assert!(IacSource::Wiener.was_recorded_as(&IacSource::Wiener.identity()));
        assert!(!IacSource::Wiener.was_recorded_as(&net.identity()));
    }
}
