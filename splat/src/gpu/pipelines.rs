//! The compute pipelines, one WGSL file per stage, each prefixed with the shared prelude and
//! with the constants of [`crate::conventions`] written in, so both renderers use one set of
//! numbers.

use crate::conventions as c;

/// The compiled stages.
pub struct Pipelines {
    pub project: wgpu::ComputePipeline,
    pub scan: wgpu::ComputePipeline,
    pub scan_add: wgpu::ComputePipeline,
    pub keys: wgpu::ComputePipeline,
    pub sort_count: wgpu::ComputePipeline,
    pub sort_scatter: wgpu::ComputePipeline,
    pub ranges: wgpu::ComputePipeline,
    pub raster: wgpu::ComputePipeline,
    pub raster_backward: wgpu::ComputePipeline,
    pub isect_reduce: wgpu::ComputePipeline,
    pub project_backward: wgpu::ComputePipeline,
    pub adam: wgpu::ComputePipeline,
}

/// The constants, as WGSL. `{:?}` prints the shortest decimal that reads back as the same f32.
fn constants() -> String {
    let f = |name: &str, v: f32| format!("const {name}: f32 = {v:?};\n");
    let mut s = format!("const TILE_SIZE: u32 = {}u;\n", c::TILE_SIZE);
    for (name, v) in [
        ("COV2D_BLUR", c::COV2D_BLUR),
        ("ALPHA_THRESHOLD", c::ALPHA_THRESHOLD),
        ("MAX_ALPHA", c::MAX_ALPHA),
        ("TRANSMITTANCE_MIN", c::TRANSMITTANCE_MIN),
        ("MAX_EXTENT_SIGMAS", c::MAX_EXTENT_SIGMAS),
        ("SH_COLOR_OFFSET", c::SH_COLOR_OFFSET),
        ("SH_C0", c::SH_C0),
        ("SH_C1", c::SH_C1),
        ("SH_C2_XY", c::SH_C2_XY),
        ("SH_C2_ZZ", c::SH_C2_ZZ),
        ("SH_C2_ZZ0", c::SH_C2_ZZ0),
        ("SH_C2_XX", c::SH_C2_XX),
        ("SH_C3_A", c::SH_C3_A),
        ("SH_C3_B", c::SH_C3_B),
        ("SH_C3_C", c::SH_C3_C),
        ("SH_C3_C0", c::SH_C3_C0),
        ("SH_C3_D", c::SH_C3_D),
        ("SH_C3_D0", c::SH_C3_D0),
    ] {
        s += &f(name, v);
    }
    s
}

/// A stage's full WGSL source: constants, prelude, then the stage.
pub fn source(stage: &str) -> String {
    format!(
        "{}{}\n{}",
        constants(),
        include_str!("wgsl/prelude.wgsl"),
        stage
    )
}

/// A projection pass's source: the splat parameters' bindings and reads
/// (`splat_params.wgsl`) before the stage, shared by the forward and the backward.
fn projection_source(stage: &str) -> String {
    format!("{}\n{stage}", include_str!("wgsl/splat_params.wgsl"))
}

fn pipeline(device: &wgpu::Device, label: &str, stage: &str) -> wgpu::ComputePipeline {
    let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some(label),
        source: wgpu::ShaderSource::Wgsl(source(stage).into()),
    });
    device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
        label: Some(label),
        layout: None,
        module: &module,
        entry_point: Some("main"),
        compilation_options: Default::default(),
        cache: None,
    })
}

impl Pipelines {
    pub fn new(device: &wgpu::Device) -> Self {
        Self {
            project: pipeline(
                device,
                "project",
                &projection_source(include_str!("wgsl/project.wgsl")),
            ),
            scan: pipeline(device, "scan", include_str!("wgsl/scan.wgsl")),
            scan_add: pipeline(device, "scan_add", include_str!("wgsl/scan_add.wgsl")),
            keys: pipeline(device, "keys", include_str!("wgsl/keys.wgsl")),
            sort_count: pipeline(device, "sort_count", include_str!("wgsl/sort_count.wgsl")),
            sort_scatter: pipeline(
                device,
                "sort_scatter",
                include_str!("wgsl/sort_scatter.wgsl"),
            ),
            ranges: pipeline(device, "ranges", include_str!("wgsl/ranges.wgsl")),
            raster: pipeline(device, "raster", include_str!("wgsl/raster.wgsl")),
            raster_backward: pipeline(
                device,
                "raster_backward",
                include_str!("wgsl/raster_backward.wgsl"),
            ),
            isect_reduce: pipeline(
                device,
                "isect_reduce",
                include_str!("wgsl/isect_reduce.wgsl"),
            ),
            project_backward: pipeline(
                device,
                "project_backward",
                &projection_source(include_str!("wgsl/project_backward.wgsl")),
            ),
            adam: pipeline(device, "adam", include_str!("wgsl/adam.wgsl")),
        }
    }
}
