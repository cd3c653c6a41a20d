//! Restoring as a job: one photo, a folder of frames, an animated GIF or a video through the
//! network the grid calls for. Every check comes before any output exists; a folder (and a
//! video, through its frames) is written frame by frame, so a stop keeps what is done and
//! `--resume` restores the rest.

use aberration::Image;
use clap::Args;
use std::path::{Path, PathBuf};
use std::time::Instant;

use super::frames::{FrameFolders, time_left};
use super::refused;
use super::restorer_net::Inference;
use crate::error::{Result, TrainError};
use crate::output::video;
use crate::settings::imaging::sensor_flag;

/// What `restore` is asked to do (its flags).
#[derive(Args, Clone, Debug)]
pub struct RestoreRequest {
    #[command(flatten)]
    pub net: Inference,
    /// The aberrated photo (PNG or JPEG), or a folder of them (the frames of a video, all of
    /// one size): each is restored into --out, a folder, under its own name as PNG.
    #[arg(long = "in")]
    pub input: PathBuf,
    /// Where the restored photo goes (PNG), or the folder the restored frames go to.
    #[arg(long)]
    pub out: PathBuf,
    /// With a folder: keep the frames --out already holds and restore the others (after a
    /// stop).
    #[arg(long)]
    pub resume: bool,
    /// Sensor size (px) the grid was made for; default G·K.
    #[arg(long, value_parser = crate::settings::values::sensor_px)]
    pub sensor_px: Option<usize>,
    /// A clean image to report PSNR/SSIM against.
    #[arg(long)]
    pub reference: Option<PathBuf>,
    /// Steady a clip (frames, GIF, video) over time: each restored frame is blended with the
    /// previous one, moved along the motion between them, where the two agree; 0 restores
    /// every frame exactly as alone, 0.5 (the default for clips) averages about three frames
    /// where the scene holds still. Below 1.
    #[arg(long)]
    pub steady: Option<f32>,
}

/// What a restore tells while it works.
pub enum RestoreEvent<'a> {
    /// A sentence: which network serves and why, a resumed folder, a warning.
    Said(String),
    /// One photo is being restored (the CLI shows a spinner until the next event).
    Restoring,
    /// Frame `done` of `total` restored, about `left` seconds to go.
    Frame {
        done: usize,
        total: usize,
        name: &'a str,
        left: f64,
    },
}

/// What a restore made.
#[derive(Clone, Debug)]
pub struct RestoreReport {
    /// Frames restored by this run (1 for a photo).
    pub frames: usize,
    pub size: (usize, usize),
    pub network: String,
    pub seconds: f64,
    pub out: PathBuf,
    /// With --reference: PSNR and SSIM of the input and of the restored photo.
    pub against_reference: Option<[f64; 4]>,
    pub kind: Restored,
}

/// What was restored.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Restored {
    Photo,
    /// A folder of frames.
    Frames,
    Gif,
    /// A video, at this frame rate.
    Video(f64),
}

fn is_gif(p: &Path) -> bool {
    p.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("gif"))
}

/// Restores what `a` names: a folder, a GIF, a video or one photo.
pub fn run(a: &RestoreRequest, on_event: &mut dyn FnMut(RestoreEvent)) -> Result<RestoreReport> {
    if let Some(s) = a.steady
        && let Err(e) = restore::steady::Steady::new(s).validate()
    {
        return refused(format!("--steady {s}: {e}"));
    }
    if a.input.is_dir() {
        return restore_folder(a, on_event);
    }
    if is_gif(&a.input) {
        return restore_gif(a, on_event);
    }
    if video::is_ffmpeg_video(&a.input) {
        return restore_video(a, on_event);
    }
    restore_photo(a, on_event)
}

/// The network and the grid mapped to `w × h` images, the choice said.
fn network_for(
    a: &RestoreRequest,
    (w, h): (usize, usize),
    on_event: &mut dyn FnMut(RestoreEvent),
) -> Result<(restore::Restorer, aberration::PsfGrid)> {
    let (native, restorer, said) = a.net.load(|n| Some(n.mapped_size(w, h, a.sensor_px)))?;
    if let Some(line) = said {
        on_event(RestoreEvent::Said(line));
    }
    let psf = native
        .for_image(w, h, a.sensor_px)
        .map_err(|e| TrainError::from(e).context(sensor_flag(a.sensor_px, &a.net.psf)))?;
    Ok((restorer, psf))
}

fn restore_photo(
    a: &RestoreRequest,
    on_event: &mut dyn FnMut(RestoreEvent),
) -> Result<RestoreReport> {
    if a.resume {
        return refused(format!(
            "--resume: only a folder of frames (--in DIR) is restored in parts; {} is one photo",
            a.input.display()
        ));
    }
    if a.steady.is_some() {
        return refused(format!(
            "--steady: steadying blends a clip's frames over time; {} is one photo",
            a.input.display()
        ));
    }
    let mut inputs = a.net.inputs();
    inputs.push(("--in", a.input.as_path()));
    if let Some(r) = &a.reference {
        inputs.push(("--reference", r));
    }
    crate::output::guard::refuse_overwrite("--out", &a.out, &inputs)?;
    crate::output::guard::refuse_unwritable_image("--out", &a.out)?;
    let read = |p: &Path| {
        Image::load(p)
            .map_err(|e| TrainError::from(e).context(format!("cannot read {}", p.display())))
    };
    let blurred = read(&a.input)?;
    let size = (blurred.width, blurred.height);
    let clean = match &a.reference {
        Some(r) => {
            let clean = read(r)?;
            if (clean.width, clean.height) != size {
                return refused(format!(
                    "{}: {}x{} does not match the input's {}x{}",
                    r.display(),
                    clean.width,
                    clean.height,
                    size.0,
                    size.1
                ));
            }
            Some(clean)
        }
        None => None,
    };
    let (restorer, psf) = network_for(a, size, on_event)?;
    if !restorer.header.fits_psf_px(psf.size()) {
        let [lo, hi] = restorer.header.trained_psf_px.unwrap_or([0, 0]);
        on_event(RestoreEvent::Said(format!(
            "warning: the network was trained on {lo}-{hi} px PSFs; this photo's are {} px",
            psf.size()
        )));
    }
    on_event(RestoreEvent::Restoring);
    let start = Instant::now();
    let restored = restorer.restore(&blurred, &psf)?;
    let seconds = start.elapsed().as_secs_f64();
    restored.save_png(&a.out)?;
    let against_reference = match &clean {
        Some(clean) => {
            let (p0, s0) = aberration::compare(&blurred, clean)?;
            let (p1, s1) = aberration::compare(&restored, clean)?;
            Some([p0, p1, s0, s1])
        }
        None => None,
    };
    Ok(RestoreReport {
        frames: 1,
        size,
        network: restorer.label(),
        seconds,
        out: a.out.clone(),
        against_reference,
        kind: Restored::Photo,
    })
}

/// `restore --in DIR`: every photo of a folder (a video's frames), through the restorer the
/// grid and the frames' size call for, into the folder `--out` under the same names as PNG.
/// Each frame is written whole as it is done; a stop (Ctrl-C) keeps the frames done, and
/// `--resume` restores the others.
fn restore_folder(
    a: &RestoreRequest,
    on_event: &mut dyn FnMut(RestoreEvent),
) -> Result<RestoreReport> {
    if a.reference.is_some() {
        return refused(
            "--reference: a folder of frames is restored without one (score a frame alone)".into(),
        );
    }
    let io = FrameFolders::check(
        &a.input,
        &a.out,
        (!a.resume).then_some("--resume keeps the frames done and restores the others"),
        &a.net.inputs(),
    )?;
    let (frames, size) = (&io.frames, io.size);
    let size = (size.0 as usize, size.1 as usize);
    let (restorer, psf) = network_for(a, size, on_event)?;
    io.make_out()?;
    let todo: Vec<(usize, &PathBuf)> = frames
        .iter()
        .enumerate()
        .filter(|(_, f)| !io.target(f).exists())
        .collect();
    let kept = frames.len() - todo.len();
    if kept > 0 {
        on_event(RestoreEvent::Said(format!(
            "--resume: {kept} of {} frames were restored before; restoring the other {}.",
            frames.len(),
            todo.len()
        )));
    }
    let steady = steady_said(a, on_event);
    // The previous frame as written (8-bit), so a resumed clip steadies as an unbroken one.
    let mut previous: Option<(usize, Image)> = None;
    let start = Instant::now();
    for (done, &(index, f)) in todo.iter().enumerate() {
        if base::interrupt::requested() {
            return Err(TrainError::Interrupted(format!(
                "restoring stopped after {} of {} frames; they are kept in {}: the same command with --resume restores the others",
                kept + done,
                frames.len(),
                a.out.display()
            )));
        }
        let blurred = Image::load(f)
            .map_err(|e| TrainError::from(e).context(format!("cannot read {}", f.display())))?;
        let restored = restorer.restore(&blurred, &psf)?;
        let target = io.target(f);
        match &steady {
            None => restored.save_png(&target)?,
            Some(s) => {
                let before = match previous.take() {
                    Some((i, img)) if i + 1 == index => Some(img),
                    _ if index > 0 && io.target(&frames[index - 1]).exists() => {
                        let p = io.target(&frames[index - 1]);
                        Some(Image::load(&p).map_err(|e| {
                            TrainError::from(e).context(format!("cannot read {}", p.display()))
                        })?)
                    }
                    _ => None,
                };
                let out = restore::steady::steady_frame(before.as_ref(), restored, s)?;
                out.save_png(&target)?;
                previous = Some((index, as_written(&out)));
            }
        }
        on_event(RestoreEvent::Frame {
            done: kept + done + 1,
            total: frames.len(),
            name: &f.file_name().unwrap_or_default().to_string_lossy(),
            left: time_left(start.elapsed().as_secs_f64(), done + 1, todo.len()),
        });
    }
    Ok(RestoreReport {
        frames: todo.len(),
        size,
        network: restorer.label(),
        seconds: start.elapsed().as_secs_f64(),
        out: a.out.clone(),
        against_reference: None,
        kind: Restored::Frames,
    })
}

/// Steadying strength for a clip when `--steady` is not given: measured on two rendered
/// clips (restore/README, "Video"), 0.5 keeps most of what 0.7 gains (+0.2-0.3 dB, flicker
/// down 84-89 %) for about 5 % more time per frame.
pub const DEFAULT_STEADY: f32 = 0.5;

/// The steadying a clip gets (None when off), said.
fn steady_said(
    a: &RestoreRequest,
    on_event: &mut dyn FnMut(RestoreEvent),
) -> Option<restore::steady::Steady> {
    let strength = a.steady.unwrap_or(DEFAULT_STEADY);
    (strength > 0.0).then(|| {
        let given = if a.steady.is_some() {
            ""
        } else {
            ", the default for clips; --steady 0 restores each frame as alone"
        };
        on_event(RestoreEvent::Said(format!(
            "Steadying over time (--steady {strength}{given}): each frame blended with the previous one along their motion where they agree."
        )));
        restore::steady::Steady::new(strength)
    })
}

/// An image as its 8-bit file holds it, so what a frame is steadied with is the same whether
/// the previous frame was just made or read back on `--resume`.
fn as_written(img: &Image) -> Image {
    let rgb = img.to_rgb8();
    Image::from_fn(img.width, img.height, |x, y| {
        rgb.get_pixel(x as u32, y as u32)
            .0
            .map(|v| v as f32 / 255.0)
    })
}

/// The frames of the GIF `path`, after every check.
fn gif_frames(path: &Path) -> Result<(Vec<image::Frame>, (usize, usize))> {
    use image::AnimationDecoder;
    let bad = |what: &str, e: &dyn std::fmt::Display| {
        TrainError::Invalid(format!("--in {}: {what}: {e}", path.display()))
    };
    let file = base::input::open(path).map_err(|e| TrainError::io(path, e))?;
    let decoder = image::codecs::gif::GifDecoder::new(std::io::BufReader::new(file))
        .map_err(|e| bad("not a GIF", &e))?;
    let frames = decoder
        .into_frames()
        .collect_frames()
        .map_err(|e| bad("cannot decode its frames", &e))?;
    let Some(first) = frames.first() else {
        return refused(format!("--in {}: the GIF has no frames", path.display()));
    };
    let (w, h) = (first.buffer().width(), first.buffer().height());
    base::limits::check_image_pixels(w, h).map_err(|p| bad("too large", &p))?;
    Ok((frames, (w as usize, h as usize)))
}

/// `restore --in clip.gif --out restored.gif`: every frame of an animated GIF through the
/// restorer its size calls for, written as one GIF with the input's frame times (without
/// ffmpeg). A stop (Ctrl-C) between frames writes nothing.
fn restore_gif(
    a: &RestoreRequest,
    on_event: &mut dyn FnMut(RestoreEvent),
) -> Result<RestoreReport> {
    if a.resume || a.reference.is_some() {
        return refused("--resume and --reference: a GIF is restored whole, without either".into());
    }
    if !is_gif(&a.out) {
        return refused(format!(
            "--out {}: a GIF is restored into a .gif (restore its frames as a folder with --in DIR for PNG frames)",
            a.out.display()
        ));
    }
    let mut inputs = a.net.inputs();
    inputs.push(("--in", a.input.as_path()));
    crate::output::guard::refuse_overwrite("--out", &a.out, &inputs)?;
    let (frames, (w, h)) = gif_frames(&a.input)?;
    let (restorer, psf) = network_for(a, (w, h), on_event)?;
    let steady = steady_said(a, on_event);
    let mut previous: Option<Image> = None;
    let start = Instant::now();
    let mut out = Vec::with_capacity(frames.len());
    for (i, f) in frames.iter().enumerate() {
        if base::interrupt::requested() {
            return Err(TrainError::Interrupted(format!(
                "restoring stopped after {i} of {} frames; nothing was written",
                frames.len()
            )));
        }
        let rgba = f.buffer();
        let blurred = Image::from_fn(w, h, |x, y| {
            let p = rgba.get_pixel(x as u32, y as u32).0;
            [p[0], p[1], p[2]].map(|v| v as f32 / 255.0)
        });
        let mut restored = restorer.restore(&blurred, &psf)?;
        if let Some(s) = &steady {
            restored = restore::steady::steady_frame(previous.as_ref(), restored, s)?;
            previous = Some(as_written(&restored));
        }
        let rgb = restored.to_rgb8();
        let rgba = image::RgbaImage::from_fn(w as u32, h as u32, |x, y| {
            let p = rgb.get_pixel(x, y).0;
            image::Rgba([p[0], p[1], p[2], 255])
        });
        out.push(image::Frame::from_parts(rgba, 0, 0, f.delay()));
        on_event(RestoreEvent::Frame {
            done: i + 1,
            total: frames.len(),
            name: "",
            left: time_left(start.elapsed().as_secs_f64(), i + 1, frames.len()),
        });
    }
    video::write_gif(&a.out, out.into_iter().map(Ok))?;
    Ok(RestoreReport {
        frames: frames.len(),
        size: (w, h),
        network: restorer.label(),
        seconds: start.elapsed().as_secs_f64(),
        out: a.out.clone(),
        against_reference: None,
        kind: Restored::Gif,
    })
}

/// `restore --in clip.mp4 --out restored.mp4` (or `.gif`): the clip's frames through ffmpeg
/// into `OUT.parts/input/`, restored into `OUT.parts/restored/` ([`restore_folder`]), and
/// encoded at the clip's rate into `--out`; the parts folder goes when the video is written.
/// A stop keeps the frames done there, and `--resume` continues.
fn restore_video(
    a: &RestoreRequest,
    on_event: &mut dyn FnMut(RestoreEvent),
) -> Result<RestoreReport> {
    if a.reference.is_some() {
        return refused(
            "--reference: a video is restored without one (score it with restorer eval-video)"
                .into(),
        );
    }
    let Some(ffmpeg) = video::on_path("ffmpeg") else {
        return refused(format!(
            "--in {}: reading a video needs ffmpeg, which is not on the PATH; install it, or restore the clip as a .gif or as a folder of frames (--in DIR --out DIR)",
            a.input.display()
        ));
    };
    let format = video::format_for_flag("--out", &a.out)?;
    let mut inputs = a.net.inputs();
    inputs.push(("--in", a.input.as_path()));
    crate::output::guard::refuse_overwrite("--out", &a.out, &inputs)?;
    let parts = PathBuf::from(format!("{}.parts", a.out.display()));
    if parts.exists() && !a.resume {
        return refused(format!(
            "--out {}: {} holds the frames of an earlier run; --resume continues it",
            a.out.display(),
            parts.display()
        ));
    }
    let (input_dir, restored_dir) = (parts.join("input"), parts.join("restored"));
    for d in [&input_dir, &restored_dir] {
        std::fs::create_dir_all(d).map_err(|e| TrainError::io(d, e))?;
    }
    let rate_file = parts.join("fps");
    let fps = match std::fs::read_to_string(&rate_file)
        .ok()
        .and_then(|t| t.trim().parse::<f64>().ok())
    {
        Some(fps) if scenes::images::list_images(&input_dir).is_ok() => fps,
        _ => {
            on_event(RestoreEvent::Said(format!(
                "Reading the frames of {} with {}.",
                a.input.display(),
                ffmpeg.display()
            )));
            let fps = video::decode(&ffmpeg, &a.input, &input_dir)?;
            base::write_bytes_atomically(&rate_file, fps.to_string().as_bytes())
                .map_err(|e| TrainError::io(&rate_file, e))?;
            fps
        }
    };
    let restored = restore_folder(
        &RestoreRequest {
            input: input_dir,
            out: restored_dir.clone(),
            resume: true,
            reference: None,
            ..a.clone()
        },
        on_event,
    )?;
    let frames = scenes::images::list_images(&restored_dir)?;
    video::encode(&format, &frames, fps, &a.out)?;
    std::fs::remove_dir_all(&parts).map_err(|e| TrainError::io(&parts, e))?;
    Ok(RestoreReport {
        frames: frames.len(),
        out: a.out.clone(),
        kind: Restored::Video(fps),
        ..restored
    })
}
