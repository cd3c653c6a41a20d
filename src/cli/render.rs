//! `metasplat render`: any splat scene from a capture's cameras or its LLFF spiral, or without
//! a capture from an orbit around the splats or one given camera.

use anyhow::{Context, Result, bail};
use clap::Args;
use glam::Vec3;
use metasplat::device::{Device, DeviceChoice};
use metasplat::outputs::render_named;
use std::path::PathBuf;

/// Which views `render --split` renders.
#[derive(Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum SplitChoice {
    /// The held-out views (every 8th).
    Test,
    /// The training views.
    Train,
}

#[derive(Args)]
pub struct RenderArgs {
    /// Splat scene (.ply in the INRIA layout, .glb or .gltf with KHR_gaussian_splatting, or
    /// .spz).
    #[arg(long = "in", visible_aliases = ["ply", "scene-file"])]
    pub ply: PathBuf,
    /// Capture whose cameras (or spiral) to render from; without it, an orbit around the
    /// splats (or --camera).
    #[arg(long)]
    pub scene: Option<PathBuf>,
    /// The folder the frames go to (made with them, all at once).
    #[arg(long)]
    pub out: PathBuf,
    /// Render N frames of the LLFF spiral instead of the capture's cameras.
    #[arg(long, requires = "scene", value_parser = clap::value_parser!(u32).range(1..=10_000))]
    pub spiral: Option<u32>,
    /// Render one split of the capture as INRIA's `render.py` lays it out: `renders/` and
    /// `gt/` (the clean image where the capture has one, else the photo) side by side, one
    /// name per view, for other tools' metric scripts.
    #[arg(long, value_enum, requires = "scene", conflicts_with = "spiral")]
    pub split: Option<SplitChoice>,
    /// Use the capture's images_N (1: images/); default images_8/ when it exists, else the
    /// folder there is.
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=64))]
    pub downsample: Option<u32>,
    /// Without --scene: frames of an orbit around the splats' bounds.
    #[arg(long, default_value_t = 30, conflicts_with_all = ["scene", "camera"], value_parser = clap::value_parser!(u32).range(1..=10_000))]
    pub orbit: u32,
    /// Without --scene: one frame from EYE looking at TARGET, as "ex,ey,ez,tx,ty,tz".
    #[arg(long, conflicts_with = "scene", value_parser = metasplat::flags::camera_pose, allow_hyphen_values = true)]
    pub camera: Option<[f32; 6]>,
    /// Image size without --scene.
    #[arg(long, default_value_t = 640, conflicts_with = "scene", value_parser = clap::value_parser!(u32).range(8..=8192))]
    pub width: u32,
    /// Image height without --scene.
    #[arg(long, default_value_t = 480, conflicts_with = "scene", value_parser = clap::value_parser!(u32).range(8..=8192))]
    pub height: u32,
    /// Field of view (degrees) across the shorter image side, without --scene.
    #[arg(long, default_value_t = 50.0, conflicts_with = "scene", value_parser = metasplat::flags::field_angle, allow_negative_numbers = true)]
    pub fov: f64,
    /// Where to render: `auto` (a hardware GPU when there is one), `cpu`, or `gpu`.
    #[arg(long, value_enum, default_value_t = DeviceChoice::Auto)]
    pub device: DeviceChoice,
}

pub fn run(a: RenderArgs) -> Result<()> {
    splat::formats::files::Format::of(&a.ply).context("--in")?;
    let mut inputs = vec![("--in", a.ply.as_path())];
    if let Some(s) = &a.scene {
        inputs.push(("--scene", s));
    }
    let mut inputs = metasplat::guard::Inputs::of(&inputs);
    inputs.refuse("--out", &a.out)?;
    metasplat::guard::refuse_file_as_folder("--out", &a.out)?;
    let capture = match &a.scene {
        Some(dir) => {
            let capture = super::open_scene(dir, super::downsample_for(dir, a.downsample), false)?;
            // The photos the capture names, wherever its model file says they are.
            inputs.add_capture(&capture);
            inputs.refuse("--out", &a.out)?;
            Some(capture)
        }
        None => None,
    };
    let (device, note) = Device::choose(a.device)?;
    let model = splat::formats::files::read_splats(&a.ply)?;
    if model.is_empty() {
        bail!("{}: the scene has no splats", a.ply.display());
    }
    // The capture's views the split names, by index.
    let views: Option<Vec<usize>> = match (&capture, a.split) {
        (Some(c), Some(SplitChoice::Test)) => Some(c.split.test.clone()),
        (Some(c), Some(SplitChoice::Train)) => Some(c.split.train.clone()),
        _ => None,
    };
    if views.as_ref().is_some_and(|v| v.is_empty()) {
        bail!("--split: the capture has no views in that split");
    }
    let cameras: Vec<(String, splat::Camera)> = match &capture {
        Some(capture) => {
            let cams = match (a.spiral, &views) {
                (Some(n), _) => {
                    metasplat::spiral::spiral(&capture.cameras, &capture.bounds, n as usize)
                }
                (None, Some(v)) => v.iter().map(|&i| capture.cameras[i].clone()).collect(),
                (None, None) => capture.cameras.clone(),
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
    // One render into --out at a time; the lock sits beside it, so that --out appears only
    // with its frames.
    let _lock = base::FolderLock::beside(&a.out, "render")?;
    // Into a folder that exists, also the lock a training run there holds: no frames land
    // in a run folder while the run writes it.
    let _folder_lock = if a.out.is_dir() {
        Some(base::FolderLock::folder(&a.out, "render")?)
    } else {
        None
    };
    // A killed render's staging folder is removed before this one stages its own.
    base::remove_orphans(&parent);
    let staging = tempfile::Builder::new()
        .prefix(&format!("{}frames-", base::temp_prefix()))
        .tempdir_in(&parent)
        .with_context(|| format!("cannot stage frames in {}", parent.display()))?;
    // With --split, renders/ and gt/ inside --out; else the frames themselves.
    let (frames_dir, truth_dir) = match (&capture, &views) {
        (Some(capture), Some(views)) => {
            let truth = staging.path().join("gt");
            std::fs::create_dir_all(&truth)
                .with_context(|| format!("cannot stage frames in {}", parent.display()))?;
            for &i in views {
                let photo = match scenes::aberrated::load_clean_image(capture, i)? {
                    Some(clean) => clean,
                    None => capture.load_image(i)?,
                };
                let to = truth.join(format!("{}.png", capture.cameras[i].name));
                scenes::images::write_png(&to, &photo, scenes::BitDepth::Eight)?;
            }
            let renders = staging.path().join("renders");
            std::fs::create_dir_all(&renders)
                .with_context(|| format!("cannot stage frames in {}", parent.display()))?;
            (renders, Some(truth))
        }
        _ => (staging.path().to_path_buf(), None),
    };
    let staged = render_named(&model, &settings, &cameras, &frames_dir, &device)?;
    // The frames into --out (or its renders/ beside gt/), then their ground truth.
    let frames_to = match truth_dir {
        Some(_) => a.out.join("renders"),
        None => a.out.clone(),
    };
    let mut moves: Vec<(PathBuf, PathBuf)> = staged
        .iter()
        .map(|f| {
            (
                f.clone(),
                frames_to.join(f.file_name().expect("a frame file")),
            )
        })
        .collect();
    if let Some(truth) = &truth_dir {
        for e in std::fs::read_dir(truth).with_context(|| format!("{}", truth.display()))? {
            let f = e?.path();
            let to = a.out.join("gt").join(f.file_name().expect("a frame file"));
            moves.push((f, to));
        }
    }
    for (from, to) in moves {
        let dir = to.parent().expect("inside --out");
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
        std::fs::rename(&from, &to)
            .with_context(|| format!("cannot move a frame to {}", to.display()))?;
    }
    println!(
        "{} splats (SH degree {}) rendered to {} images {}x{} in {:.2} s under {}",
        model.len(),
        model.sh_degree,
        staged.len(),
        cameras.first().map_or(0, |c| c.1.width),
        cameras.first().map_or(0, |c| c.1.height),
        start.elapsed().as_secs_f64(),
        a.out.display()
    );
    if let (Some(capture), Some(_)) = (&capture, &truth_dir) {
        let truth = if capture.root.join(scenes::aberrated::CLEAN_DIR).is_dir() {
            "the clean images"
        } else {
            "the photos"
        };
        println!(
            "The renders are in {}/renders/ and {truth} beside them in {}/gt/, one name per view.",
            a.out.display(),
            a.out.display()
        );
    }
    Ok(())
}

/// The viewer's default view without a capture: an orbit around the view that frames the
/// splats' bounds, or the one camera given (both from the viewer's camera code).
fn free_cameras(a: &RenderArgs, model: &splat::Gaussians) -> Result<Vec<(String, splat::Camera)>> {
    let fov = (a.fov as f32).to_radians();
    if let Some(c) = a.camera {
        let view = viewer::ViewCamera::looking(
            Vec3::new(c[0], c[1], c[2]),
            Vec3::new(c[3], c[4], c[5]),
            fov,
        );
        return Ok(vec![("camera".into(), view.camera(a.width, a.height))]);
    }
    let Some(home) = viewer::ViewCamera::framing(&model.means, fov) else {
        bail!("{}: no splat has a finite position", a.ply.display());
    };
    Ok((0..a.orbit)
        .map(|k| {
            let mut view = home.clone();
            view.yaw = std::f32::consts::TAU * k as f32 / a.orbit as f32;
            (format!("orbit{k:03}"), view.camera(a.width, a.height))
        })
        .collect())
}
