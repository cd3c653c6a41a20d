//! `metasplat restore`: one photo, a folder of frames, an animated GIF or a video through
//! the network.

use crate::cli::progress::step;
use aberration::Image;
use anyhow::{Context, Result, bail};
use clap::Args;
use std::path::{Path, PathBuf};

use super::network::{Inference, metric};

#[derive(Args)]
pub struct RestoreArgs {
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
    #[arg(long, value_parser = metasplat::settings::values::sensor_px)]
    pub sensor_px: Option<usize>,
    /// A clean image to report PSNR/SSIM against.
    #[arg(long)]
    pub reference: Option<PathBuf>,
}

pub fn run_restore(a: RestoreArgs) -> Result<()> {
    if a.input.is_dir() {
        return run_restore_folder(a);
    }
    if is_gif(&a.input) {
        return run_restore_gif(a);
    }
    if metasplat::output::video::is_ffmpeg_video(&a.input) {
        return run_restore_video(a);
    }
    if a.resume {
        bail!(
            "--resume: only a folder of frames (--in DIR) is restored in parts; {} is one photo",
            a.input.display()
        );
    }
    let mut inputs = a.net.inputs();
    inputs.push(("--in", a.input.as_path()));
    if let Some(r) = &a.reference {
        inputs.push(("--reference", r));
    }
    metasplat::output::guard::refuse_overwrite("--out", &a.out, &inputs)?;
    metasplat::output::guard::refuse_unwritable_image("--out", &a.out)?;
    let blurred =
        Image::load(&a.input).with_context(|| format!("cannot read {}", a.input.display()))?;
    let (native, restorer) = a
        .net
        .load(|n| Some(n.mapped_size(blurred.width, blurred.height, a.sensor_px)))?;
    let psf = native
        .for_image(blurred.width, blurred.height, a.sensor_px)
        .with_context(|| metasplat::settings::imaging::sensor_flag(a.sensor_px, &a.net.psf))?;
    if !restorer.header.fits_psf_px(psf.size()) {
        let [lo, hi] = restorer.header.trained_psf_px.unwrap_or([0, 0]);
        println!(
            "warning: the network was trained on {lo}-{hi} px PSFs; this photo's are {} px",
            psf.size()
        );
    }
    let (restored, secs) = step("restoring", || restorer.restore(&blurred, &psf));
    let restored = restored?;
    restored
        .save_png(&a.out)
        .with_context(|| format!("cannot write {}", a.out.display()))?;
    print!(
        "restored {}x{} with '{}' in {secs:.2} s -> {}",
        blurred.width,
        blurred.height,
        restorer.config().name,
        a.out.display()
    );
    if let Some(r) = &a.reference {
        let clean = Image::load(r).with_context(|| format!("cannot read {}", r.display()))?;
        if (clean.width, clean.height) != (blurred.width, blurred.height) {
            bail!(
                "{}: {}x{} does not match the input's {}x{}",
                r.display(),
                clean.width,
                clean.height,
                blurred.width,
                blurred.height
            );
        }
        let (p0, s0) = metric(&blurred, &clean)?;
        let (p1, s1) = metric(&restored, &clean)?;
        print!("; PSNR {p0:.2} -> {p1:.2} dB, SSIM {s0:.4} -> {s1:.4}");
    }
    println!();
    Ok(())
}

/// `restore --in DIR`: every photo of a folder (a video's frames), through the restorer the
/// grid and the frames' size call for, into the folder `--out` under the same names as PNG.
/// Each frame is written whole as it is done; a stop (Ctrl-C) keeps the frames done, and
/// `--resume` restores the others.
fn run_restore_folder(a: RestoreArgs) -> Result<()> {
    if a.reference.is_some() {
        bail!("--reference: a folder of frames is restored without one (score a frame alone)");
    }
    let io = crate::cli::frames::FrameFolders::check(
        &a.input,
        &a.out,
        (!a.resume).then_some("--resume keeps the frames done and restores the others"),
        &a.net.inputs(),
    )?;
    let (frames, size) = (&io.frames, io.size);
    let (w, h) = (size.0 as usize, size.1 as usize);
    let (native, restorer) = a.net.load(|n| Some(n.mapped_size(w, h, a.sensor_px)))?;
    let psf = native
        .for_image(w, h, a.sensor_px)
        .with_context(|| metasplat::settings::imaging::sensor_flag(a.sensor_px, &a.net.psf))?;
    io.make_out()?;
    let todo: Vec<&PathBuf> = frames.iter().filter(|f| !io.target(f).exists()).collect();
    let kept = frames.len() - todo.len();
    if kept > 0 {
        println!(
            "--resume: {kept} of {} frames were restored before; restoring the other {}.",
            frames.len(),
            todo.len()
        );
    }
    let start = std::time::Instant::now();
    for (done, f) in todo.iter().enumerate() {
        if base::interrupt::requested() {
            return Err(metasplat::TrainError::Interrupted(format!(
                "restoring stopped after {} of {} frames; they are kept in {}: the same command with --resume restores the others",
                kept + done,
                frames.len(),
                a.out.display()
            ))
            .into());
        }
        let blurred = Image::load(f).with_context(|| format!("cannot read {}", f.display()))?;
        let restored = restorer.restore(&blurred, &psf)?;
        let target = io.target(f);
        restored
            .save_png(&target)
            .with_context(|| format!("cannot write {}", target.display()))?;
        println!(
            "frame {} of {} ({}) restored; about {:.0} s left",
            kept + done + 1,
            frames.len(),
            f.file_name().unwrap_or_default().to_string_lossy(),
            crate::cli::frames::time_left(start.elapsed().as_secs_f64(), done + 1, todo.len())
        );
    }
    println!(
        "restored {} frames {}x{} with '{}' in {:.1} s -> {}",
        todo.len(),
        size.0,
        size.1,
        restorer.config().name,
        start.elapsed().as_secs_f64(),
        a.out.display()
    );
    Ok(())
}

fn is_gif(p: &Path) -> bool {
    p.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("gif"))
}

/// `restore --in clip.gif --out restored.gif`: every frame of an animated GIF through the
/// restorer its size calls for, written as one GIF with the input's frame times (without
/// ffmpeg). A stop (Ctrl-C) between frames writes nothing.
fn run_restore_gif(a: RestoreArgs) -> Result<()> {
    use image::AnimationDecoder;
    if a.resume || a.reference.is_some() {
        bail!("--resume and --reference: a GIF is restored whole, without either");
    }
    if !is_gif(&a.out) {
        bail!(
            "--out {}: a GIF is restored into a .gif (restore its frames as a folder with --in DIR for PNG frames)",
            a.out.display()
        );
    }
    let mut inputs = a.net.inputs();
    inputs.push(("--in", a.input.as_path()));
    metasplat::output::guard::refuse_overwrite("--out", &a.out, &inputs)?;
    let file =
        base::input::open(&a.input).with_context(|| format!("--in {}", a.input.display()))?;
    let decoder = image::codecs::gif::GifDecoder::new(std::io::BufReader::new(file))
        .with_context(|| format!("--in {}: not a GIF", a.input.display()))?;
    let frames = decoder
        .into_frames()
        .collect_frames()
        .with_context(|| format!("--in {}: cannot decode its frames", a.input.display()))?;
    let Some(first) = frames.first() else {
        bail!("--in {}: the GIF has no frames", a.input.display());
    };
    let (w, h) = (
        first.buffer().width() as usize,
        first.buffer().height() as usize,
    );
    base::limits::check_image_pixels(w as u32, h as u32)
        .map_err(|p| anyhow::anyhow!("--in {}: {p}", a.input.display()))?;
    let (native, restorer) = a.net.load(|n| Some(n.mapped_size(w, h, a.sensor_px)))?;
    let psf = native
        .for_image(w, h, a.sensor_px)
        .with_context(|| metasplat::settings::imaging::sensor_flag(a.sensor_px, &a.net.psf))?;
    let start = std::time::Instant::now();
    let mut out = Vec::with_capacity(frames.len());
    for (i, f) in frames.iter().enumerate() {
        if base::interrupt::requested() {
            return Err(metasplat::TrainError::Interrupted(format!(
                "restoring stopped after {i} of {} frames; nothing was written",
                frames.len()
            ))
            .into());
        }
        let rgba = f.buffer();
        let blurred = Image::from_fn(w, h, |x, y| {
            let p = rgba.get_pixel(x as u32, y as u32).0;
            [p[0], p[1], p[2]].map(|v| v as f32 / 255.0)
        });
        let restored = restorer.restore(&blurred, &psf)?;
        let rgb = restored.to_rgb8();
        let rgba = image::RgbaImage::from_fn(w as u32, h as u32, |x, y| {
            let p = rgb.get_pixel(x, y).0;
            image::Rgba([p[0], p[1], p[2], 255])
        });
        out.push(image::Frame::from_parts(rgba, 0, 0, f.delay()));
        println!(
            "frame {} of {} restored; about {:.0} s left",
            i + 1,
            frames.len(),
            crate::cli::frames::time_left(start.elapsed().as_secs_f64(), i + 1, frames.len())
        );
    }
    let mut bytes = Vec::new();
    {
        let mut encoder = image::codecs::gif::GifEncoder::new_with_speed(&mut bytes, 10);
        encoder.set_repeat(image::codecs::gif::Repeat::Infinite)?;
        encoder.encode_frames(out)?;
    }
    base::write_bytes_atomically(&a.out, &bytes)
        .with_context(|| format!("cannot write {}", a.out.display()))?;
    println!(
        "restored {} frames {w}x{h} with '{}' in {:.1} s -> {}",
        frames.len(),
        restorer.config().name,
        start.elapsed().as_secs_f64(),
        a.out.display()
    );
    Ok(())
}

/// `restore --in clip.mp4 --out restored.mp4` (or `.gif`): the clip's frames through ffmpeg
/// into `OUT.parts/input/`, restored into `OUT.parts/restored/` ([`run_restore_folder`]), and
/// encoded at the clip's rate into `--out`; the parts folder goes when the video is written.
/// A stop keeps the frames done there, and `--resume` continues.
fn run_restore_video(a: RestoreArgs) -> Result<()> {
    if a.reference.is_some() {
        bail!("--reference: a video is restored without one (score it with restorer eval-video)");
    }
    let Some(ffmpeg) = metasplat::output::video::on_path("ffmpeg") else {
        bail!(
            "--in {}: reading a video needs ffmpeg, which is not on the PATH; install it, or restore the clip as a .gif or as a folder of frames (--in DIR --out DIR)",
            a.input.display()
        );
    };
    let format = metasplat::output::video::format_for_flag("--out", &a.out)?;
    let mut inputs = a.net.inputs();
    inputs.push(("--in", a.input.as_path()));
    metasplat::output::guard::refuse_overwrite("--out", &a.out, &inputs)?;
    let parts = PathBuf::from(format!("{}.parts", a.out.display()));
    if parts.exists() && !a.resume {
        bail!(
            "--out {}: {} holds the frames of an earlier run; --resume continues it",
            a.out.display(),
            parts.display()
        );
    }
    let (input_dir, restored_dir) = (parts.join("input"), parts.join("restored"));
    for d in [&input_dir, &restored_dir] {
        std::fs::create_dir_all(d).with_context(|| format!("cannot make {}", d.display()))?;
    }
    let rate_file = parts.join("fps");
    let fps = match std::fs::read_to_string(&rate_file)
        .ok()
        .and_then(|t| t.trim().parse::<f64>().ok())
    {
        Some(fps) if scenes::images::list_images(&input_dir).is_ok() => fps,
        _ => {
            println!(
                "Reading the frames of {} with {}.",
                a.input.display(),
                ffmpeg.display()
            );
            let fps = metasplat::output::video::decode(&ffmpeg, &a.input, &input_dir)?;
            base::write_bytes_atomically(&rate_file, fps.to_string().as_bytes())
                .with_context(|| format!("cannot write {}", rate_file.display()))?;
            fps
        }
    };
    let out = a.out.clone();
    run_restore_folder(RestoreArgs {
        input: input_dir,
        out: restored_dir.clone(),
        resume: true,
        reference: None,
        ..a
    })?;
    let frames = scenes::images::list_images(&restored_dir)?;
    metasplat::output::video::encode(&format, &frames, fps, &out)?;
    std::fs::remove_dir_all(&parts)
        .with_context(|| format!("cannot remove {}", parts.display()))?;
    println!(
        "wrote {} ({} frames at {fps} frames per second)",
        out.display(),
        frames.len()
    );
    Ok(())
}
