//! The network: MAFG guidance, a U-shaped body of STAF blocks (Restormer layout), a residual
//! added to one Wiener image of the bank (`RestorerConfig::residual_base`).

pub mod channel;
pub mod conv_train;
pub mod dense_direct;
pub mod fresh;
pub mod fuse_direct;
pub mod gate_direct;
pub mod gate_train;
pub mod gelu;
pub mod kernels;
pub mod lanes;
pub mod layers;
pub mod mafg;
pub mod norm_direct;
pub mod pointwise;
pub mod query_box;
pub mod staf;
#[cfg(test)]
mod test_values;
pub mod window;
pub mod window_direct;
pub mod window_train;

use crate::config::{Guidance, RestorerConfig};
use aberration::wiener::BANK_MEDIAN;
use burn::module::Module;
use burn::nn::conv::Conv2d;
use burn::nn::{PixelShuffle, PixelShuffleConfig, PixelUnshuffle, PixelUnshuffleConfig};
use burn::tensor::{Device, Tensor};
use layers::{conv, conv3, pointwise};
use mafg::CrossAttentionGuide;
use staf::{BlockSpec, Gate, StafBlock};

/// Pixel-unshuffle downsampling: 3×3 conv `C → C/2`, then 2×2 → channels (`2C` out).
#[derive(Module, Debug)]
pub struct Down {
    pub conv: Conv2d,
    pub unshuffle: PixelUnshuffle,
}

/// Pixel-shuffle upsampling: 3×3 conv `C → 2C`, then channels → 2×2 (`C/2` out).
#[derive(Module, Debug)]
pub struct Up {
    pub conv: Conv2d,
    pub shuffle: PixelShuffle,
}

impl Down {
    fn new(c: usize, device: &Device) -> Self {
        Self {
            conv: conv(c, c / 2, 3, false, device),
            unshuffle: PixelUnshuffleConfig::new(2).init(),
        }
    }
    fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        self.unshuffle.forward(conv3(&self.conv, x))
    }
}

impl Up {
    fn new(c: usize, device: &Device) -> Self {
        Self {
            conv: conv(c, 2 * c, 3, false, device),
            shuffle: PixelShuffleConfig::new(2).init(),
        }
    }
    fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        self.shuffle.forward(conv3(&self.conv, x))
    }
}

#[derive(Module, Debug)]
pub struct Stage {
    pub blocks: Vec<StafBlock>,
}

impl Stage {
    fn forward(&self, mut x: Tensor<4>) -> Tensor<4> {
        for b in &self.blocks {
            x = b.forward(x);
        }
        x
    }
}

#[derive(Module, Debug)]
pub struct RestorerNet {
    pub guide: Option<CrossAttentionGuide>,
    /// 3×3 conv from the guidance channels to `dim`.
    pub embed: Conv2d,
    pub encoders: Vec<Stage>,
    pub downs: Vec<Down>,
    pub latent: Stage,
    /// Upsamplers into decoder levels 3, 2, 1.
    pub ups: Vec<Up>,
    /// 1×1 reductions after the skip concatenation at decoder levels 3 and 2.
    pub reduces: Vec<Conv2d>,
    pub decoders: Vec<Stage>,
    pub refinement: Stage,
    pub output: Conv2d,
    pub single_wiener: bool,
    pub residual_base: usize,
}

fn stage(
    cfg: &RestorerConfig,
    n: usize,
    c: usize,
    channel_heads: usize,
    qe: usize,
    gate: Gate,
    device: &Device,
) -> Stage {
    let blocks = (0..n)
        .map(|i| {
            StafBlock::new(
                BlockSpec {
                    channels: c,
                    channel_heads,
                    window_heads: c / cfg.window_head_dim,
                    win: cfg.window,
                    kwin: cfg.key_window(),
                    hidden: cfg.ffn_hidden(c),
                    // Query enhancement on every other block, starting with the first.
                    qe: if i % 2 == 0 { qe } else { 0 },
                    gate,
                },
                device,
            )
        })
        .collect();
    Stage { blocks }
}

impl RestorerNet {
    /// A freshly initialised network (seed the device first for reproducible weights).
    pub fn new(cfg: &RestorerConfig, device: &Device) -> Self {
        let d = cfg.dim;
        let residual = cfg.guidance == Guidance::CrossAttentionResidual;
        let attended = cfg.guidance == Guidance::CrossAttention || residual;
        let guide = attended.then(|| {
            CrossAttentionGuide::new(
                cfg.mafg_embed,
                cfg.mafg_heads,
                cfg.mafg_head_dim,
                cfg.window,
                cfg.key_window(),
                residual,
                device,
            )
        });
        let cin = if cfg.guidance == Guidance::SingleWiener {
            3
        } else {
            39
        };
        let encoders = (0..3)
            .map(|l| {
                stage(
                    cfg,
                    cfg.blocks[l],
                    d << l,
                    cfg.heads[l],
                    0,
                    Gate::PerChannel,
                    device,
                )
            })
            .collect();
        let downs = (0..3).map(|l| Down::new(d << l, device)).collect();
        let latent = stage(
            cfg,
            cfg.blocks[3],
            8 * d,
            cfg.heads[3],
            cfg.qe_latent,
            Gate::PerChannel,
            device,
        );
        let ups = (0..3)
            .rev()
            .map(|l| Up::new(d << (l + 1), device))
            .collect();
        let reduces = vec![
            conv(8 * d, 4 * d, 1, false, device),
            conv(4 * d, 2 * d, 1, false, device),
        ];
        let decoders = vec![
            stage(
                cfg,
                cfg.blocks[2],
                4 * d,
                cfg.heads[2],
                cfg.qe_decoder[0],
                Gate::PerPixel,
                device,
            ),
            stage(
                cfg,
                cfg.blocks[1],
                2 * d,
                cfg.heads[1],
                cfg.qe_decoder[1],
                Gate::PerPixel,
                device,
            ),
            stage(
                cfg,
                cfg.blocks[0],
                2 * d,
                cfg.heads[0],
                cfg.qe_decoder[2],
                Gate::PerPixel,
                device,
            ),
        ];
        let refinement = stage(
            cfg,
            cfg.refinement,
            2 * d,
            cfg.heads[0],
            cfg.qe_refinement,
            Gate::PerPixel,
            device,
        );
        Self {
            guide,
            embed: conv(cin, d, 3, false, device),
            encoders,
            downs,
            latent,
            ups,
            reduces,
            decoders,
            refinement,
            output: conv(2 * d, 3, 3, false, device),
            single_wiener: cfg.guidance == Guidance::SingleWiener,
            residual_base: cfg.residual_base,
        }
    }

    /// `bank: [b, 39, h, w]` (13 Wiener images, filter-major; `h`, `w` multiples of
    /// [`RestorerConfig::multiple`]) → restored `[b, 3, h, w]` (not clamped).
    pub fn forward(&self, bank: Tensor<4>) -> Tensor<4> {
        let base = bank.clone().narrow(1, 3 * self.residual_base, 3);
        let guided = match (&self.guide, self.single_wiener) {
            (Some(g), _) => g.forward(bank),
            (None, true) => bank.narrow(1, 3 * BANK_MEDIAN, 3),
            (None, false) => bank,
        };
        let x = conv3(&self.embed, guided);
        let mut skips = Vec::with_capacity(3);
        let mut x = x;
        for (enc, down) in self.encoders.iter().zip(&self.downs) {
            let e = enc.forward(x);
            skips.push(e.clone());
            x = down.forward(e);
        }
        let mut x = self.latent.forward(x);
        for (i, (up, dec)) in self.ups.iter().zip(&self.decoders).enumerate() {
            let skip = skips.pop().expect("one skip per level");
            x = Tensor::cat(vec![up.forward(x), skip], 1);
            if let Some(r) = self.reduces.get(i) {
                x = pointwise(r, x);
            }
            x = dec.forward(x);
        }
        let x = self.refinement.forward(x);
        conv3(&self.output, x) + base
    }
}
