//! Network sizes and ablation switches, with the analytic parameter count every model is
//! checked against.

use aberration::wiener::{BANK_MEDIAN, BANK_SIZE};
use serde::{Deserialize, Serialize};

/// How the 13 Wiener images enter the network.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum Guidance {
    /// The paper's MAFG: windowed cross-attention, query from the median image, keys and
    /// values from each filter output.
    CrossAttention,
    /// The same cross-attention with each filter's own image added to its answer, so the
    /// guide starts as the identity on the bank instead of a window average of it.
    #[value(name = "residual")]
    CrossAttentionResidual,
    /// Ablation: the 13 images concatenated (39 channels) straight into the 3×3 embedding.
    Concat,
    /// Ablation: the median Wiener image alone.
    #[value(name = "single")]
    SingleWiener,
}

impl std::fmt::Display for Guidance {
    /// The command-line name.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        use clap::ValueEnum;
        let v = self.to_possible_value().expect("no variant is skipped");
        f.write_str(v.get_name())
    }
}

/// The three sizes of the restorer.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Preset {
    Tiny,
    Small,
    Paper,
}

/// Sizes of the MAFG + STAF restorer. The U-shaped body follows Restormer: level `l` has
/// `dim·2^l` channels (the first decoder level and the refinement keep `2·dim`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RestorerConfig {
    pub name: String,
    /// Channels at the first level.
    pub dim: usize,
    /// STAF blocks per encoder level 1..3 and the latent level; decoders mirror them.
    pub blocks: [usize; 4],
    /// Refinement blocks after the last decoder level.
    pub refinement: usize,
    /// Heads of the transposed channel attention per level.
    pub heads: [usize; 4],
    /// Dimensions per head of the spatial window attention (heads = channels / this).
    pub window_head_dim: usize,
    /// Query window side; keys and values come from a window grown by half of it.
    pub window: usize,
    /// GDFN hidden expansion.
    pub ffn_expansion: f64,
    /// MAFG per-filter embedding width, heads and dimensions per head.
    pub mafg_embed: usize,
    pub mafg_heads: usize,
    pub mafg_head_dim: usize,
    pub guidance: Guidance,
    /// The bank's K follows each tile's channel intensity (`K = k·(1 − c_I)`); off is the
    /// "no channel intensity in K" ablation (fixed K = k).
    pub adaptive_k: bool,
    /// Query-enhancement pooling kernels: latent level, decoder levels 3, 2, 1, refinement.
    pub qe_latent: usize,
    pub qe_decoder: [usize; 3],
    pub qe_refinement: usize,
    /// Side of the square training crops.
    pub crop: usize,
    /// The bank image the network's output is added to. Weights saved before this switch
    /// existed read as the median filter, as they were trained.
    #[serde(default = "median_filter")]
    pub residual_base: usize,
}

fn median_filter() -> usize {
    BANK_MEDIAN
}

impl RestorerConfig {
    /// The paper's released configuration (≈29 M parameters), in the paper's layout as we read it:
    /// MAFG cross-attention without a skip, the residual on the median Wiener image.
    pub fn paper() -> Self {
        Self {
            name: "paper".into(),
            dim: 48,
            blocks: [2, 4, 4, 4],
            refinement: 4,
            heads: [1, 2, 4, 8],
            window_head_dim: 16,
            window: 8,
            ffn_expansion: 2.66,
            mafg_embed: 32,
            mafg_heads: 2,
            mafg_head_dim: 16,
            guidance: Guidance::CrossAttention,
            adaptive_k: true,
            qe_latent: 15,
            qe_decoder: [11, 7, 3],
            qe_refinement: 3,
            crop: 256,
            residual_base: BANK_MEDIAN,
        }
    }

    pub fn small() -> Self {
        Self {
            name: "small".into(),
            dim: 32,
            blocks: [1, 2, 2, 2],
            refinement: 2,
            heads: [1, 2, 4, 8],
            mafg_embed: 16,
            crop: 128,
            ..Self::paper().trainable_layout()
        }
    }

    /// The layout `small` and `tiny` use: a skip around the MAFG cross-attention (without it
    /// the guide starts as a window blur of the bank and learns slowly) and the residual on
    /// Wiener filter 0 (K = 1e-2), the bank's best single image on natural photos, which
    /// leaves the network detail to add instead of noise to remove. The ablations behind
    /// this choice are in restore/README.md.
    pub fn trainable_layout(self) -> Self {
        Self {
            guidance: Guidance::CrossAttentionResidual,
            residual_base: 0,
            ..self
        }
    }

    /// Trainable on two CPU cores.
    pub fn tiny() -> Self {
        Self {
            name: "tiny".into(),
            window: 4,
            dim: 16,
            blocks: [1, 1, 1, 1],
            refinement: 1,
            heads: [1, 1, 2, 2],
            window_head_dim: 8,
            mafg_embed: 8,
            mafg_heads: 1,
            mafg_head_dim: 8,
            crop: 64,
            ..Self::paper().trainable_layout()
        }
    }

    pub fn preset(p: Preset) -> Self {
        match p {
            Preset::Tiny => Self::tiny(),
            Preset::Small => Self::small(),
            Preset::Paper => Self::paper(),
        }
    }

    /// This config with ablation switches changed; each change is named in the config's
    /// name, so weights trained under it say so.
    pub fn with_ablations(
        mut self,
        guidance: Option<Guidance>,
        fixed_k: bool,
        residual_base: Option<usize>,
    ) -> Result<Self, String> {
        if let Some(g) = guidance.filter(|&g| g != self.guidance) {
            self.guidance = g;
            self.name = format!("{}-{g}", self.name);
        }
        if fixed_k {
            self.adaptive_k = false;
            self.name = format!("{}-fixed-k", self.name);
        }
        if let Some(m) = residual_base.filter(|&m| m != self.residual_base) {
            self.residual_base = m;
            self.name = format!("{}-base{m}", self.name);
        }
        self.validate()?;
        Ok(self)
    }

    /// The same network, whatever its name and training crop: weights of one load into the
    /// other.
    pub fn same_network(&self, other: &Self) -> bool {
        let unnamed = |c: &Self| Self {
            name: String::new(),
            crop: 0,
            ..c.clone()
        };
        unnamed(self) == unnamed(other)
    }

    /// The same parameters, whatever feeds the network or what its output is added to: the
    /// bank's K (`adaptive_k`) and the residual base are switches without parameters of their
    /// own, so weights trained under one fine-tune under the other (`restorer train --init`);
    /// restoring with them still needs [`Self::same_network`].
    pub fn same_parameters(&self, other: &Self) -> bool {
        let bare = |c: &Self| Self {
            adaptive_k: true,
            residual_base: 0,
            ..c.clone()
        };
        bare(self).same_network(&bare(other))
    }

    /// Channels at level 0..3 of the encoder.
    pub fn level_dim(&self, level: usize) -> usize {
        self.dim << level
    }

    /// Side of the key/value windows: the query window grown by half of it (overlap 0.5).
    pub fn key_window(&self) -> usize {
        self.window + self.window / 2
    }

    /// Inputs are padded to a multiple of this (three 2× downsamplings, then whole windows).
    pub fn multiple(&self) -> usize {
        8 * self.window
    }

    /// GDFN hidden width for `c` channels.
    pub fn ffn_hidden(&self, c: usize) -> usize {
        (c as f64 * self.ffn_expansion) as usize
    }

    /// Checks that every size divides as the modules need.
    pub fn validate(&self) -> Result<(), String> {
        let fail = |m: String| Err(format!("config '{}': {m}", self.name));
        if self.dim == 0 || self.window == 0 || !self.window.is_multiple_of(2) {
            return fail("dim must be positive and window a positive even number".into());
        }
        for l in 0..4 {
            let c = self.level_dim(l);
            if self.heads[l] == 0 || !c.is_multiple_of(self.heads[l]) {
                return fail(format!(
                    "{} heads do not divide {c} channels",
                    self.heads[l]
                ));
            }
        }
        for c in [self.dim, 2 * self.dim, 4 * self.dim, 8 * self.dim] {
            if self.window_head_dim == 0 || c % self.window_head_dim != 0 {
                return fail(format!(
                    "window head dim {} does not divide {c} channels",
                    self.window_head_dim
                ));
            }
        }
        for k in [self.qe_latent, self.qe_refinement]
            .iter()
            .chain(self.qe_decoder.iter())
        {
            if k % 2 == 0 {
                return fail(format!("query-enhancement kernel {k} must be odd"));
            }
        }
        if self.mafg_embed == 0 || self.mafg_heads * self.mafg_head_dim == 0 {
            return fail("MAFG sizes must be positive".into());
        }
        if self.residual_base >= BANK_SIZE {
            return fail(format!(
                "residual base {} is not one of the {BANK_SIZE} bank filters",
                self.residual_base
            ));
        }
        if self.crop == 0 || !self.crop.is_multiple_of(self.multiple()) {
            return fail(format!(
                "crop {} must be a multiple of {}",
                self.crop,
                self.multiple()
            ));
        }
        Ok(())
    }

    /// The number of trainable scalars, counted from the architecture on paper (the tests
    /// check the built model against it).
    pub fn analytic_params(&self) -> usize {
        let d = self.dim;
        let block = |c: usize, heads: usize| -> usize {
            let h = self.ffn_hidden(c);
            let norm = 2 * c;
            let gdfn = 3 * h * c + 18 * h;
            let channel_attn = 4 * c * c + 27 * c + heads;
            let (w, wk) = (self.window, self.key_window());
            let window_attn = 4 * c * c + 4 * c + (w + wk - 1).pow(2) * (c / self.window_head_dim);
            let fusion = 2 * c * c + c + c * c + c;
            4 * norm + 2 * gdfn + channel_attn + window_attn + fusion
        };
        let mut n = 0;
        for l in 0..4 {
            n += self.blocks[l] * block(d << l, self.heads[l]);
        }
        // Decoder levels 3, 2 at their encoder widths; level 1 and the refinement at 2·dim.
        n += self.blocks[2] * block(4 * d, self.heads[2]);
        n += self.blocks[1] * block(2 * d, self.heads[1]);
        n += self.blocks[0] * block(2 * d, self.heads[0]);
        n += self.refinement * block(2 * d, self.heads[0]);
        // Downsampling convs (C → C/2, then unshuffle) and upsampling convs (C → 2C, shuffle).
        for l in 0..3 {
            let c = d << l;
            n += 9 * c * (c / 2);
            let up = d << (l + 1);
            n += 9 * up * (2 * up);
        }
        // 1×1 channel reductions after the skip concatenations at decoder levels 3 and 2.
        n += 8 * d * 4 * d + 4 * d * 2 * d;
        // Output 3×3 conv 2·dim → 3.
        n += 9 * 2 * d * 3;
        n + match self.guidance {
            Guidance::CrossAttention | Guidance::CrossAttentionResidual => {
                let (e, hd) = (self.mafg_embed, self.mafg_heads * self.mafg_head_dim);
                let (w, wk) = (self.window, self.key_window());
                4 * e + 2 * e + 3 * (e * hd + hd) + (w * w + wk * wk) * hd + 3 * hd + 3 + 9 * 39 * d
            }
            Guidance::Concat => 9 * 39 * d,
            Guidance::SingleWiener => 9 * 3 * d,
        }
    }

    /// An upper estimate of the bytes one training step on `batch` crops of `side × side`
    /// holds: the activations the backward pass keeps (per block its norms, projections,
    /// feed-forward planes and attention probabilities; per bank filter its embedding, keys,
    /// values and cross-attention probabilities), doubled for the gradients and temporaries
    /// alive at the backward's peak, plus the input bank and the weights with their gradients
    /// and two AdamW moments. `restorer train` refuses a batch beyond the machine with it
    /// before it allocates (tested against a counting allocator in `tests/train_memory.rs`).
    pub fn training_bytes(&self, batch: usize, side: usize) -> u64 {
        let lk = self.key_window().pow(2) as f64;
        let block = |c: usize| -> f64 {
            let (cf, h) = (c as f64, self.ffn_hidden(c) as f64);
            let heads = (c / self.window_head_dim).max(1) as f64;
            24.0 * cf + 12.0 * h + 2.0 * heads * lk
        };
        let at = |l: i32| 0.25f64.powi(l);
        let d = self.dim;
        let mut per_px = 0.0;
        for l in 0..4 {
            per_px += self.blocks[l] as f64 * block(d << l) * at(l as i32);
        }
        per_px += self.blocks[2] as f64 * block(4 * d) * at(2);
        per_px += self.blocks[1] as f64 * block(2 * d) * at(1);
        per_px += (self.blocks[0] + self.refinement) as f64 * block(2 * d);
        let bank = BANK_SIZE as f64;
        per_px += match self.guidance {
            Guidance::CrossAttention | Guidance::CrossAttentionResidual => {
                let e = self.mafg_embed as f64;
                let hd = (self.mafg_heads * self.mafg_head_dim) as f64;
                bank * (2.0 * e + 3.0 * hd + 2.0 * self.mafg_heads as f64 * lk + 3.0) + e + hd
            }
            Guidance::Concat | Guidance::SingleWiener => 0.0,
        };
        // The bank and the clean crop.
        per_px += 3.0 * bank + 3.0;
        let pixels = (batch * side * side) as f64;
        let activations = 2.0 * 4.0 * pixels * per_px;
        let weights = 4.0 * 4.0 * self.analytic_params() as f64;
        (activations + weights).ceil() as u64
    }

    /// Floating-point operations of one forward pass per input pixel, counted from the
    /// architecture on paper: two per multiply-add of every convolution, matrix product and
    /// attention (logits and weighted sums), each at its level's resolution. Norms,
    /// activations, softmax and pooling are left out: they are a few operations per value,
    /// not per weight. A training step costs about three times this per crop pixel.
    pub fn analytic_flops_per_pixel(&self) -> f64 {
        let d = self.dim;
        let wk = self.key_window();
        let lk = (wk * wk) as f64;
        // Each query pixel of a window scores `lk` keys and mixes `lk` values, all heads
        // together `c` channels wide.
        let window_attention = |c: f64| 2.0 * 2.0 * lk * c;
        let block = |c: usize, heads: usize| -> f64 {
            let (c, h) = (c as f64, self.ffn_hidden(c) as f64);
            let gdfn = 2.0 * (c * 2.0 * h + 9.0 * 2.0 * h + h * c);
            // A `c/heads`-square attention map per head, built from and applied to every pixel.
            let channel_attn =
                2.0 * (3.0 * c * c + 9.0 * 3.0 * c + c * c) + 2.0 * 2.0 * c * c / heads as f64;
            let spatial = 2.0 * (3.0 * c * c + c * c) + window_attention(c);
            let fusion = 2.0 * (2.0 * c * c + c * c);
            2.0 * gdfn + channel_attn + spatial + fusion
        };
        // Pixels at level `l` per input pixel.
        let at = |l: i32| 0.25f64.powi(l);
        let mut f = 0.0;
        for l in 0..4 {
            f += self.blocks[l] as f64 * block(d << l, self.heads[l]) * at(l as i32);
        }
        f += self.blocks[2] as f64 * block(4 * d, self.heads[2]) * at(2);
        f += self.blocks[1] as f64 * block(2 * d, self.heads[1]) * at(1);
        f += (self.blocks[0] + self.refinement) as f64 * block(2 * d, self.heads[0]);
        for l in 0..3 {
            let c = (d << l) as f64;
            f += 2.0 * 9.0 * c * (c / 2.0) * at(l);
            let up = (d << (l + 1)) as f64;
            f += 2.0 * 9.0 * up * (2.0 * up) * at(l + 1);
        }
        let d = d as f64;
        f += 2.0 * (8.0 * d * 4.0 * d * at(2) + 4.0 * d * 2.0 * d * at(1));
        f += 2.0 * 9.0 * 2.0 * d * 3.0;
        let bank = BANK_SIZE as f64;
        f + match self.guidance {
            Guidance::CrossAttention | Guidance::CrossAttentionResidual => {
                let (e, hd) = (
                    self.mafg_embed as f64,
                    (self.mafg_heads * self.mafg_head_dim) as f64,
                );
                // Every filter embedded, keyed and valued; one query (the median's); every
                // filter's window attention and projection back to RGB.
                let per_filter = 2.0 * (3.0 * e + 2.0 * e * hd + hd * 3.0) + window_attention(hd);
                bank * per_filter + 2.0 * e * hd + 2.0 * 9.0 * 3.0 * bank * d
            }
            Guidance::Concat => 2.0 * 9.0 * 3.0 * bank * d,
            Guidance::SingleWiener => 2.0 * 9.0 * 3.0 * d,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn weights_saved_before_the_residual_base_switch_read_as_the_median_filter() {
        let mut json = serde_json::to_value(RestorerConfig::tiny()).unwrap();
        json.as_object_mut().unwrap().remove("residual_base");
        let old: RestorerConfig = serde_json::from_value(json).unwrap();
        assert_eq!(old.residual_base, BANK_MEDIAN);
        assert_ne!(RestorerConfig::tiny().residual_base, BANK_MEDIAN);
    }

    #[test]
    fn same_network_ignores_the_name_but_not_the_residual_base() {
        let a = RestorerConfig::tiny();
        let renamed = RestorerConfig {
            name: "tiny-residual-base0".into(),
            ..a.clone()
        };
        assert!(a.same_network(&renamed));
        // The training crop is not part of the network: weights trained on 64² crops
        // fine-tune on 128² ones.
        let larger_crops = RestorerConfig {
            crop: 128,
            ..a.clone()
        };
        assert!(a.same_network(&larger_crops));
        let median = RestorerConfig {
            residual_base: BANK_MEDIAN,
            ..a.clone()
        };
        assert!(!a.same_network(&median));
        // Fine-tuning may move the base and the bank's K, not the parameters.
        let fixed_k = RestorerConfig {
            adaptive_k: false,
            ..median.clone()
        };
        assert!(a.same_parameters(&fixed_k) && !a.same_network(&fixed_k));
        assert!(!a.same_parameters(&RestorerConfig::small()));
        let wider = RestorerConfig {
            dim: a.dim + 8,
            ..a.clone()
        };
        assert!(!a.same_parameters(&wider));
        let bad = RestorerConfig {
            residual_base: BANK_SIZE,
            ..a
        };
        assert!(bad.validate().unwrap_err().contains("residual base"));
    }
}
