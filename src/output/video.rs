//! Rendered frames into one video file: through `ffmpeg` when it is on the PATH (`.mp4`,
//! `.mov`, `.webm`, `.mkv`), or an animated GIF written here (`.gif`), so that a camera path
//! becomes something to watch without any tool installed. The file is written under a
//! temporary name beside its place, with an ordinary mode, and renamed there at the end.

use std::path::{Path, PathBuf};

use crate::error::{Result, TrainError};

/// An error that says what could not be done, and why.
fn failed(what: String, why: impl std::fmt::Display) -> TrainError {
    TrainError::Invalid(format!("{what}: {why}"))
}

/// How a video file is written.
pub enum VideoFormat {
    /// Through this `ffmpeg`.
    Ffmpeg(PathBuf),
    Gif,
}

/// How `path` is written; refused before any work when it cannot be.
pub fn format_for(path: &Path) -> Result<VideoFormat> {
    format_for_flag("--video", path)
}

/// Whether `path` names a video ffmpeg reads and writes (not a GIF).
pub fn is_ffmpeg_video(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .is_some_and(|e| matches!(e.as_str(), "mp4" | "mov" | "webm" | "mkv"))
}

/// The frames of the video `input` as `dir/frame%05d.png` (from 1), through `ffmpeg`, and its
/// frame rate (30 when ffmpeg does not say). The first Ctrl-C ends the tool.
pub fn decode(ffmpeg: &Path, input: &Path, dir: &Path) -> Result<f64> {
    // ffmpeg describes the input on stderr when asked for nothing else (and exits 1).
    let probe = std::process::Command::new(ffmpeg)
        .args(["-hide_banner", "-i"])
        .arg(input)
        .stdin(std::process::Stdio::null())
        .output()
        .map_err(|e| failed(format!("cannot run {}", ffmpeg.display()), e))?;
    let fps = String::from_utf8_lossy(&probe.stderr)
        .split(',')
        .find_map(|part| part.trim().strip_suffix(" fps")?.trim().parse::<f64>().ok())
        .filter(|f| f.is_finite() && *f > 0.0)
        .unwrap_or(30.0);
    let mut command = std::process::Command::new(ffmpeg);
    command
        .args(["-hide_banner", "-loglevel", "error", "-i"])
        .arg(input)
        .args(["-vsync", "0"])
        .arg(frame_pattern(&dir.join("frame00000.png")));
    run_tool(command, ffmpeg, |status| {
        format!(
            "{} could not read the frames of {} ({status})",
            ffmpeg.display(),
            input.display()
        )
    })?;
    Ok(fps)
}

/// Runs `command` (the video tool `tool`) to its end with its input closed (its own input
/// would be the terminal's: a tool waiting on it never ends) and the first Ctrl-C honoured
/// ([`wait_or_stop`]); a failed exit is the error `on_failure` words.
fn run_tool(
    mut command: std::process::Command,
    tool: &Path,
    on_failure: impl FnOnce(std::process::ExitStatus) -> String,
) -> Result<()> {
    let child = command
        .stdin(std::process::Stdio::null())
        .spawn()
        .map_err(|e| failed(format!("cannot run {}", tool.display()), e))?;
    let status = wait_or_stop(child, tool)?;
    if !status.success() {
        return Err(TrainError::Invalid(on_failure(status)));
    }
    Ok(())
}

/// [`format_for`], naming `flag` in its refusals.
pub fn format_for_flag(flag: &str, path: &Path) -> Result<VideoFormat> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    match ext.as_deref() {
        Some("gif") => Ok(VideoFormat::Gif),
        Some("mp4" | "mov" | "webm" | "mkv") => match on_path("ffmpeg") {
            Some(ffmpeg) => Ok(VideoFormat::Ffmpeg(ffmpeg)),
            None => Err(TrainError::Invalid(format!(
                "{flag} {}: writing this format needs ffmpeg, which is not on the PATH; install it, or give a .gif file (written without it)",
                path.display()
            ))),
        },
        _ => Err(TrainError::Invalid(format!(
            "{flag} {}: a video is written as .mp4, .mov, .webm or .mkv (through ffmpeg) or as .gif",
            path.display()
        ))),
    }
}

/// The most frames per second a GIF shows: its frame time is a whole number of hundredths of
/// a second, and players show a frame of less than 2/100 s for 1/10 s.
pub const GIF_MAX_FPS: f64 = 50.0;

/// A GIF frame's time at `fps`, in hundredths of a second (the nearest it can hold); more
/// than [`GIF_MAX_FPS`] is refused naming the flag.
pub fn gif_centiseconds(fps: f64) -> Result<u32> {
    if !(fps.is_finite() && fps > 0.0) || fps > GIF_MAX_FPS {
        return Err(TrainError::Invalid(format!(
            "--fps {fps}: a .gif shows at most {GIF_MAX_FPS} frames per second (its frame time is in hundredths of a second, and players slow shorter frames to 1/10 s); write an .mp4 for more"
        )));
    }
    Ok((100.0 / fps).round().clamp(2.0, 65535.0) as u32)
}

/// The rate a video is written at for `fps` asked: a GIF's nearest.
pub fn written_fps(format: &VideoFormat, fps: f64) -> Result<f64> {
    Ok(match format {
        VideoFormat::Gif => 100.0 / gif_centiseconds(fps)? as f64,
        VideoFormat::Ffmpeg(_) => fps,
    })
}

/// The first executable file called `name` in the PATH's folders.
pub fn on_path(name: &str) -> Option<PathBuf> {
    use std::os::unix::fs::PermissionsExt;
    std::env::split_paths(&std::env::var_os("PATH")?)
        .map(|d| d.join(name))
        .find(|p| {
            p.metadata()
                .is_ok_and(|m| m.is_file() && m.permissions().mode() & 0o111 != 0)
        })
}

/// Encodes `frames` (PNG files named `frame%05d.png` in one folder, in order) at `fps` into
/// `out`.
pub fn encode(format: &VideoFormat, frames: &[PathBuf], fps: f64, out: &Path) -> Result<()> {
    match format {
        VideoFormat::Gif => {
            let delay = image::Delay::from_numer_denom_ms(10 * gif_centiseconds(fps)?, 1);
            write_gif(
                out,
                frames.iter().map(|f| {
                    let img = image::open(f)
                        .map_err(|e| failed(format!("cannot read the frame {}", f.display()), e))?;
                    Ok(image::Frame::from_parts(img.to_rgba8(), 0, 0, delay))
                }),
            )?;
        }
        VideoFormat::Ffmpeg(ffmpeg) => {
            let dir = match out.parent() {
                Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
                _ => PathBuf::from("."),
            };
            let ext = out.extension().and_then(|e| e.to_str()).unwrap_or("video");
            // ffmpeg writes over this file in place, so it keeps an ordinary mode.
            let (prefix, suffix) = (format!("{}video-", base::temp_prefix()), format!(".{ext}"));
            let mut builder = tempfile::Builder::new();
            builder.prefix(&prefix).suffix(&suffix);
            {
                use std::os::unix::fs::PermissionsExt;
                builder.permissions(std::fs::Permissions::from_mode(0o666));
            }
            let temp = builder
                .tempfile_in(&dir)
                .map_err(|e| failed(format!("cannot write in {}", dir.display()), e))?;
            let first = frames
                .first()
                .ok_or_else(|| TrainError::Invalid("no frames to encode".into()))?;
            let pattern = frame_pattern(first);
            let mut command = std::process::Command::new(ffmpeg);
            command
                .args(["-hide_banner", "-loglevel", "error", "-y", "-framerate"])
                .arg(format!("{fps}"))
                .arg("-i")
                .arg(&pattern)
                // Even sizes and 4:2:0 colour, which every player takes.
                .args([
                    "-vf",
                    "pad=ceil(iw/2)*2:ceil(ih/2)*2",
                    "-pix_fmt",
                    "yuv420p",
                ])
                .arg(temp.path());
            run_tool(command, ffmpeg, |status| {
                format!(
                    "{} could not encode {} ({status}); the frames were not kept",
                    ffmpeg.display(),
                    out.display()
                )
            })?;
            // A tool that says it succeeded but wrote nothing does not make a video.
            let written = temp.as_file().metadata().map_or(0, |m| m.len());
            if written == 0 {
                return Err(TrainError::Invalid(format!(
                    "{} exited successfully but wrote nothing for {}; the frames were not kept",
                    ffmpeg.display(),
                    out.display()
                )));
            }
            temp.persist(out)
                .map_err(|e| TrainError::io(out, e.error))?;
        }
    }
    Ok(())
}

/// Writes `frames` (each with its own delay) as a looping GIF to `out`, atomically; the first
/// frame that cannot be made stops it with nothing written.
pub fn write_gif(out: &Path, frames: impl IntoIterator<Item = Result<image::Frame>>) -> Result<()> {
    use image::codecs::gif::{GifEncoder, Repeat};
    let mut bytes = Vec::new();
    {
        let gif_failed = |e| failed(format!("cannot encode {}", out.display()), e);
        let mut encoder = GifEncoder::new_with_speed(&mut bytes, 10);
        encoder.set_repeat(Repeat::Infinite).map_err(gif_failed)?;
        for frame in frames {
            encoder.encode_frame(frame?).map_err(gif_failed)?;
        }
    }
    base::write_bytes_atomically(out, &bytes).map_err(|e| TrainError::io(out, e))
}

/// Waits for `child`, polling so that the first Ctrl-C, SIGTERM or SIGHUP ends it (a hung
/// tool would otherwise hold the process until a second signal killed it with the frames,
/// lock and temporary video still on disk); the caller's cleanup then runs as usual.
pub fn wait_or_stop(
    mut child: std::process::Child,
    tool: &Path,
) -> Result<std::process::ExitStatus> {
    loop {
        if let Some(status) = child
            .try_wait()
            .map_err(|e| failed(format!("cannot wait for {}", tool.display()), e))?
        {
            return Ok(status);
        }
        if base::interrupt::requested() {
            let _ = child.kill();
            let _ = child.wait();
            return Err(TrainError::Interrupted(format!(
                "stopped while {} encoded the video; nothing was written",
                tool.display()
            )));
        }
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
}

/// ffmpeg's pattern for the frames beside `first` (`frame%05d.png`): a `%` in the folder's
/// path is written `%%`, which ffmpeg reads as the character itself.
fn frame_pattern(first: &Path) -> PathBuf {
    use std::os::unix::ffi::{OsStrExt, OsStringExt};
    let dir = first.parent().unwrap_or(Path::new("."));
    let mut bytes = Vec::new();
    for &b in dir.as_os_str().as_bytes() {
        bytes.push(b);
        if b == b'%' {
            bytes.push(b'%');
        }
    }
    PathBuf::from(std::ffi::OsString::from_vec(bytes)).join("frame%05d.png")
}

#[cfg(test)]
mod tests {
    #[test]
    fn a_percent_in_the_frames_folder_reaches_ffmpeg_as_itself() {
        let p = super::frame_pattern(std::path::Path::new("/out/50% scale/frame00000.png"));
        assert_eq!(p, std::path::Path::new("/out/50%% scale/frame%05d.png"));
    }

    #[test]
    fn a_gif_holds_the_nearest_frame_time_and_refuses_rates_it_cannot_show() {
        let gif = super::VideoFormat::Gif;
        assert_eq!(super::gif_centiseconds(30.0).unwrap(), 3);
        assert_eq!(super::written_fps(&gif, 30.0).unwrap(), 100.0 / 3.0);
        assert_eq!(super::gif_centiseconds(0.1).unwrap(), 1000);
        assert_eq!(super::written_fps(&gif, 50.0).unwrap(), 50.0);
        let e = super::gif_centiseconds(60.0).unwrap_err().to_string();
        assert!(e.contains("--fps 60") && e.contains(".mp4"), "{e}");
    }
}
