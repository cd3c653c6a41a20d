//! The wgpu rasterizer: the CPU renderer's stages as compute shaders (one WGSL file per stage
//! in `wgsl/`), behind the same [`Rasterizer`] interface and tested against the CPU renderer
//! and the float64 reference.
//!
//! Stages of a render: projection and culling with SH colour and per-Gaussian tile counts →
//! exclusive scan → key emission → stable radix sort of (tile, depth) keys → per-tile ranges
//! → front-to-back blending in 16×16 workgroups. The model is uploaded once per scene
//! ([`Rasterizer::upload`]); a render reads back one count (to size the keys) and its images.
//! The backward pass blends back to front per tile and sums each (tile, splat) pair's pixel
//! contributions with a fixed-order tree into the pair's own slot, then sums each Gaussian's
//! slots: no float atomics, so it is deterministic. The projection backward (screen-space to
//! parameter gradients, SH and quaternion included) runs on the GPU as well; the host reads
//! back the parameter gradients and the screen-space mean gradients densification uses.

mod context;
mod pipelines;
#[doc(hidden)]
pub mod sort;
mod training;
mod util;

use std::sync::Arc;

use glam::Vec3;

pub use crate::trainer::StepReport;
pub use context::GpuContext;
pub use training::{GpuTrainer, GpuTraining};
pub use wgpu::DeviceType;

use crate::camera::Camera;
use crate::conventions::TILE_SIZE;
use crate::cpu::render::{Gradients, RenderOutput, RenderSettings};
use crate::error::SplatError;
use crate::model::Gaussians;
use crate::rasterizer::{PixelGradients, Rasterizer};
use pipelines::Pipelines;
use sort::{KeyBuffers, radix_sort, scan};
use util::{
    Scratch, bind, bind_resources, blocks, dispatch, f32s, grid, part, read_back, storage,
    storage_init, u32s, uniform,
};

/// Floats per projected Gaussian (`PROJ_STRIDE` in the shaders).
const PROJ_STRIDE: u64 = 12;

/// Pieces of a parameter buffer start at multiples of this many Gaussians: 256 bytes per
/// float of a Gaussian, the largest storage offset alignment WebGPU allows.
pub const CHUNK_ALIGN: u32 = 64;

/// The uniform naming a piece (`Chunk` in the shaders).
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct ChunkUniform {
    first: u32,
    count: u32,
}

/// The rasterizer on one GPU. Cheap to clone: the device and pipelines are shared.
#[derive(Clone)]
pub struct GpuRasterizer {
    ctx: Arc<GpuContext>,
    kernels: Arc<Pipelines>,
    /// Bytes one binding may span: per-Gaussian parameter buffers larger than this are bound
    /// and processed in pieces ([`GpuRasterizer::chunks`]).
    max_binding: u64,
}

/// A model resident on the GPU: its parameters in one buffer, Gaussian by Gaussian (the
/// layout of [`Gaussians::packed`]). It does not borrow the host model: the lifetime is the
/// [`Rasterizer`] interface's, for renderers whose scenes do.
pub struct GpuScene<'a> {
    _model: std::marker::PhantomData<&'a Gaussians>,
    params: wgpu::Buffer,
    n: u32,
    sh_degree: u32,
    stride: u32,
}

impl GpuScene<'_> {
    pub fn len(&self) -> usize {
        self.n as usize
    }

    pub fn is_empty(&self) -> bool {
        self.n == 0
    }
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct CameraUniform {
    r0: [f32; 4],
    r1: [f32; 4],
    r2: [f32; 4],
    t: [f32; 4],
    intr: [f32; 4],
    lim: [f32; 4],
    pos: [f32; 4],
    bg: [f32; 4],
    dims: [u32; 4],
    cfg: [u32; 4],
}

impl GpuRasterizer {
    /// Opens the best adapter there is; an error that says why when there is none.
    pub fn new() -> Result<Self, SplatError> {
        Ok(Self::on(Arc::new(GpuContext::new()?)))
    }

    /// The rasterizer on an already opened device.
    pub fn on(ctx: Arc<GpuContext>) -> Self {
        let kernels = Arc::new(Pipelines::new(&ctx.device));
        let l = &ctx.limits;
        let max_binding = l.max_storage_buffer_binding_size.min(l.max_buffer_size);
        Self {
            ctx,
            kernels,
            max_binding,
        }
    }

    /// The same rasterizer binding at most `bytes` of a buffer at once (at least one piece of
    /// [`CHUNK_ALIGN`] Gaussians), so tests can split small scenes the way a small-limit driver
    /// splits large ones.
    #[doc(hidden)]
    pub fn with_binding_limit(mut self, bytes: u64) -> Self {
        self.max_binding = bytes.min(self.max_binding);
        self
    }

    /// The pieces `(first, count)` in which `n` Gaussians of `stride` floats each are bound:
    /// as large as one binding allows, each starting at a multiple of [`CHUNK_ALIGN`] Gaussians
    /// (so its byte offset meets every device's storage offset alignment).
    #[doc(hidden)]
    pub fn chunks(&self, n: u32, stride: u32) -> Vec<(u32, u32)> {
        let fits = self.max_binding / (4 * stride as u64);
        let size = (fits / CHUNK_ALIGN as u64 * CHUNK_ALIGN as u64)
            .clamp(CHUNK_ALIGN as u64, u32::MAX as u64) as u32;
        (0..n.div_ceil(size))
            .map(|k| (k * size, size.min(n - k * size)))
            .collect()
    }

    /// Dispatches a projection pass (`kernel`, forward or backward) once per chunk of the
    /// scene's parameters, each bound as both passes lay them out: the camera, the chunk's
    /// parameters, the three buffers `middle` gives for the chunk's byte range `(at, len)`,
    /// and the chunk's uniform.
    fn per_parameter_chunk<'a>(
        &self,
        enc: &mut wgpu::CommandEncoder,
        kernel: &wgpu::ComputePipeline,
        scene: &'a GpuScene,
        n: u32,
        cam_u: &'a wgpu::Buffer,
        middle: impl Fn(u64, u64) -> [wgpu::BindingResource<'a>; 3],
    ) {
        let dev = &self.ctx.device;
        let bytes = 4 * scene.stride as u64;
        for (first, count) in self.chunks(n, scene.stride) {
            let chunk = ChunkUniform { first, count };
            let chunk = uniform(dev, "chunk", bytemuck::bytes_of(&chunk));
            let (at, len) = (bytes * first as u64, bytes * count as u64);
            let [a, b, c] = middle(at, len);
            let g = bind_resources(
                dev,
                kernel,
                vec![
                    cam_u.as_entire_binding(),
                    part(&scene.params, at, len),
                    a,
                    b,
                    c,
                    chunk.as_entire_binding(),
                ],
            );
            dispatch(enc, kernel, &g, grid(blocks(count)));
        }
    }

    pub fn context(&self) -> &GpuContext {
        &self.ctx
    }

    /// [`Rasterizer::upload`] of a scene that can outlive `g` (a viewer keeps one scene for
    /// as long as it shows it).
    pub fn upload_static(&self, g: &Gaussians) -> Result<GpuScene<'static>, SplatError> {
        g.validate()?;
        let n = u32::try_from(g.len()).map_err(|_| {
            SplatError::Gpu(format!("{} splats are too many for one scene", g.len()))
        })?;
        let stride = 14 + 3 * g.rest_count() as u32;
        // Bound in pieces: only the whole buffer must fit the device.
        self.ctx
            .check_buffer("the splat parameters", 4 * stride as u64 * n as u64)?;
        let params = g.packed();
        let params = storage_init(&self.ctx.device, "splats", bytemuck::cast_slice(&params));
        let sh_degree = g.sh_degree;
        Ok(GpuScene {
            _model: std::marker::PhantomData,
            params,
            n,
            sh_degree,
            stride,
        })
    }

    fn forward(
        &self,
        scene: &GpuScene,
        cam: &Camera,
        settings: &RenderSettings,
        scratch: &mut Scratch,
    ) -> Result<(RenderOutput, GpuSaved), SplatError> {
        cam.validate()?;
        if settings.sh_degree > scene.sh_degree {
            return Err(SplatError::InvalidInput(format!(
                "render sh_degree {} exceeds the model's stored degree {}",
                settings.sh_degree, scene.sh_degree
            )));
        }
        if !settings.background.is_finite() {
            return Err(SplatError::InvalidInput("background is not finite".into()));
        }
        let (ctx, k) = (&*self.ctx, &*self.kernels);
        let dev = &ctx.device;
        let n = scene.n;
        let (w, h) = (cam.width, cam.height);
        let (tiles_x, tiles_y) = (w.div_ceil(TILE_SIZE), h.div_ceil(TILE_SIZE));
        let np = w as u64 * h as u64;
        ctx.check_size("the projected splats", 4 * PROJ_STRIDE * n as u64)?;
        ctx.check_size("the rendered images", 4 * 5 * np)?;

        let rows = cam.rotation.transpose();
        let lim = crate::cpu::project::clamp_limits(cam);
        let pos = cam.position();
        let row = |v: Vec3, w: f32| [v.x, v.y, v.z, w];
        let cu = CameraUniform {
            r0: row(rows.x_axis, 0.0),
            r1: row(rows.y_axis, 0.0),
            r2: row(rows.z_axis, 0.0),
            t: row(cam.translation, cam.near),
            intr: [cam.fx, cam.fy, cam.cx, cam.cy],
            lim,
            pos: row(pos, cam.far),
            bg: row(settings.background, 0.0),
            dims: [w, h, tiles_x, tiles_y],
            cfg: [
                n,
                settings.sh_degree,
                scene.stride,
                settings.antialiased as u32,
            ],
        };
        let cam_u = uniform(dev, "camera", bytemuck::bytes_of(&cu));
        let proj = scratch.storage(dev, "projected", 4 * PROJ_STRIDE * n as u64);
        let counts = scratch.storage(dev, "tile counts", 4 * n as u64);
        let offsets = scratch.storage(dev, "tile offsets", 4 * n as u64);
        let radii = scratch.storage(dev, "radii", 8 * n as u64);

        // Projection and the scan of tile counts; read back how many keys there are.
        let mut enc = dev.create_command_encoder(&Default::default());
        let total = if n > 0 {
            self.per_parameter_chunk(&mut enc, &k.project, scene, n, &cam_u, |_, _| {
                [
                    proj.as_entire_binding(),
                    counts.as_entire_binding(),
                    radii.as_entire_binding(),
                ]
            });
            scan(dev, k, &mut enc, &counts, &offsets, n, scratch);
            let last = 4 * (n as u64 - 1);
            let b = read_back(
                dev,
                &ctx.queue,
                enc,
                &[(&offsets, last, 4), (&counts, last, 4)],
            )?;
            let (o, c) = (u32s(&b[0])[0] as u64, u32s(&b[1])[0] as u64);
            enc = dev.create_command_encoder(&Default::default());
            o + c
        } else {
            0
        };
        ctx.check_size("the tile keys", 4 * total)?;
        let total = u32::try_from(total).map_err(|_| {
            SplatError::Gpu(format!("{total} tile keys are more than a u32 counts"))
        })?;

        // Keys, sort, ranges, blending.
        let a = KeyBuffers::new(dev, total, scratch);
        let b = KeyBuffers::new(dev, total, scratch);
        let owner = scratch.storage(dev, "key owners", 4 * total as u64);
        if total > 0 {
            let g = bind(
                dev,
                &k.keys,
                &[
                    &cam_u, &proj, &offsets, &a.hi, &a.lo, &a.val, &counts, &owner,
                ],
            );
            dispatch(&mut enc, &k.keys, &g, grid(blocks(n)));
        }
        let num_tiles = tiles_x * tiles_y;
        let hi_bits = 32 - (num_tiles.max(2) - 1).leading_zeros();
        let sorted = if radix_sort(dev, k, &mut enc, (&a, &b), total, hi_bits, scratch) {
            b
        } else {
            a
        };
        let ranges = scratch.storage(dev, "tile ranges", 8 * num_tiles as u64);
        enc.clear_buffer(&ranges, 0, None);
        if total > 0 {
            let len = uniform(dev, "keys len", bytemuck::bytes_of(&total));
            let g = bind(dev, &k.ranges, &[&len, &sorted.hi, &ranges]);
            dispatch(&mut enc, &k.ranges, &g, grid(blocks(total)));
        }
        let out = scratch.storage(dev, "images", 4 * 5 * np);
        let state = scratch.storage(dev, "pixel state", 4 * 2 * np);
        let stats = scratch.storage(dev, "stats", 4);
        enc.clear_buffer(&stats, 0, None);
        let g = bind(
            dev,
            &k.raster,
            &[
                &cam_u,
                &proj,
                &sorted.val,
                &ranges,
                &out,
                &state,
                &stats,
                &owner,
            ],
        );
        dispatch(&mut enc, &k.raster, &g, (tiles_x, tiles_y));
        let bytes = read_back(
            dev,
            &ctx.queue,
            enc,
            &[
                (&out, 0, 4 * 5 * np),
                (&radii, 0, 8 * n as u64),
                (&stats, 0, 4),
            ],
        )?;
        let img = f32s(&bytes[0]);
        let np = np as usize;
        let color = img[..3 * np]
            .chunks_exact(3)
            .map(|c| Vec3::new(c[0], c[1], c[2]))
            .collect();
        let radii: Vec<[i32; 2]> = f32s(&bytes[1])
            .chunks_exact(2)
            .map(|r| [r[0] as i32, r[1] as i32])
            .collect();
        let output = RenderOutput {
            width: w,
            height: h,
            color,
            alpha: img[3 * np..4 * np].to_vec(),
            depth: img[4 * np..5 * np].to_vec(),
            visible: radii.iter().map(|r| r[0] > 0 || r[1] > 0).collect(),
            radii,
            num_intersections: total as usize,
            num_blended: u32s(&bytes[2])[0] as u64,
        };
        let saved = GpuSaved {
            camera: cam.clone(),
            generation: scratch.0.as_ref().map(|p| p.generation()),
            n,
            total,
            tiles: (tiles_x, tiles_y),
            cam_u,
            proj,
            values: sorted.val,
            owner,
            ranges,
            offsets,
            counts,
            out,
            state,
        };
        Ok((output, saved))
    }

    /// Records the backward pass into `enc`: the screen-space gradients (12 floats per
    /// Gaussian) and the parameter gradients (the parameters' layout), left on the GPU.
    fn encode_backward(
        &self,
        scene: &GpuScene,
        st: &GpuSaved,
        pixel: PixelGradients<'_>,
        enc: &mut wgpu::CommandEncoder,
        scratch: &mut Scratch,
    ) -> Result<(wgpu::Buffer, wgpu::Buffer), SplatError> {
        if st
            .generation
            .is_some_and(|g| scratch.0.as_ref().is_none_or(|p| p.generation() != g))
        {
            return Err(SplatError::InvalidInput(
                "backward of a render whose working buffers a later render reused".into(),
            ));
        }
        if scene.n != st.n {
            return Err(SplatError::InvalidInput(format!(
                "backward called with {} Gaussians, the forward pass rendered {}",
                scene.n, st.n
            )));
        }
        let np = st.camera.num_pixels();
        let size = |what, got: usize| {
            if got == np {
                Ok(())
            } else {
                Err(SplatError::SizeMismatch {
                    what,
                    expected: np,
                    got,
                })
            }
        };
        size("v_color", pixel.color.len())?;
        if let Some(a) = pixel.alpha {
            size("v_alpha", a.len())?;
        }
        if let Some(d) = pixel.depth {
            size("v_depth", d.len())?;
        }
        let finite = |v: Option<&[f32]>| v.is_none_or(|a| a.iter().all(|x| x.is_finite()));
        if !pixel.color.iter().all(|v| v.is_finite())
            || !finite(pixel.alpha)
            || !finite(pixel.depth)
        {
            return Err(SplatError::InvalidInput(
                "pixel gradients are not finite".into(),
            ));
        }
        let (ctx, k) = (&*self.ctx, &*self.kernels);
        let dev = &ctx.device;
        // Absent gradients are zeros: the same arithmetic as the CPU's `None`.
        let mut pix = Vec::with_capacity(5 * np);
        pix.extend(pixel.color.iter().flat_map(|c| c.to_array()));
        pix.extend_from_slice(pixel.alpha.unwrap_or(&vec![0.0; np]));
        pix.extend_from_slice(pixel.depth.unwrap_or(&vec![0.0; np]));
        let pix = scratch.storage_init(
            dev,
            &ctx.queue,
            "pixel gradients",
            bytemuck::cast_slice(&pix),
        );
        ctx.check_size("the tile gradients", 48 * st.total as u64)?;
        let isect = scratch.storage(dev, "tile gradients", 48 * st.total as u64);
        let screen = scratch.storage(dev, "screen gradients", 48 * st.n as u64);
        enc.clear_buffer(&isect, 0, None);
        let bg = bind(
            dev,
            &k.raster_backward,
            &[
                &st.cam_u, &st.proj, &st.values, &st.owner, &st.ranges, &st.state, &st.out, &pix,
                &isect,
            ],
        );
        dispatch(enc, &k.raster_backward, &bg, st.tiles);
        let grad_bytes = 4 * scene.stride as u64 * st.n as u64;
        ctx.check_buffer("the parameter gradients", grad_bytes)?;
        let grads = scratch.storage(dev, "parameter gradients", grad_bytes);
        if st.n > 0 {
            let len = uniform(dev, "gaussians", bytemuck::bytes_of(&st.n));
            let bg = bind(
                dev,
                &k.isect_reduce,
                &[&len, &st.offsets, &st.counts, &isect, &screen],
            );
            dispatch(enc, &k.isect_reduce, &bg, grid(blocks(st.n)));
            let pass = &k.project_backward;
            self.per_parameter_chunk(enc, pass, scene, st.n, &st.cam_u, |at, len| {
                [
                    screen.as_entire_binding(),
                    st.counts.as_entire_binding(),
                    part(&grads, at, len),
                ]
            });
        }
        Ok((screen, grads))
    }

    fn backward_pass(
        &self,
        scene: &GpuScene,
        st: &GpuSaved,
        pixel: PixelGradients<'_>,
    ) -> Result<Gradients, SplatError> {
        let dev = &self.ctx.device;
        let mut enc = dev.create_command_encoder(&Default::default());
        let (screen, grads) =
            self.encode_backward(scene, st, pixel, &mut enc, &mut Scratch::fresh())?;
        let n = st.n as u64;
        let bytes = read_back(
            dev,
            &self.ctx.queue,
            enc,
            &[
                (&screen, 0, 48 * n),
                (&grads, 0, 4 * scene.stride as u64 * n),
            ],
        )?;
        let sg = f32s(&bytes[0]);
        let params = Gaussians::from_packed(&f32s(&bytes[1]), scene.sh_degree)?;
        Ok(Gradients {
            params,
            means2d: sg.chunks_exact(12).map(|v| [v[0], v[1]]).collect(),
            means2d_abs: sg.chunks_exact(12).map(|v| [v[2], v[3]]).collect(),
        })
    }
}

#[doc(hidden)]
impl GpuRasterizer {
    /// The GPU exclusive scan on its own, for tests against a CPU scan.
    pub fn exclusive_scan(&self, values: &[u32]) -> Result<Vec<u32>, SplatError> {
        let dev = &self.ctx.device;
        let n = values.len() as u32;
        let input = storage_init(dev, "scan in", bytemuck::cast_slice(values));
        let output = storage(dev, "scan out", 4 * n as u64);
        let mut enc = dev.create_command_encoder(&Default::default());
        scan(
            dev,
            &self.kernels,
            &mut enc,
            &input,
            &output,
            n,
            &mut Scratch::fresh(),
        );
        let b = read_back(dev, &self.ctx.queue, enc, &[(&output, 0, 4 * n as u64)])?;
        Ok(u32s(&b[0]))
    }

    /// The GPU radix sort on its own: `(hi, lo, value)` triples sorted stably by `(hi, lo)`.
    pub fn sort_pairs(
        &self,
        hi: &[u32],
        lo: &[u32],
        values: &[u32],
        hi_bits: u32,
    ) -> Result<Vec<(u32, u32, u32)>, SplatError> {
        let dev = &self.ctx.device;
        let n = hi.len() as u32;
        let a = KeyBuffers {
            hi: storage_init(dev, "hi", bytemuck::cast_slice(hi)),
            lo: storage_init(dev, "lo", bytemuck::cast_slice(lo)),
            val: storage_init(dev, "val", bytemuck::cast_slice(values)),
        };
        let b = KeyBuffers::new(dev, n, &mut Scratch::fresh());
        let mut enc = dev.create_command_encoder(&Default::default());
        let s = if radix_sort(
            dev,
            &self.kernels,
            &mut enc,
            (&a, &b),
            n,
            hi_bits,
            &mut Scratch::fresh(),
        ) {
            &b
        } else {
            &a
        };
        let bytes = 4 * n as u64;
        let r = read_back(
            dev,
            &self.ctx.queue,
            enc,
            &[(&s.hi, 0, bytes), (&s.lo, 0, bytes), (&s.val, 0, bytes)],
        )?;
        let (h, l, v) = (u32s(&r[0]), u32s(&r[1]), u32s(&r[2]));
        Ok((0..n as usize).map(|i| (h[i], l[i], v[i])).collect())
    }
}

/// What a GPU forward pass keeps for its backward pass: its buffers, still on the GPU.
pub struct GpuSaved {
    camera: Camera,
    /// The pool generation whose buffers these are (None: buffers of its own).
    generation: Option<u64>,
    n: u32,
    total: u32,
    tiles: (u32, u32),
    cam_u: wgpu::Buffer,
    proj: wgpu::Buffer,
    values: wgpu::Buffer,
    owner: wgpu::Buffer,
    ranges: wgpu::Buffer,
    offsets: wgpu::Buffer,
    counts: wgpu::Buffer,
    out: wgpu::Buffer,
    state: wgpu::Buffer,
}

impl Rasterizer for GpuRasterizer {
    type Scene<'a> = GpuScene<'a>;
    type Saved = GpuSaved;

    fn name(&self) -> &str {
        "gpu"
    }

    fn upload<'a>(&'a self, g: &'a Gaussians) -> Result<GpuScene<'a>, SplatError> {
        self.upload_static(g)
    }

    fn render(
        &self,
        scene: &GpuScene,
        cam: &Camera,
        settings: &RenderSettings,
    ) -> Result<RenderOutput, SplatError> {
        self.forward(scene, cam, settings, &mut Scratch::fresh())
            .map(|(out, _)| out)
    }

    fn render_for_backward(
        &self,
        scene: &GpuScene,
        cam: &Camera,
        settings: &RenderSettings,
    ) -> Result<(RenderOutput, GpuSaved), SplatError> {
        self.forward(scene, cam, settings, &mut Scratch::fresh())
    }

    fn backward(
        &self,
        scene: &GpuScene,
        saved: &GpuSaved,
        pixel: PixelGradients<'_>,
    ) -> Result<Gradients, SplatError> {
        self.backward_pass(scene, saved, pixel)
    }
}
