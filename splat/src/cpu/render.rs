//! The CPU rasterizer's entry points: [`render`] (forward only), [`render_for_backward`]
//! (forward that keeps its state) and [`render_backward`]. [`crate::CpuRasterizer`] puts them
//! behind the [`crate::Rasterizer`] interface.
//!
//! Parallelism is over Gaussians (projection, parameter gradients) and over tiles (blending);
//! every output value is produced by exactly one task and cross-tile sums are reduced per
//! Gaussian in tile order, so results are bit-identical for any rayon thread count.

use glam::Vec3;
use rayon::prelude::*;

use crate::camera::Camera;
use crate::cpu::blend;
use crate::cpu::lanes::LANES;
use crate::cpu::project::lanes::{BackwardIn, Block, project_backward_lanes, project_lanes};
use crate::cpu::stages::{
    self, IsectGrad, ParamGrad, PixelGrads, PixelOut, Projected, ScreenGrad, Splat, TileSink,
};
use crate::cpu::tiles::{self, TileBins};
use crate::disjoint::Disjoint;
use crate::error::SplatError;
use crate::model::Gaussians;
use crate::reference::scalar_blend;

#[derive(Clone, Debug, PartialEq)]
pub struct RenderSettings {
    /// SH degree used for colour (≤ the model's stored degree); higher bands are not evaluated.
    pub sh_degree: u32,
    pub background: Vec3,
    /// Mip-Splatting opacity compensation for the 0.3 px low-pass (gsplat `rasterize_mode="antialiased"`).
    pub antialiased: bool,
}

impl Default for RenderSettings {
    fn default() -> Self {
        Self {
            sh_degree: 0,
            background: Vec3::ZERO,
            antialiased: false,
        }
    }
}

/// Forward outputs; images are row-major `width * height`.
#[derive(Clone, Debug)]
pub struct RenderOutput {
    pub width: u32,
    pub height: u32,
    pub color: Vec<Vec3>,
    pub alpha: Vec<f32>,
    /// Expected (alpha-normalised) camera-space depth, 0 where alpha is 0.
    pub depth: Vec<f32>,
    /// Per-Gaussian pixel half-extent `[x, y]` of its screen bounding box; `[0, 0]` if culled.
    pub radii: Vec<[i32; 2]>,
    /// Per-Gaussian: survived culling (touches the image, in front, opacity ≥ 1/255).
    pub visible: Vec<bool>,
    /// Number of (tile, Gaussian) pairs blended over; the work measure used by the benchmarks.
    pub num_intersections: usize,
    /// Number of (pixel, Gaussian) pairs actually blended: the irreducible work of the pass.
    pub num_blended: u64,
}

/// What the CPU forward pass keeps for [`render_backward`]: the per-pixel end state and the
/// sorted tile lists. Only [`render_for_backward`] makes one; plain renders drop it.
#[derive(Clone, Debug)]
pub struct ForwardState {
    kernels: BlendKernels,
    camera: Camera,
    settings: RenderSettings,
    num_gaussians: usize,
    splats: Vec<Splat>,
    bins: TileBins,
    depth: Vec<f32>,
    final_t: Vec<f32>,
    n_contrib: Vec<u32>,
    /// Per tile-list entry, the blocks in which the splat blended (`blocks::forward_tile`);
    /// the scalar kernels keep none.
    blended_blocks: Option<Vec<u32>>,
}

impl ForwardState {
    pub fn camera(&self) -> &Camera {
        &self.camera
    }

    pub fn settings(&self) -> &RenderSettings {
        &self.settings
    }
}

fn check_inputs(g: &Gaussians, cam: &Camera, s: &RenderSettings) -> Result<(), SplatError> {
    cam.validate()?;
    g.validate()?;
    if s.sh_degree > g.sh_degree {
        return Err(SplatError::InvalidInput(format!(
            "render sh_degree {} exceeds the model's stored degree {}",
            s.sh_degree, g.sh_degree
        )));
    }
    if !s.background.is_finite() {
        return Err(SplatError::InvalidInput("background is not finite".into()));
    }
    Ok(())
}

/// Which CPU blending kernels a render uses: the vectorised pixel blocks ([`crate::cpu::blend`],
/// the default) or the scalar per-splat loops ([`crate::reference::scalar_blend`]), kept as their reference
/// and for side-by-side benchmarks.
#[doc(hidden)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum BlendKernels {
    #[default]
    Lanes,
    Scalar,
}

/// [`render_for_backward`] with the given kernels (its backward uses the same).
#[doc(hidden)]
pub fn render_for_backward_with(
    g: &Gaussians,
    cam: &Camera,
    settings: &RenderSettings,
    kernels: BlendKernels,
) -> Result<(RenderOutput, ForwardState), SplatError> {
    let (out, state) = forward(g, cam, settings, true, kernels)?;
    Ok((out, state.expect("requested")))
}

/// Renders `g` from `cam` for looking at (evaluation, novel views, a viewer): nothing is kept
/// for a backward pass. Gaussians with non-finite parameters are treated as culled.
pub fn render(
    g: &Gaussians,
    cam: &Camera,
    settings: &RenderSettings,
) -> Result<RenderOutput, SplatError> {
    forward(g, cam, settings, false, BlendKernels::Lanes).map(|(out, _)| out)
}

/// Renders `g` from `cam` and keeps what [`render_backward`] needs.
pub fn render_for_backward(
    g: &Gaussians,
    cam: &Camera,
    settings: &RenderSettings,
) -> Result<(RenderOutput, ForwardState), SplatError> {
    render_for_backward_with(g, cam, settings, BlendKernels::Lanes)
}

fn forward(
    g: &Gaussians,
    cam: &Camera,
    settings: &RenderSettings,
    keep: bool,
    kernels: BlendKernels,
) -> Result<(RenderOutput, Option<ForwardState>), SplatError> {
    check_inputs(g, cam, settings)?;
    let n = g.len();
    let mut projected: Vec<Projected> = Vec::with_capacity(n);
    // Eight Gaussians at a time ([`project_lanes`]), each block written into its own slots.
    projected.spare_capacity_mut()[..n]
        .par_chunks_mut(LANES)
        .enumerate()
        .for_each(|(b, slots)| {
            let first = b * LANES;
            let at = Block {
                g,
                first,
                cam,
                sh_degree: settings.sh_degree,
                antialiased: settings.antialiased,
            };
            let block = project_lanes(&at, slots.len());
            for (slot, p) in slots.iter_mut().zip(block) {
                slot.write(p);
            }
        });
    // SAFETY: the chunks cover `0 .. n` and every slot of each was written.
    unsafe { projected.set_len(n) };
    let (w, h) = (cam.width, cam.height);
    let bins = tiles::bin(&projected, w, h);
    let splats: Vec<Splat> = stages::splats_of(&projected);
    let n_pix = cam.num_pixels();
    let mut color = vec![Vec3::ZERO; n_pix];
    let mut alpha = vec![0.0; n_pix];
    let mut depth = vec![0.0; n_pix];
    let (mut final_t, mut n_contrib) = if keep {
        (vec![1.0; n_pix], vec![0; n_pix])
    } else {
        (Vec::new(), Vec::new())
    };
    // The blocks each tile-list entry blended in, for the backward (only the vectorised
    // kernels record them).
    let keep_blocks = keep && kernels == BlendKernels::Lanes;
    let mut blended_blocks = vec![0u32; if keep_blocks { bins.ids.len() } else { 0 }];
    let num_blended = {
        let blocks_out = Disjoint::new(&mut blended_blocks);
        let sink = TileSink::new(
            w,
            &mut color,
            &mut alpha,
            &mut depth,
            keep.then_some((&mut final_t[..], &mut n_contrib[..])),
        );
        (0..bins.num_tiles())
            .into_par_iter()
            .map_init(
                || (Vec::new(), Vec::new()),
                |(list, scratch), t| {
                    let tile = stages::tile_pixels(&bins, t, w, h);
                    match kernels {
                        BlendKernels::Lanes => {
                            stages::gather_into(&bins, &splats, t, list);
                            let range = bins.range(t);
                            let blocks = if keep_blocks {
                                // SAFETY: tile t's range of the list entries is this task's alone.
                                unsafe { blocks_out.part(range.start, range.len()) }
                            } else {
                                scratch.resize(range.len(), 0);
                                &mut scratch[..]
                            };
                            // SAFETY: tile t is this task's alone.
                            unsafe {
                                blend::forward_tile(list, tile, settings.background, &sink, blocks)
                            }
                        }
                        BlendKernels::Scalar => {
                            let out = scalar_blend::forward_tile(
                                &bins,
                                &splats,
                                t,
                                w,
                                h,
                                settings.background,
                            );
                            let tw = tile.2 as usize;
                            // SAFETY: tile t is this task's alone.
                            unsafe {
                                sink.write_tile(tile, |lx, ly| {
                                    let i = ly * tw + lx;
                                    PixelOut {
                                        color: out.color[i],
                                        alpha: out.alpha[i],
                                        depth: out.depth[i],
                                        final_t: out.final_t[i],
                                        n_contrib: out.n_contrib[i],
                                    }
                                })
                            };
                            out.blended
                        }
                    }
                },
            )
            .sum::<u64>()
    };
    let radii = projected.par_iter().map(|p| p.radius).collect();
    let visible = projected
        .par_iter()
        .map(|p| p.radius[0] > 0 || p.radius[1] > 0)
        .collect();
    let state = keep.then(|| ForwardState {
        kernels,
        camera: cam.clone(),
        settings: settings.clone(),
        num_gaussians: g.len(),
        splats,
        bins: bins.clone(),
        // The backward reads its own copy: callers may edit the public depth buffer.
        depth: depth.clone(),
        final_t,
        n_contrib,
        blended_blocks: keep_blocks.then_some(blended_blocks),
    });
    let out = RenderOutput {
        width: w,
        height: h,
        color,
        alpha,
        depth,
        radii,
        visible,
        num_intersections: bins.ids.len(),
        num_blended,
    };
    Ok((out, state))
}

/// Gradients of a scalar loss with respect to every parameter, in the model's layout, plus the
/// densification statistics.
#[derive(Clone, Debug)]
pub struct Gradients {
    /// Same layout as the model (`sh_rest` beyond the rendered degree stays zero).
    pub params: Gaussians,
    /// `∂L/∂mean2d` in pixels, per Gaussian.
    pub means2d: Vec<[f32; 2]>,
    /// Per-pixel `|∂L/∂mean2d|` summed over pixels, per component (gsplat `absgrad`).
    pub means2d_abs: Vec<[f32; 2]>,
}

/// Backward pass for the loss gradients `v_color` (and optionally `v_alpha`, `v_depth`) of the
/// images of the forward pass that made `st` ([`render_for_backward`] of the same model).
pub fn render_backward(
    g: &Gaussians,
    st: &ForwardState,
    v_color: &[Vec3],
    v_alpha: Option<&[f32]>,
    v_depth: Option<&[f32]>,
) -> Result<Gradients, SplatError> {
    let (cam, settings) = (&st.camera, &st.settings);
    check_inputs(g, cam, settings)?;
    if st.num_gaussians != g.len() {
        return Err(SplatError::InvalidInput(format!(
            "render_backward called with {} Gaussians, the forward pass rendered {}",
            g.len(),
            st.num_gaussians
        )));
    }
    let n_pix = cam.num_pixels();
    let size = |what, got: usize| {
        if got == n_pix {
            Ok(())
        } else {
            Err(SplatError::SizeMismatch {
                what,
                expected: n_pix,
                got,
            })
        }
    };
    size("v_color", v_color.len())?;
    if let Some(a) = v_alpha {
        size("v_alpha", a.len())?;
    }
    if let Some(d) = v_depth {
        size("v_depth", d.len())?;
    }
    let finite = |v: Option<&[f32]>| v.is_none_or(|a| a.iter().all(|x| x.is_finite()));
    if !v_color.iter().all(|v| v.is_finite()) || !finite(v_alpha) || !finite(v_depth) {
        return Err(SplatError::InvalidInput(
            "pixel gradients are not finite".into(),
        ));
    }

    let bins = &st.bins;
    let (w, h) = (cam.width, cam.height);
    let pix = PixelGrads {
        v_color,
        v_alpha,
        v_depth,
        depth: &st.depth,
        final_t: &st.final_t,
        n_contrib: &st.n_contrib,
    };
    // Per-Gaussian ranges of the intersection records, each in tile order (a stable counting
    // sort of the tile lists), and where each tile-list position's record goes.
    let n = g.len();
    let n_isect = bins.ids.len();
    let mut starts = vec![0usize; n + 1];
    for &id in &bins.ids {
        starts[id as usize + 1] += 1;
    }
    for i in 0..n {
        starts[i + 1] += starts[i];
    }
    let mut cursor = starts.clone();
    let dest: Vec<usize> = bins
        .ids
        .iter()
        .map(|&id| {
            let d = cursor[id as usize];
            cursor[id as usize] += 1;
            d
        })
        .collect();
    drop(cursor);

    // Each tile's records go straight to their Gaussian's range (scattered writes, which do
    // not stall as the scattered reads of gathering them per Gaussian afterwards did). Not
    // zero-filled: each tile's kernel writes every slot of its list, and `dest` is a
    // permutation of `0 .. n_isect`.
    let mut isect: Vec<IsectGrad> = Vec::with_capacity(n_isect);
    {
        let by_gaussian = Disjoint::new(&mut isect.spare_capacity_mut()[..n_isect]);
        (0..bins.num_tiles()).into_par_iter().for_each_init(
            || (Vec::new(), Vec::new(), blend::BackScratch::default()),
            |(list, out, scratch), t| {
                let range = bins.range(t);
                out.clear();
                out.resize(range.len(), std::mem::MaybeUninit::uninit());
                match st.kernels {
                    BlendKernels::Lanes => {
                        stages::gather_into(bins, &st.splats, t, list);
                        blend::backward_tile(
                            list,
                            stages::tile_pixels(bins, t, w, h),
                            w,
                            settings.background,
                            &pix,
                            out,
                            st.blended_blocks.as_ref().map(|b| &b[range.clone()]),
                            scratch,
                        )
                    }
                    BlendKernels::Scalar => scalar_blend::backward_tile(
                        bins,
                        &st.splats,
                        t,
                        w,
                        h,
                        settings.background,
                        &pix,
                        out,
                    ),
                }
                for (&d, rec) in dest[range].iter().zip(out.iter()) {
                    // SAFETY: `dest` is a permutation, so no other task writes slot `d`.
                    unsafe { by_gaussian.write(d, *rec) };
                }
            },
        );
    }
    // SAFETY: `dest` covers `0 .. n_isect` and both kernels write every slot of their tile's
    // list (their documented contract), each copied to its `dest`.
    unsafe { isect.set_len(n_isect) };

    // Two passes: first each Gaussian's records (contiguous, in tile order) summed into one
    // compact record, then the compute-heavy projection backward over contiguous data.
    let screen: Vec<(ScreenGrad, glam::Vec2)> = (0..n)
        .into_par_iter()
        .map(|i| {
            let mut sg = ScreenGrad::default();
            let mut abs = glam::Vec2::ZERO;
            for p in &isect[starts[i]..starts[i + 1]] {
                sg.mean2d += p.mean2d;
                abs += p.mean2d_abs;
                for k in 0..3 {
                    sg.conic[k] += p.conic[k];
                }
                sg.color += p.color;
                sg.opacity += p.opacity;
                sg.depth += p.depth;
            }
            (sg, abs)
        })
        .collect();
    drop(isect);
    let r = gradients_from_screen(g, cam, settings, &screen, &st.splats, |i| {
        starts[i] != starts[i + 1]
    });
    Ok(r)
}

/// Parameter gradients from the per-Gaussian screen-space gradients (with the sums of
/// `|∂L/∂mean2d|`) of a backward pass over the pixels; `splats`: the forward's screen-space
/// splats (their colours); `touched(i)`: Gaussian `i` was in some tile's list.
pub(crate) fn gradients_from_screen(
    g: &Gaussians,
    cam: &Camera,
    settings: &RenderSettings,
    screen: &[(ScreenGrad, glam::Vec2)],
    splats: &[stages::Splat],
    touched: impl Fn(usize) -> bool + Sync,
) -> Gradients {
    let n = g.len();
    let rc = g.rest_count();
    // Built in parallel, field by field: serial zero-filling and copying of these buffers
    // would be a large part of a step's serial time.
    let mut sh_rest: Vec<Vec3> = (0..n * rc).into_par_iter().map(|_| Vec3::ZERO).collect();
    // Eight Gaussians at a time ([`project_backward_lanes`]), each block writing its own
    // slots of the results and of the SH buffer.
    let mut results: Vec<(ParamGrad, [f32; 2], [f32; 2])> = Vec::with_capacity(n);
    {
        let rest = Disjoint::new(&mut sh_rest);
        results.spare_capacity_mut()[..n]
            .par_chunks_mut(LANES)
            .enumerate()
            .for_each(|(b, slots)| {
                let first = b * LANES;
                let count = slots.len();
                let part = &screen[first..first + count];
                let last = count - 1;
                let sg: [ScreenGrad; LANES] = std::array::from_fn(|l| part[l.min(last)].0);
                let colors: [Vec3; LANES] =
                    std::array::from_fn(|l| splats[first + l.min(last)].color());
                let touched = std::array::from_fn(|l| l < count && touched(first + l));
                // SAFETY: the SH part of Gaussians `first .. first + count` is this block's.
                let v_rest = unsafe { rest.part(first * rc, count * rc) };
                let at = Block {
                    g,
                    first,
                    cam,
                    sh_degree: settings.sh_degree,
                    antialiased: settings.antialiased,
                };
                let from = BackwardIn {
                    colors: &colors[..count],
                    screen: &sg[..count],
                    touched,
                };
                let grads = project_backward_lanes(&at, &from, v_rest);
                for (l, slot) in slots.iter_mut().enumerate() {
                    let (s, abs) = &part[l];
                    slot.write((grads[l], [s.mean2d.x, s.mean2d.y], [abs.x, abs.y]));
                }
            });
    }
    // SAFETY: the chunks cover `0 .. n` and every slot of each was written.
    unsafe { results.set_len(n) };
    let grads = Gaussians {
        means: results.par_iter().map(|r| r.0.mean).collect(),
        log_scales: results.par_iter().map(|r| r.0.log_scale).collect(),
        rotations: results.par_iter().map(|r| r.0.rotation).collect(),
        logit_opacities: results.par_iter().map(|r| r.0.logit_opacity).collect(),
        sh_dc: results.par_iter().map(|r| r.0.sh_dc).collect(),
        sh_rest,
        sh_degree: g.sh_degree,
    };
    let means2d = results.par_iter().map(|r| r.1).collect();
    let means2d_abs = results.par_iter().map(|r| r.2).collect();
    Gradients {
        params: grads,
        means2d,
        means2d_abs,
    }
}
