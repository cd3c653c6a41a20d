//! `metasplat render`: any PLY from a capture's cameras or from its LLFF spiral.

use anyhow::{Context, Result};
use clap::Args;
use metasplat::device::{Device, DeviceChoice};
use metasplat::outputs::render_frames;
use std::path::PathBuf;

#[derive(Args)]
pub struct RenderArgs {
    /// Splat scene (.ply in the INRIA layout, .glb with KHR_gaussian_splatting, or .spz).
    #[arg(long, visible_alias = "scene-file")]
    pub ply: PathBuf,
    /// Capture whose cameras (or spiral) to render from.
    #[arg(long)]
    pub scene: PathBuf,
    #[arg(long)]
    pub out: PathBuf,
    /// Render N frames of the LLFF spiral instead of the capture's cameras.
    #[arg(long)]
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=10_000))]
    pub spiral: Option<u32>,
    #[arg(long, default_value_t = 8, value_parser = clap::value_parser!(u32).range(1..=64))]
    pub downsample: u32,
    /// Where to render: `auto` (a hardware GPU when there is one), `cpu`, or `gpu`.
    #[arg(long, value_enum, default_value_t = DeviceChoice::Auto)]
    pub device: DeviceChoice,
}

pub fn run(a: RenderArgs) -> Result<()> {
    let inputs = [("--ply", a.ply.as_path()), ("--scene", a.scene.as_path())];
    metasplat::guard::refuse_overwrite("--out", &a.out, &inputs)?;
    let (device, note) = Device::choose(a.device)?;
    let model = splat::files::read_splats(&a.ply)?;
    let capture = super::open_scene(&a.scene, a.downsample)?;
    let cameras = match a.spiral {
        Some(n) => metasplat::spiral::spiral(&capture.cameras, &capture.bounds, n as usize),
        None => capture.cameras.clone(),
    };
    std::fs::create_dir_all(&a.out)
        .with_context(|| format!("cannot create {}", a.out.display()))?;
    let settings = splat::RenderSettings {
        sh_degree: model.sh_degree,
        ..Default::default()
    };
    let start = std::time::Instant::now();
    println!("{note}");
    let written = render_frames(&model, &settings, &cameras, &a.out, &device)?;
    println!(
        "{} splats (SH degree {}) rendered to {} images {}x{} in {:.2} s under {}",
        model.len(),
        model.sh_degree,
        written.len(),
        cameras.first().map_or(0, |c| c.width),
        cameras.first().map_or(0, |c| c.height),
        start.elapsed().as_secs_f64(),
        a.out.display()
    );
    Ok(())
}
