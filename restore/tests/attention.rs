//! Each attention module against a plain, slow f64 reference written from its definition.
#![allow(clippy::needless_range_loop)] // index loops mirror the formulas

use burn::module::Param;
use burn::tensor::{Device, Distribution, Tensor, TensorData};
use restore::net::channel::ChannelAttention;
use restore::net::layers::enhance_query;
use restore::net::mafg::CrossAttentionGuide;
use restore::net::window::{WindowAttention, key_windows, query_windows};

fn vec4(t: Tensor<4>) -> (Vec<f64>, [usize; 4]) {
    let d = t.dims();
    (
        t.try_into_vec_as::<f32>()
            .unwrap()
            .into_iter()
            .map(f64::from)
            .collect(),
        d,
    )
}

fn rand4(shape: [usize; 4], device: &Device) -> Tensor<4> {
    Tensor::random(shape, Distribution::Normal(0.0, 1.0), device)
}

fn max_abs_diff(a: &[f64], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}

/// Softmax-weighted sum over the allowed keys: `out[c] = Σ_j softmax(logit)_j v_j[c]`.
fn softmax_mix(logits: &[(f64, usize)], v: impl Fn(usize, usize) -> f64, d: usize) -> Vec<f64> {
    let m = logits.iter().map(|l| l.0).fold(f64::NEG_INFINITY, f64::max);
    let z: f64 = logits.iter().map(|l| (l.0 - m).exp()).sum();
    (0..d)
        .map(|c| {
            logits
                .iter()
                .map(|&(l, j)| (l - m).exp() / z * v(j, c))
                .sum()
        })
        .collect()
}

#[test]
fn key_windows_gather_the_overlapping_window_around_each_query_window() {
    let device = Device::flex();
    let (c, h, w, win, kwin) = (2, 16, 24, 8, 12);
    let x = rand4([1, c, h, w], &device);
    let (xv, _) = vec4(x.clone());
    let got: Vec<f64> = key_windows(x.clone(), win, kwin)
        .try_into_vec_as::<f32>()
        .unwrap()
        .into_iter()
        .map(f64::from)
        .collect();
    let p = (kwin - win) as isize / 2;
    let mut want = vec![];
    for wy in 0..h / win {
        for wx in 0..w / win {
            for ky in 0..kwin as isize {
                for kx in 0..kwin as isize {
                    let (y, xx) = ((wy * win) as isize + ky - p, (wx * win) as isize + kx - p);
                    for ch in 0..c {
                        let inside = (0..h as isize).contains(&y) && (0..w as isize).contains(&xx);
                        want.push(if inside {
                            xv[(ch * h + y as usize) * w + xx as usize]
                        } else {
                            0.0
                        });
                    }
                }
            }
        }
    }
    assert_eq!(max_abs_diff(&got, &want), 0.0);
    // Query windows are exact partitions: 6 windows of 64 pixels, every pixel once.
    let q = query_windows(x, win);
    assert_eq!(q.dims(), [6, 64, c]);
}

/// Full attention over every pixel with an explicit mask: key allowed iff it lies in the
/// `kwin` window centred on the query's `win` window, plus the relative-position logit.
#[allow(clippy::too_many_arguments)]
fn full_masked_attention(
    q: &[f64],
    k: &[f64],
    v: &[f64],
    c: usize,
    h: usize,
    w: usize,
    heads: usize,
    win: usize,
    kwin: usize,
    rel: impl Fn(usize, usize, usize, usize, usize) -> f64,
) -> Vec<f64> {
    let d = c / heads;
    let p = (kwin - win) / 2;
    let mut out = vec![0.0; c * h * w];
    for y in 0..h {
        for x in 0..w {
            let (wy0, wx0) = (
                (y / win * win) as isize - p as isize,
                (x / win * win) as isize - p as isize,
            );
            for hd in 0..heads {
                let mut logits = vec![];
                for ky in 0..h {
                    for kx in 0..w {
                        let (dy, dx) = (ky as isize - wy0, kx as isize - wx0);
                        if !(0..kwin as isize).contains(&dy) || !(0..kwin as isize).contains(&dx) {
                            continue;
                        }
                        let dot: f64 = (0..d)
                            .map(|i| {
                                let ch = hd * d + i;
                                q[(ch * h + y) * w + x] * k[(ch * h + ky) * w + kx]
                            })
                            .sum();
                        let l = dot / (d as f64).sqrt()
                            + rel(hd, y % win, x % win, dy as usize, dx as usize);
                        logits.push((l, ky * w + kx));
                    }
                }
                let o = softmax_mix(&logits, |j, i| v[((hd * d + i) * h) * w + j], d);
                for i in 0..d {
                    out[((hd * d + i) * h + y) * w + x] = o[i];
                }
            }
        }
    }
    out
}

#[test]
fn window_attention_equals_full_attention_with_an_explicit_window_mask() {
    let device = Device::flex();
    device.seed(3);
    let (c, h, w, heads, win, kwin) = (8, 16, 24, 2, 8, 12);
    for qe in [0, 3] {
        let mut m = WindowAttention::new(c, heads, win, kwin, qe, &device);
        m.relative = Param::from_tensor(Tensor::random(
            [19 * 19, heads],
            Distribution::Normal(0.0, 0.5),
            &device,
        ));
        let x = rand4([1, c, h, w], &device);
        let got = vec4(m.forward(x.clone())).0;
        // Reference from the same projections, then the same output projection.
        let mut parts = m.qkv.forward(x).chunk(3, 1);
        let (v, k) = (parts.pop().unwrap(), parts.pop().unwrap());
        let q = enhance_query(parts.pop().unwrap(), qe);
        let (qv, kv, vv) = (vec4(q).0, vec4(k).0, vec4(v).0);
        let table: Vec<f64> = m
            .relative
            .val()
            .try_into_vec_as::<f32>()
            .unwrap()
            .into_iter()
            .map(f64::from)
            .collect();
        let side = win + kwin - 1;
        let rel = |hd: usize, qy: usize, qx: usize, ky: usize, kx: usize| {
            let (dy, dx) = (qy + kwin - 1 - ky, qx + kwin - 1 - kx);
            table[(dy * side + dx) * heads + hd]
        };
        let att = full_masked_attention(&qv, &kv, &vv, c, h, w, heads, win, kwin, rel);
        let att = Tensor::<4>::from_data(
            TensorData::new(
                att.iter().map(|&a| a as f32).collect::<Vec<_>>(),
                [1, c, h, w],
            ),
            &device,
        );
        let want = vec4(m.proj.forward(att)).0;
        let err = max_abs_diff(&got, &want);
        assert!(err < 1e-4, "qe {qe}: {err}");
    }
}

#[test]
fn query_enhancement_subtracts_the_zero_padded_local_mean() {
    let device = Device::flex();
    let (c, h, w, k) = (2, 9, 11, 5);
    let x = rand4([1, c, h, w], &device);
    let (xv, _) = vec4(x.clone());
    let got = vec4(enhance_query(x, k)).0;
    let r = (k / 2) as isize;
    let mut want = vec![];
    for ch in 0..c {
        for y in 0..h as isize {
            for xx in 0..w as isize {
                let mut s = 0.0;
                for dy in -r..=r {
                    for dx in -r..=r {
                        let (yy, xxx) = (y + dy, xx + dx);
                        if (0..h as isize).contains(&yy) && (0..w as isize).contains(&xxx) {
                            s += xv[(ch * h + yy as usize) * w + xxx as usize];
                        }
                    }
                }
                want.push(xv[(ch * h + y as usize) * w + xx as usize] - s / (k * k) as f64);
            }
        }
    }
    assert!(max_abs_diff(&got, &want) < 1e-5);
}

#[test]
fn channel_attention_matches_a_direct_transposed_attention() {
    let device = Device::flex();
    device.seed(5);
    let (c, h, w, heads) = (8, 6, 10, 2);
    for qe in [0, 3] {
        let mut m = ChannelAttention::new(c, heads, qe, &device);
        m.temperature = Param::from_tensor(Tensor::from_data(
            TensorData::new(vec![0.7f32, 2.5], [2]),
            &device,
        ));
        let x = rand4([1, c, h, w], &device);
        let got = vec4(m.forward(x.clone())).0;
        let mut parts = m.qkv_depthwise.forward(m.qkv.forward(x)).chunk(3, 1);
        let (v, k) = (parts.pop().unwrap(), parts.pop().unwrap());
        let q = enhance_query(parts.pop().unwrap(), qe);
        let (qv, kv, vv) = (vec4(q).0, vec4(k).0, vec4(v).0);
        let n = h * w;
        let d = c / heads;
        let temps = [0.7, 2.5];
        let norm = |t: &[f64], ch: usize| -> f64 {
            t[ch * n..(ch + 1) * n]
                .iter()
                .map(|a| a * a)
                .sum::<f64>()
                .sqrt()
        };
        let mut att = vec![0.0; c * n];
        for hd in 0..heads {
            for i in 0..d {
                let ci = hd * d + i;
                let logits: Vec<(f64, usize)> = (0..d)
                    .map(|j| {
                        let cj = hd * d + j;
                        let dot: f64 = (0..n).map(|p| qv[ci * n + p] * kv[cj * n + p]).sum();
                        (dot / (norm(&qv, ci) * norm(&kv, cj)) * temps[hd], cj)
                    })
                    .collect();
                let o = softmax_mix(&logits, |cj, p| vv[cj * n + p], n);
                att[ci * n..(ci + 1) * n].copy_from_slice(&o);
            }
        }
        let att = Tensor::<4>::from_data(
            TensorData::new(
                att.iter().map(|&a| a as f32).collect::<Vec<_>>(),
                [1, c, h, w],
            ),
            &device,
        );
        let want = vec4(m.proj.forward(att)).0;
        let err = max_abs_diff(&got, &want);
        assert!(err < 1e-4, "qe {qe}: {err}");
    }
}

#[test]
fn mafg_cross_attention_matches_per_filter_masked_attention() {
    let device = Device::flex();
    device.seed(7);
    let (e, heads, hdim, win, kwin, h, w) = (4, 2, 3, 8, 12, 16, 16);
    let m = CrossAttentionGuide::new(e, heads, hdim, win, kwin, false, &device);
    let bank = Tensor::<4>::random([1, 39, h, w], Distribution::Default, &device);
    let got = vec4(m.forward(bank.clone())).0;
    let c = heads * hdim;
    let feats = m.norm.forward(m.embed.forward(bank.reshape([13, 3, h, w])));
    let median = feats.clone().narrow(0, 6, 1);
    let (qv, _) = vec4(m.q.forward(median));
    let (kv, _) = vec4(m.k.forward(feats.clone()));
    let (vv, _) = vec4(m.v.forward(feats));
    let pq: Vec<f64> = m
        .pos_q
        .val()
        .try_into_vec_as::<f32>()
        .unwrap()
        .into_iter()
        .map(f64::from)
        .collect();
    let pk: Vec<f64> = m
        .pos_k
        .val()
        .try_into_vec_as::<f32>()
        .unwrap()
        .into_iter()
        .map(f64::from)
        .collect();
    let p = (kwin - win) / 2;
    let n = h * w;
    let mut outs = vec![];
    for f in 0..13 {
        // Position embeddings are added per window position: to the query at its place in the
        // query window and to the key at its place in the key window.
        let mut att = vec![0.0; c * n];
        let d = hdim;
        for y in 0..h {
            for x in 0..w {
                let (wy0, wx0) = (
                    (y / win * win) as isize - p as isize,
                    (x / win * win) as isize - p as isize,
                );
                let qpos = (y % win) * win + x % win;
                for hd in 0..heads {
                    let mut logits = vec![];
                    for ky in 0..h {
                        for kx in 0..w {
                            let (dy, dx) = (ky as isize - wy0, kx as isize - wx0);
                            if !(0..kwin as isize).contains(&dy)
                                || !(0..kwin as isize).contains(&dx)
                            {
                                continue;
                            }
                            let kpos = dy as usize * kwin + dx as usize;
                            let dot: f64 = (0..d)
                                .map(|i| {
                                    let ch = hd * d + i;
                                    (qv[ch * n + y * w + x] + pq[qpos * c + ch])
                                        * (kv[(f * c + ch) * n + ky * w + kx] + pk[kpos * c + ch])
                                })
                                .sum();
                            logits.push((dot / (d as f64).sqrt(), ky * w + kx));
                        }
                    }
                    let o = softmax_mix(&logits, |j, i| vv[(f * c + hd * d + i) * n + j], d);
                    for i in 0..d {
                        att[(hd * d + i) * n + y * w + x] = o[i];
                    }
                }
            }
        }
        let att = Tensor::<4>::from_data(
            TensorData::new(
                att.iter().map(|&a| a as f32).collect::<Vec<_>>(),
                [1, c, h, w],
            ),
            &device,
        );
        outs.extend(vec4(m.out.forward(att)).0);
    }
    let err = max_abs_diff(&got, &outs);
    assert!(err < 1e-4, "{err}");
}
