//! The analytic FLOP count against one read off the built network: every convolution's
//! weights at the resolution it runs at, and every attention module's own sizes.

use aberration::wiener::BANK_SIZE;
use burn::module::{Module, ModuleVisitor, Param};
use burn::nn::conv::Conv2d;
use burn::tensor::{Device, Tensor};
use restore::net::Stage;
use restore::{RestorerConfig, RestorerNet};

/// Two operations per multiply-add of a convolution, per output pixel.
fn conv_flops(c: &Conv2d) -> f64 {
    2.0 * c.weight.val().dims().iter().product::<usize>() as f64
}

struct ConvWeights(f64);

impl ModuleVisitor for ConvWeights {
    fn visit_float<const D: usize>(&mut self, p: &Param<Tensor<D>>) {
        // In a STAF block every rank-4 parameter is a convolution's weights.
        if D == 4 {
            self.0 += 2.0 * p.val().dims().iter().product::<usize>() as f64;
        }
    }
}

fn stage_flops(s: &Stage) -> f64 {
    s.blocks
        .iter()
        .map(|b| {
            let mut v = ConvWeights(0.0);
            b.visit(&mut v);
            let c = b.spatial.proj.weight.val().dims()[0] as f64;
            let lk = b.spatial.kwin.pow(2) as f64;
            let spatial = 4.0 * lk * c;
            let channel = 4.0 * c * c / b.channel.heads as f64;
            v.0 + spatial + channel
        })
        .sum()
}

fn walked_flops(net: &RestorerNet) -> f64 {
    let at = |l: i32| 0.25f64.powi(l);
    let mut f = conv_flops(&net.embed) + conv_flops(&net.output);
    if let Some(g) = &net.guide {
        let m = BANK_SIZE as f64;
        let hd = g.q.weight.val().dims()[0] as f64;
        f += m * (conv_flops(&g.embed) + conv_flops(&g.k) + conv_flops(&g.v) + conv_flops(&g.out))
            + conv_flops(&g.q)
            + m * 4.0 * g.kwin.pow(2) as f64 * hd;
    }
    for (l, (e, d)) in net.encoders.iter().zip(&net.downs).enumerate() {
        f += (stage_flops(e) + conv_flops(&d.conv)) * at(l as i32);
    }
    f += stage_flops(&net.latent) * at(3);
    for (i, (u, d)) in net.ups.iter().zip(&net.decoders).enumerate() {
        let level = 2 - i as i32;
        f += conv_flops(&u.conv) * at(level + 1) + stage_flops(d) * at(level);
        if let Some(r) = net.reduces.get(i) {
            f += conv_flops(r) * at(level);
        }
    }
    f + stage_flops(&net.refinement)
}

#[test]
fn the_analytic_flop_count_matches_the_built_network() {
    let device = Device::flex();
    for cfg in [
        RestorerConfig::tiny(),
        RestorerConfig::small(),
        RestorerConfig::paper(),
    ] {
        let net = RestorerNet::new(&cfg, &device);
        let (analytic, walked) = (cfg.analytic_flops_per_pixel(), walked_flops(&net));
        println!(
            "{}: {:.1} kFLOP per pixel (analytic), {:.1} (walked)",
            cfg.name,
            analytic / 1e3,
            walked / 1e3
        );
        assert!(
            (analytic - walked).abs() <= 1e-9 * walked,
            "{}: analytic {analytic} vs walked {walked}",
            cfg.name
        );
    }
}
