//! `metasplat render`: any splat scene from a capture's cameras or its LLFF spiral, or without
//! a capture from an orbit around the splats or one given camera.

use anyhow::{Context, Result, bail};
use clap::Args;
use glam::Vec3;
use metasplat::device::{Device, DeviceChoice};
use metasplat::outputs::render_named;
use std::path::PathBuf;

#[derive(Args)]
pub struct RenderArgs {
    /// Splat scene (.ply in the INRIA layout, .glb or .gltf with KHR_gaussian_splatting, or
    /// .spz).
    #[arg(long, visible_alias = "scene-file")]
    pub ply: PathBuf,
    /// Capture whose cameras (or spiral) to render from; without it, an orbit around the
    /// splats (or --camera).
    #[arg(long)]
    pub scene: Option<PathBuf>,
    #[arg(long)]
    pub out: PathBuf,
    /// Render N frames of the LLFF spiral instead of the capture's cameras.
    #[arg(long, requires = "scene", value_parser = clap::value_parser!(u32).range(1..=10_000))]
    pub spiral: Option<u32>,
    #[arg(long, default_value_t = 8, value_parser = clap::value_parser!(u32).range(1..=64))]
    pub downsample: u32,
    /// Without --scene: frames of an orbit around the splats' bounds.
    #[arg(long, default_value_t = 30, conflicts_with_all = ["scene", "camera"], value_parser = clap::value_parser!(u32).range(1..=10_000))]
    pub orbit: u32,
    /// Without --scene: one frame from EYE looking at TARGET, as "ex,ey,ez,tx,ty,tz".
    #[arg(long, conflicts_with = "scene", value_parser = parse_camera, allow_hyphen_values = true)]
    pub camera: Option<[f32; 6]>,
    /// Image size without --scene.
    #[arg(long, default_value_t = 640, value_parser = clap::value_parser!(u32).range(8..=8192))]
    pub width: u32,
    #[arg(long, default_value_t = 480, value_parser = clap::value_parser!(u32).range(8..=8192))]
    pub height: u32,
    /// Vertical field of view (degrees) without --scene.
    #[arg(long, default_value_t = 50.0, value_parser = metasplat::flags::field_angle, allow_negative_numbers = true)]
    pub fov: f64,
    /// Where to render: `auto` (a hardware GPU when there is one), `cpu`, or `gpu`.
    #[arg(long, value_enum, default_value_t = DeviceChoice::Auto)]
    pub device: DeviceChoice,
}

fn parse_camera(s: &str) -> Result<[f32; 6], String> {
    let v: Vec<f32> = s
        .split(',')
        .map(|x| x.trim().parse::<f32>())
        .collect::<Result<_, _>>()
        .map_err(|_| format!("'{s}' is not six numbers ex,ey,ez,tx,ty,tz"))?;
    let v: [f32; 6] = v
        .try_into()
        .map_err(|_| format!("'{s}' is not six numbers ex,ey,ez,tx,ty,tz"))?;
    if v.iter().any(|x| !x.is_finite()) || v[..3] == v[3..] {
        return Err(format!(
            "'{s}': finite numbers, and the eye apart from the target"
        ));
    }
    Ok(v)
}

pub fn run(a: RenderArgs) -> Result<()> {
    let mut inputs = vec![("--ply", a.ply.as_path())];
    if let Some(s) = &a.scene {
        inputs.push(("--scene", s));
    }
    metasplat::guard::refuse_overwrite("--out", &a.out, &inputs)?;
    let (device, note) = Device::choose(a.device)?;
    let model = splat::files::read_splats(&a.ply)?;
    if model.is_empty() {
        bail!("{}: the scene has no splats", a.ply.display());
    }
    let cameras: Vec<(String, splat::Camera)> = match &a.scene {
        Some(dir) => {
            let capture = super::open_scene(dir, a.downsample)?;
            let cams = match a.spiral {
                Some(n) => metasplat::spiral::spiral(&capture.cameras, &capture.bounds, n as usize),
                None => capture.cameras.clone(),
            };
            cams.iter()
                .map(|c| (c.name.clone(), metasplat::convert::splat_camera(c)))
                .collect()
        }
        None => free_cameras(&a, &model)?,
    };
    let settings = splat::RenderSettings {
        sh_degree: model.sh_degree,
        ..Default::default()
    };
    let start = std::time::Instant::now();
    println!("{note}");
    // All or nothing: the frames go to a staging folder beside --out and move in at the end,
    // so a failure (a full disk) leaves no partial frame set.
    let parent = match a.out.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    std::fs::create_dir_all(&parent)
        .with_context(|| format!("cannot create {}", parent.display()))?;
    // A killed render's staging folder is removed before this one stages its own.
    base::remove_orphans(&parent)
        .with_context(|| format!("cannot clear old staging folders in {}", parent.display()))?;
    let staging = tempfile::Builder::new()
        .prefix(&format!("{}frames-", base::temp_prefix()))
        .tempdir_in(&parent)
        .with_context(|| format!("cannot stage frames in {}", parent.display()))?;
    let staged = render_named(&model, &settings, &cameras, staging.path(), &device)?;
    std::fs::create_dir_all(&a.out)
        .with_context(|| format!("cannot create {}", a.out.display()))?;
    let mut written = Vec::with_capacity(staged.len());
    for f in &staged {
        let to = a.out.join(f.file_name().expect("a frame file"));
        std::fs::rename(f, &to)
            .with_context(|| format!("cannot move a frame to {}", to.display()))?;
        written.push(to);
    }
    println!(
        "{} splats (SH degree {}) rendered to {} images {}x{} in {:.2} s under {}",
        model.len(),
        model.sh_degree,
        written.len(),
        cameras.first().map_or(0, |c| c.1.width),
        cameras.first().map_or(0, |c| c.1.height),
        start.elapsed().as_secs_f64(),
        a.out.display()
    );
    Ok(())
}

/// The viewer's default view without a capture: an orbit framing the splats' bounds, or the
/// one camera given.
fn free_cameras(a: &RenderArgs, model: &splat::Gaussians) -> Result<Vec<(String, splat::Camera)>> {
    let fov = (a.fov as f32).to_radians();
    if let Some(c) = a.camera {
        let f = 0.5 * a.height as f32 / (0.5 * fov).tan();
        let cam = splat::Camera::look_at(
            Vec3::new(c[0], c[1], c[2]),
            Vec3::new(c[3], c[4], c[5]),
            Vec3::NEG_Y,
            f,
            f,
            a.width,
            a.height,
        );
        return Ok(vec![("camera".into(), cam)]);
    }
    let Some((center, radius)) = splat::camera::scene_bounds(&model.means) else {
        bail!("{}: no splat has a finite position", a.ply.display());
    };
    let distance = 1.2 * radius / (0.5 * fov).sin();
    Ok((0..a.orbit)
        .map(|k| {
            let angle = std::f32::consts::TAU * k as f32 / a.orbit as f32;
            let cam = splat::Camera::orbit(center, distance, angle, 0.3, fov, a.width, a.height);
            (format!("orbit{k:03}"), cam)
        })
        .collect())
}
