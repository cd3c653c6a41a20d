//! Rendering as a job: any splat scene from a capture's cameras or its LLFF spiral, or without
//! a capture from an orbit around the splats or one given camera, into a folder of frames
//! (all or nothing), INRIA's `renders/` and `gt/`, a clean and aberrated clip pair, or one
//! video file. [`prepare`] makes every check and reads the splats, the cameras and the lens,
//! writing nothing; [`PreparedRender::run`] renders and moves the frames in.

use clap::Args;
use glam::Vec3;
use std::path::{Path, PathBuf};

use super::refused;
use crate::error::{Result, TrainError};
use crate::output::render_named;
use crate::output::video::{self, VideoFormat};
use crate::splats::device::{Device, DeviceChoice};

/// An I/O failure on `path`, said as what could not be done.
fn cannot(what: String, path: &Path) -> impl FnOnce(std::io::Error) -> TrainError {
    let path = path.to_path_buf();
    move |e| TrainError::io(path, e).context(what)
}

/// Which views `render --split` renders.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum SplitChoice {
    /// The held-out views (every 8th).
    Test,
    /// The training views.
    Train,
}

#[derive(Args, Clone, Debug)]
pub struct RenderRequest {
    /// Splat scene (.ply in the INRIA layout, .glb or .gltf with KHR_gaussian_splatting, or
    /// .spz).
    #[arg(long = "in", visible_aliases = ["ply", "scene-file"])]
    pub ply: PathBuf,
    /// Capture whose cameras (or spiral) to render from; without it, an orbit around the
    /// splats (or --camera).
    #[arg(long)]
    pub scene: Option<PathBuf>,
    /// The folder the frames go to (made with them, all at once).
    #[arg(long, required_unless_present = "video", conflicts_with = "video")]
    pub out: Option<PathBuf>,
    /// One video file of the frames instead of a folder: .mp4, .mov, .webm or .mkv through
    /// ffmpeg (when it is on the PATH), or an animated .gif written without it.
    #[arg(long)]
    pub video: Option<PathBuf>,
    /// Frames per second of --video (default: the --path file's, else 30).
    #[arg(long, requires = "video", value_parser = crate::settings::values::positive)]
    pub fps: Option<f64>,
    /// Render N frames of the LLFF spiral instead of the capture's cameras.
    #[arg(long, requires = "scene", value_parser = clap::value_parser!(u32).range(1..=10_000))]
    pub spiral: Option<u32>,
    /// Render N frames along the capture's cameras in order (positions interpolated, turns
    /// by slerp), passing through every one.
    #[arg(long, requires = "scene", conflicts_with = "spiral", value_parser = clap::value_parser!(u32).range(1..=10_000))]
    pub through_cameras: Option<u32>,
    /// Render the frames of a nerfstudio camera path (`camera_path.json`, as its viewer
    /// exports and `ns-render camera-path` reads): its size, field of view and rate.
    #[arg(long, conflicts_with_all = ["spiral", "through_cameras", "split", "camera"])]
    pub path: Option<PathBuf>,
    /// Render one split of the capture as INRIA's `render.py` lays it out: `renders/` and
    /// `gt/` (the clean image where the capture has one, else the photo) side by side, one
    /// name per view, for other tools' metric scripts.
    #[arg(long, value_enum, requires = "scene", conflicts_with_all = ["spiral", "through_cameras", "video"])]
    pub split: Option<SplitChoice>,
    /// Use the capture's images_N (1: images/); default images_8/ when it exists, else the
    /// folder there is.
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=64))]
    pub downsample: Option<u32>,
    /// Without --scene: frames of an orbit around the splats' bounds.
    #[arg(long, default_value_t = 30, conflicts_with_all = ["scene", "camera"], value_parser = clap::value_parser!(u32).range(1..=10_000))]
    pub orbit: u32,
    /// Without --scene: one frame from EYE looking at TARGET, as "ex,ey,ez,tx,ty,tz".
    #[arg(long, conflicts_with = "scene", value_parser = crate::settings::values::camera_pose, allow_hyphen_values = true)]
    pub camera: Option<[f32; 6]>,
    /// Image size without --scene.
    #[arg(long, default_value_t = 640, conflicts_with = "scene", value_parser = clap::value_parser!(u32).range(8..=8192))]
    pub width: u32,
    /// Image height without --scene.
    #[arg(long, default_value_t = 480, conflicts_with = "scene", value_parser = clap::value_parser!(u32).range(8..=8192))]
    pub height: u32,
    /// Field of view (degrees) across the shorter image side, without --scene.
    #[arg(long, default_value_t = 50.0, conflicts_with = "scene", value_parser = crate::settings::values::field_angle, allow_negative_numbers = true)]
    pub fov: f64,
    /// Where to render: `auto` (a hardware GPU when there is one), `cpu`, or `gpu`.
    #[arg(long, value_enum, default_value_t = DeviceChoice::Auto)]
    pub device: DeviceChoice,
    /// Also make the clip's aberrated twin through this PSF grid (.npy): the frames go to
    /// `--out`/clean/ and their blur, with noise seeded per frame as `aberrate --in DIR`
    /// makes it, to `--out`/aberrated/ — a clean and aberrated clip pair to restore
    /// (`restore --in`) and score (`restorer eval-video`).
    #[arg(long, conflicts_with_all = ["video", "split"])]
    pub aberrate: Option<PathBuf>,
    /// How `--aberrate` blurs the frames.
    #[command(flatten)]
    pub imaging: crate::settings::imaging::ImagingArgs,
}

/// Everything `render` checked and read before it writes: where the frames go, how, the
/// model, the cameras and the lens of an aberrated twin.
pub struct PreparedRender {
    request: RenderRequest,
    target: PathBuf,
    video: Option<VideoFormat>,
    fps: f64,
    capture: Option<scenes::Capture>,
    views: Option<Vec<usize>>,
    cameras: Vec<(String, splat::Camera)>,
    lens: Option<aberration::ImagingModel>,
    model: splat::Gaussians,
    device: Device,
    /// Sentences on what was chosen (the device, the capture's folder).
    pub notes: Vec<String>,
}

/// What a render made.
#[derive(Clone, Debug)]
pub struct RenderReport {
    pub splats: usize,
    pub sh_degree: u32,
    pub frames: usize,
    pub size: (u32, u32),
    pub seconds: f64,
    /// The folder or the video file.
    pub target: PathBuf,
    /// A video's frame rate as written, and whether ffmpeg wrote it.
    pub video: Option<(f64, bool)>,
    /// Sentences on where the frames' companions went (ground truth, the aberrated twin).
    pub said: Vec<String>,
}

impl PreparedRender {
    /// Renders every frame into a staging folder beside the target, then moves them in (or
    /// encodes the video) at once: a failure (a full disk) leaves no partial frame set.
    pub fn run(self) -> Result<RenderReport> {
        let start = std::time::Instant::now();
        let target = &self.target;
        let parent = match target.parent() {
            Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
            _ => PathBuf::from("."),
        };
        std::fs::create_dir_all(&parent).map_err(cannot(
            format!("cannot create {}", parent.display()),
            &parent,
        ))?;
        // One render into the target at a time; the lock sits beside it, so that the target
        // appears only with its frames.
        let _lock = base::FolderLock::beside(target, "render")?;
        // Into a folder that exists, also the lock a training run there holds: no frames land
        // in a run folder while the run writes it.
        let _folder_lock = if target.is_dir() {
            Some(base::FolderLock::folder(target, "render")?)
        } else {
            None
        };
        // A killed render's staging folder is removed before this one stages its own.
        base::remove_orphans(&parent);
        let staging = tempfile::Builder::new()
            .prefix(&format!("{}frames-", base::temp_prefix()))
            .tempdir_in(&parent)
            .map_err(cannot(
                format!("cannot stage frames in {}", parent.display()),
                &parent,
            ))?;
        let (frames_dir, truth_dir) = self.stage_folders(staging.path(), &parent)?;
        let settings = splat::RenderSettings {
            sh_degree: self.model.sh_degree,
            ..Default::default()
        };
        let staged = render_named(
            &self.model,
            &settings,
            &self.cameras,
            &frames_dir,
            &self.device,
        )?;
        let size = self
            .cameras
            .first()
            .map_or((0, 0), |c| (c.1.width, c.1.height));
        let (video, said) = match &self.video {
            Some(format) => {
                video::encode(format, &staged, self.fps, target)?;
                let fps = video::written_fps(format, self.fps)?;
                (
                    Some((fps, matches!(format, VideoFormat::Ffmpeg(_)))),
                    vec![],
                )
            }
            None => (
                None,
                self.move_in(&staged, staging.path(), truth_dir.as_deref())?,
            ),
        };
        Ok(RenderReport {
            splats: self.model.len(),
            sh_degree: self.model.sh_degree,
            frames: staged.len(),
            size,
            seconds: start.elapsed().as_secs_f64(),
            target: target.clone(),
            video,
            said,
        })
    }

    /// The staging folders: with --split, renders/ and gt/ (the ground truth written now); with
    /// --aberrate, clean/; else the staging folder itself. Returns the frames' folder and the
    /// ground truth's.
    fn stage_folders(&self, staging: &Path, parent: &Path) -> Result<(PathBuf, Option<PathBuf>)> {
        let made = |dir: PathBuf| -> Result<PathBuf> {
            std::fs::create_dir_all(&dir).map_err(cannot(
                format!("cannot stage frames in {}", parent.display()),
                &dir,
            ))?;
            Ok(dir)
        };
        Ok(match (&self.capture, &self.views) {
            _ if self.lens.is_some() => (made(staging.join("clean"))?, None),
            (Some(capture), Some(views)) => {
                let truth = made(staging.join("gt"))?;
                for &i in views {
                    let photo = match scenes::aberrated::load_clean_image(capture, i)? {
                        Some(clean) => clean,
                        None => capture.load_image(i)?,
                    };
                    let to = truth.join(format!("{}.png", capture.cameras[i].name));
                    scenes::images::write_png(&to, &photo, scenes::BitDepth::Eight)?;
                }
                (made(staging.join("renders"))?, Some(truth))
            }
            _ => (staging.to_path_buf(), None),
        })
    }

    /// The staged frames into --out (or its renders/ beside gt/, or its clean/ beside
    /// aberrated/, the twin made now), then their ground truth or their blur; returns the
    /// sentences that say where.
    fn move_in(
        &self,
        staged: &[PathBuf],
        staging: &Path,
        truth_dir: Option<&Path>,
    ) -> Result<Vec<String>> {
        let (a, out) = (&self.request, &self.target);
        let mut said = Vec::new();
        let twin = self
            .lens
            .as_ref()
            .map(|model| aberrated_twin(model, staged, staging, a.imaging.seed))
            .transpose()?;
        // The frames into --out (or its renders/ beside gt/, or its clean/ beside aberrated/),
        // then their ground truth or their blur.
        let frames_to = match (truth_dir, &twin) {
            (Some(_), _) => out.join("renders"),
            (None, Some(_)) => out.join("clean"),
            (None, None) => out.clone(),
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
        if let Some(truth) = truth_dir {
            let listed = cannot(format!("cannot list {}", truth.display()), truth);
            for e in std::fs::read_dir(truth).map_err(listed)? {
                let f = e
                    .map_err(cannot(format!("cannot list {}", truth.display()), truth))?
                    .path();
                let to = out.join("gt").join(f.file_name().expect("a frame file"));
                moves.push((f, to));
            }
        }
        if let Some((targets, ..)) = &twin {
            for f in targets {
                moves.push((
                    f.clone(),
                    out.join("aberrated")
                        .join(f.file_name().expect("a frame file")),
                ));
            }
        }
        for (from, to) in moves {
            let dir = to.parent().expect("inside --out");
            std::fs::create_dir_all(dir)
                .map_err(cannot(format!("cannot create {}", dir.display()), dir))?;
            std::fs::rename(&from, &to).map_err(cannot(
                format!("cannot move a frame to {}", to.display()),
                &to,
            ))?;
        }
        if let Some((_, mean, px)) = &twin {
            said.push(format!(
                "Their aberrated twin, through {px} px PSFs ({} mode, noise seeded per frame; {mean:.2} dB against the clean frames), is in {}/aberrated/ beside them in {}/clean/.",
                a.imaging.mode,
                out.display(),
                out.display()
            ));
        }
        if let (Some(capture), Some(_)) = (&self.capture, truth_dir) {
            let truth = if capture.root.join(scenes::aberrated::CLEAN_DIR).is_dir() {
                "the clean images"
            } else {
                "the photos"
            };
            said.push(format!(
                "The renders are in {}/renders/ and {truth} beside them in {}/gt/, one name per view.",
                out.display(),
                out.display()
            ));
        }
        Ok(said)
    }
}

/// Every check `render` makes and everything it reads, before anything is written.
pub fn prepare(a: &RenderRequest) -> Result<PreparedRender> {
    splat::formats::files::Format::of(&a.ply).map_err(|e| TrainError::from(e).context("--in"))?;
    let mut inputs = vec![("--in", a.ply.as_path())];
    if let Some(s) = &a.scene {
        inputs.push(("--scene", s));
    }
    if let Some(p) = &a.path {
        inputs.push(("--path", p));
    }
    if let Some(p) = &a.aberrate {
        inputs.push(("--aberrate", p));
    }
    if a.aberrate.is_none() && a.imaging.any_given() {
        return refused(
            "--mode, --seed, --no-noise and --sensor-px say how --aberrate blurs the frames; give --aberrate PSF with them".into(),
        );
    }
    let mut inputs = crate::output::guard::Inputs::of(&inputs);
    // The frames' folder, or the video file; and how the video is written, before any work.
    let (target, flag) = match (&a.out, &a.video) {
        (Some(out), _) => (out.clone(), "--out"),
        (None, Some(video)) => (video.clone(), "--video"),
        (None, None) => {
            return refused("give --out (a folder of frames) or --video (one file)".into());
        }
    };
    let video = a.video.as_deref().map(video::format_for).transpose()?;
    inputs.refuse(flag, &target)?;
    if let (Some(fps), None) = (a.fps, &video) {
        return refused(format!(
            "--fps {fps}: only --video uses a frame rate; a folder of frames has none"
        ));
    }
    if video.is_some() && target.is_dir() {
        return refused(format!(
            "--video {}: is a folder, not a file",
            target.display()
        ));
    }
    if video.is_none() {
        crate::output::guard::refuse_file_as_folder("--out", &target)?;
    }
    let camera_path = a
        .path
        .as_deref()
        .map(scenes::nerfstudio::read_camera_path)
        .transpose()?;
    // A rate the format cannot show is refused before any frame is rendered.
    let fps = a
        .fps
        .or(camera_path.as_ref().map(|p| p.fps))
        .unwrap_or(30.0);
    if let Some(format) = &video {
        video::written_fps(format, fps)?;
    }
    let mut notes = Vec::new();
    let capture = match &a.scene {
        Some(dir) => {
            let (downsample, note) = crate::settings::downsample_for(dir, a.downsample);
            notes.extend(note);
            let capture = crate::settings::open_scene(dir, downsample, false)?;
            // The photos the capture names, wherever its model file says they are.
            inputs.add_capture(&capture);
            inputs.refuse(flag, &target)?;
            Some(capture)
        }
        None => None,
    };
    let (device, note) = Device::choose(a.device)?;
    notes.push(note);
    let model = splat::formats::files::read_splats(&a.ply)?;
    if model.is_empty() {
        return refused(format!("{}: the scene has no splats", a.ply.display()));
    }
    // The capture's views the split names, by index.
    let views: Option<Vec<usize>> = match (&capture, a.split) {
        (Some(c), Some(SplitChoice::Test)) => Some(c.split.test.clone()),
        (Some(c), Some(SplitChoice::Train)) => Some(c.split.train.clone()),
        _ => None,
    };
    if views.as_ref().is_some_and(|v| v.is_empty()) {
        return refused("--split: the capture has no views in that split".into());
    }
    let mut cameras: Vec<(String, splat::Camera)> = match (&capture, &camera_path) {
        (_, Some(path)) => path
            .cameras
            .iter()
            .map(|c| (c.name.clone(), crate::splats::convert::splat_camera(c)))
            .collect(),
        (Some(capture), None) => {
            let cams = match (a.spiral, a.through_cameras, &views) {
                (Some(n), _, _) => {
                    scenes::spiral::spiral(&capture.cameras, &capture.bounds, n as usize)
                }
                (None, Some(n), _) => scenes::spiral::through_cameras(&capture.cameras, n as usize),
                (None, None, Some(v)) => v.iter().map(|&i| capture.cameras[i].clone()).collect(),
                (None, None, None) => capture.cameras.clone(),
            };
            cams.iter()
                .map(|c| (c.name.clone(), crate::splats::convert::splat_camera(c)))
                .collect()
        }
        (None, None) => free_cameras(a, &model)?,
    };
    // The lens of the aberrated twin, planned for the frames' size before any is rendered.
    let lens = match &a.aberrate {
        Some(path) => {
            let size = cameras.first().map_or((0, 0), |c| (c.1.width, c.1.height));
            if cameras.iter().any(|c| (c.1.width, c.1.height) != size) {
                return refused(
                    "--aberrate: the frames differ in size; one imaging model serves one size"
                        .into(),
                );
            }
            let psf = aberration::PsfGrid::load_npy(path)?;
            Some(
                a.imaging
                    .model_for(&psf, path, "--aberrate: the frames", size)?,
            )
        }
        None => None,
    };
    if video.is_some() {
        // The encoders read the frames by number.
        for (k, (name, _)) in cameras.iter_mut().enumerate() {
            *name = format!("frame{k:05}");
        }
    }
    Ok(PreparedRender {
        request: a.clone(),
        target,
        video,
        fps,
        capture,
        views,
        cameras,
        lens,
        model,
        device,
        notes,
    })
}

/// `render --aberrate`: the staged frames through `model` into `staging`/aberrated/, noise
/// seeded per frame; the twin frames, their mean PSNR against the clean ones, and the PSF
/// side.
fn aberrated_twin(
    model: &aberration::ImagingModel,
    staged: &[PathBuf],
    staging: &Path,
    seed: u64,
) -> Result<(Vec<PathBuf>, f64, usize)> {
    let dir = staging.join("aberrated");
    std::fs::create_dir_all(&dir)
        .map_err(cannot(format!("cannot stage {}", dir.display()), &dir))?;
    let targets: Vec<PathBuf> = staged
        .iter()
        .map(|f| dir.join(f.file_name().expect("a frame file")))
        .collect();
    let mean = crate::settings::imaging::aberrate_frames(model, staged, &targets, seed)?;
    Ok((targets, mean, model.psf().size()))
}

/// The viewer's default view without a capture: an orbit around the view that frames the
/// splats' bounds, or the one camera given (both from the viewer's camera code).
fn free_cameras(
    a: &RenderRequest,
    model: &splat::Gaussians,
) -> Result<Vec<(String, splat::Camera)>> {
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
        return refused(format!(
            "{}: no splat has a finite position",
            a.ply.display()
        ));
    };
    Ok((0..a.orbit)
        .map(|k| {
            let mut view = home.clone();
            view.yaw = std::f32::consts::TAU * k as f32 / a.orbit as f32;
            (format!("orbit{k:03}"), view.camera(a.width, a.height))
        })
        .collect())
}
