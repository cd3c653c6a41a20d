//! The direct SSIM: the obvious scalar loops the fast [`crate::metrics`] path is checked
//! against (bit for bit: both add the same terms in the same order).

use glam::Vec3;

use crate::metrics::{SSIM_C1, SSIM_C2, SSIM_WINDOW, window};

/// Mean SSIM of `rendered` against `target` and its gradient with respect to `rendered`
/// (sizes are the caller's to check).
pub fn ssim(rendered: &[Vec3], target: &[Vec3], width: u32, height: u32) -> (f32, Vec<Vec3>) {
    let plane = |img: &[Vec3], ch: usize| img.iter().map(|v| v[ch]).collect::<Vec<f32>>();
    let mut grad = vec![Vec3::ZERO; rendered.len()];
    let value = ssim_channels(
        width as usize,
        height as usize,
        |ch| (plane(rendered, ch), plane(target, ch)),
        Some(&mut |i, ch, g| grad[i][ch] = g),
    );
    (value, grad)
}

/// Separable zero-padded "same" convolution; the kernel is symmetric, so this is also its own
/// adjoint, which the backward pass relies on.
fn blur(src: &[f32], w: usize, h: usize, k: &[f32; SSIM_WINDOW], tmp: &mut [f32], dst: &mut [f32]) {
    let r = SSIM_WINDOW / 2;
    for y in 0..h {
        let row = &src[y * w..(y + 1) * w];
        for x in 0..w {
            let lo = x.saturating_sub(r);
            let hi = (x + r).min(w - 1);
            let mut acc = 0.0;
            for xx in lo..=hi {
                acc += k[xx + r - x] * row[xx];
            }
            tmp[y * w + x] = acc;
        }
    }
    for y in 0..h {
        let lo = y.saturating_sub(r);
        let hi = (y + r).min(h - 1);
        for x in 0..w {
            let mut acc = 0.0;
            for yy in lo..=hi {
                acc += k[yy + r - y] * tmp[yy * w + x];
            }
            dst[y * w + x] = acc;
        }
    }
}

/// Per-pixel gradient sink: `(pixel, channel, ∂SSIM/∂x)`.
type GradSink<'a> = &'a mut dyn FnMut(usize, usize, f32);

/// The SSIM of three channel pairs, and with `grad` its gradient with respect to the first.
fn ssim_channels(
    w: usize,
    h: usize,
    channel: impl Fn(usize) -> (Vec<f32>, Vec<f32>),
    mut grad: Option<GradSink<'_>>,
) -> f32 {
    let n = w * h;
    let k = window();
    let inv_count = 1.0 / (3 * n) as f32;
    let mut total = 0.0f64;
    let mut tmp = vec![0.0f32; n];
    let mut bufs: Vec<Vec<f32>> = (0..5).map(|_| vec![0.0f32; n]).collect();
    let mut planes: Vec<Vec<f32>> = (0..5).map(|_| vec![0.0f32; n]).collect();
    for ch in 0..3 {
        let (x, y) = channel(ch);
        for i in 0..n {
            planes[0][i] = x[i];
            planes[1][i] = y[i];
            planes[2][i] = x[i] * x[i];
            planes[3][i] = y[i] * y[i];
            planes[4][i] = x[i] * y[i];
        }
        for (p, b) in planes.iter().zip(bufs.iter_mut()) {
            blur(p, w, h, &k, &mut tmp, b);
        }
        // Per-pixel derivatives of the SSIM map w.r.t. the blurred statistics μx, E[x²], E[xy],
        // written back into `planes` and then pulled back through the (self-adjoint) blur.
        // Summed row by row (each row in pixel order, then the rows in order), as the fast
        // path sums its rows in parallel.
        let mut row_total = 0.0f64;
        for i in 0..n {
            let (mx, my) = (bufs[0][i], bufs[1][i]);
            let vx = bufs[2][i] - mx * mx;
            let vy = bufs[3][i] - my * my;
            let cxy = bufs[4][i] - mx * my;
            let a1 = 2.0 * mx * my + SSIM_C1;
            let a2 = 2.0 * cxy + SSIM_C2;
            let b1 = mx * mx + my * my + SSIM_C1;
            let b2 = vx + vy + SSIM_C2;
            let s = a1 * a2 / (b1 * b2);
            row_total += s as f64;
            if (i + 1) % w == 0 {
                total += row_total;
                row_total = 0.0;
            }
            let d_m2 = -s / b2;
            let d_mxy = 2.0 * a1 / (b1 * b2);
            let d_mx = 2.0 * my * (a2 - a1) / (b1 * b2) - 2.0 * mx * s / b1 + 2.0 * mx * s / b2;
            planes[0][i] = d_mx * inv_count;
            planes[2][i] = d_m2 * inv_count;
            planes[4][i] = d_mxy * inv_count;
        }
        let Some(sink) = grad.as_mut() else {
            continue;
        };
        for p in [0, 2, 4] {
            blur(&planes[p], w, h, &k, &mut tmp, &mut bufs[p]);
        }
        for i in 0..n {
            sink(
                i,
                ch,
                bufs[0][i] + 2.0 * x[i] * bufs[2][i] + y[i] * bufs[4][i],
            );
        }
    }
    (total * inv_count as f64) as f32
}
