//! `metasplat view`: the interactive viewer on a splat scene, with a capture to compare against
//! and a training run to follow.

use anyhow::{Context, Result, bail};
use clap::Args;
use glam::Vec3;
use metasplat::output::view::{CaptureComparison, RunWatch};
use metasplat::settings::{DataOptions, RestorerChoice};
use std::path::PathBuf;

#[derive(Args)]
pub struct ViewArgs {
    /// Splat scene (.ply, .glb/.gltf or .spz), or a run folder (as --run). With --run and no
    /// file: the run's newest model.
    #[arg(conflicts_with = "input")]
    pub file: Option<PathBuf>,
    /// The splat scene, spelt as `render` and `export` spell it.
    #[arg(long = "in", visible_aliases = ["ply", "scene-file"])]
    pub input: Option<PathBuf>,
    /// Capture whose cameras to jump between and whose photos, PSF model and restorer the
    /// comparison mode shows.
    #[arg(long)]
    pub scene: Option<PathBuf>,
    /// Use the capture's images_N (1: images/); default images_8/ when it exists, else the
    /// folder there is.
    #[arg(long, requires = "scene", value_parser = clap::value_parser!(u32).range(1..=64))]
    pub downsample: Option<u32>,
    /// Source of I_ac in the comparison: `auto`, `wiener` or a restorer weights file.
    #[arg(long, default_value = "auto", requires = "scene")]
    pub restorer: RestorerChoice,
    /// A training run folder to follow: its newest checkpoint or PLY is shown as it changes.
    #[arg(long)]
    pub run: Option<PathBuf>,
    /// Open at this capture camera (its name or its index).
    #[arg(long, requires = "scene", conflicts_with = "camera")]
    pub at: Option<String>,
    /// Open at EYE looking at TARGET, as "ex,ey,ez,tx,ty,tz".
    #[arg(long, value_parser = metasplat::settings::values::camera_pose, allow_hyphen_values = true)]
    pub camera: Option<[f32; 6]>,
    /// Field of view (degrees) of the free camera, across the shorter side of the window.
    #[arg(long, default_value_t = 50.0, value_parser = metasplat::settings::values::field_angle, allow_negative_numbers = true)]
    pub fov: f64,
    /// Window size; at a capture camera with --screenshot, the capture's image size.
    #[arg(long, value_parser = clap::value_parser!(u32).range(64..=8192))]
    pub width: Option<u32>,
    /// Window height (px).
    #[arg(long, value_parser = clap::value_parser!(u32).range(64..=8192))]
    pub height: Option<u32>,
    /// Save a picture of the window after --frames frames, then close it.
    #[arg(long)]
    pub screenshot: Option<PathBuf>,
    /// With --screenshot: frames to draw before the picture is taken.
    #[arg(long, default_value_t = 3, requires = "screenshot", value_parser = clap::value_parser!(u32).range(1..=10_000))]
    pub frames: u32,
    /// With --screenshot: keep the side panel in the picture.
    #[arg(long, requires = "screenshot")]
    pub with_panel: bool,
    /// Open in comparison mode (needs --scene; at --at, or the first held-out camera).
    #[arg(long, requires = "scene", conflicts_with = "camera")]
    pub compare: bool,
}

/// The scene file and the run folder as meant (a run folder given as the file is followed, as
/// --run does), and a screenshot refused where it would replace an input.
fn resolve_inputs(a: &mut ViewArgs) -> Result<()> {
    if a.file.is_none() {
        a.file = a.input.take();
    }
    // A run folder given as the file is followed, as --run does.
    if let Some(dir) = a.file.as_ref().filter(|f| f.is_dir()) {
        if let Some(run) = &a.run {
            bail!(
                "{} is a run folder and --run names {}: give the run once",
                dir.display(),
                run.display()
            );
        }
        a.run = a.file.take();
    }
    if let Some(shot) = &a.screenshot {
        let mut inputs = Vec::new();
        if let Some(f) = &a.file {
            inputs.push(("the scene file", f.as_path()));
        }
        if let Some(s) = &a.scene {
            inputs.push(("--scene", s.as_path()));
        }
        if let Some(r) = &a.run {
            inputs.push(("--run", r.as_path()));
        }
        metasplat::output::guard::refuse_overwrite("--screenshot", shot, &inputs)?;
    }
    Ok(())
}

/// The splats to show and where they came from: the scene file, or the run's newest
/// checkpoint or PLY.
fn load_model(a: &ViewArgs, watch: Option<&mut RunWatch>) -> Result<(splat::Gaussians, String)> {
    let (model, source) = match (&a.file, watch) {
        (Some(f), _) => (super::progress::read_splats(f)?, f.display().to_string()),
        (None, Some(w)) => match w.check() {
            Some(Ok((g, what))) => {
                // "Showing step 300 of the run (…) from RUN/checkpoint.bin." names the source
                // in a sentence of its own.
                println!("{what}");
                let from = what
                    .rsplit_once(" from ")
                    .map_or(what.clone(), |(_, f)| f.trim_end_matches('.').to_string());
                (g, from)
            }
            Some(Err(e)) => bail!(e),
            None => bail!(
                "--run {}: the run has no checkpoint or PLY yet; wait for its first checkpoint",
                a.run.as_ref().expect("watch implies --run").display()
            ),
        },
        (None, None) => bail!("give a splat scene file, or --run to follow a training run"),
    };
    if model.is_empty() {
        bail!("{source}: the scene has no splats");
    }
    Ok((model, source))
}

/// The capture the renders are compared with (--scene), through the run's refined PSF grid
/// when it has one.
fn open_comparison(a: &ViewArgs) -> Result<Option<CaptureComparison>> {
    Ok(match &a.scene {
        Some(dir) => {
            let downsample = super::downsample_for(dir, a.downsample);
            let options = DataOptions {
                downsample,
                restorer: a.restorer.clone(),
                iac_cache: metasplat::train::iac_cache::for_viewing(dir, a.run.as_deref()),
                ..Default::default()
            };
            let mut c = CaptureComparison::open(dir, &options)
                .with_context(|| format!("cannot open the scene {}", dir.display()))?;
            if let Some(path) = a
                .run
                .as_ref()
                .map(|r| r.join(metasplat::output::PSF_REFINED_FILE))
                .filter(|p| p.is_file())
            {
                c.with_refined_psf(&path)?;
                println!(
                    "The comparison also shows the render through the run's refined PSF grid ({}).",
                    path.display()
                );
            }
            Some(c)
        }
        None => None,
    })
}

/// Where the view opens: at --at, looking as --camera says, at the capture's first held-out
/// camera, or framing the splats.
fn start_view(a: &ViewArgs, captures: &[viewer::CaptureView]) -> Result<viewer::Start> {
    Ok(match (&a.at, a.camera) {
        (Some(at), _) => {
            let i = captures
                .iter()
                .position(|c| &c.name == at)
                .or_else(|| at.parse::<usize>().ok().filter(|&i| i < captures.len()))
                .with_context(|| {
                    format!(
                        "--at {at}: no camera of that name or index (the capture has {} cameras, e.g. {})",
                        captures.len(),
                        captures.first().map_or("none", |c| c.name.as_str())
                    )
                })?;
            viewer::Start::Capture(i)
        }
        (None, Some(c)) => viewer::Start::LookAt {
            eye: Vec3::new(c[0], c[1], c[2]),
            target: Vec3::new(c[3], c[4], c[5]),
        },
        // With a capture, at its first held-out camera: where the comparison means most.
        (None, None) if !captures.is_empty() => {
            viewer::Start::Capture(captures.iter().position(|c| c.held_out).unwrap_or(0))
        }
        (None, None) => viewer::Start::Framing,
    })
}

pub fn run(mut a: ViewArgs) -> Result<()> {
    resolve_inputs(&mut a)?;
    let mut watch = a.run.as_deref().map(RunWatch::new);
    let (model, source) = load_model(&a, watch.as_mut())?;
    // What the run decided for its capture, as `train` said it.
    if let Some(run) = &a.run {
        for d in metasplat::output::view::decisions(run) {
            println!("{d}");
        }
    }
    let comparison = open_comparison(&a)?;
    let captures = comparison.as_ref().map_or(Vec::new(), capture_views);
    let start = start_view(&a, &captures)?;
    let default_size = match (&start, &a.screenshot) {
        (viewer::Start::Capture(i), Some(_)) => {
            [captures[*i].camera.width, captures[*i].camera.height]
        }
        _ => [960, 640],
    };
    if let Some(note) = comparison.as_ref().and_then(|c| c.describe_restorer()) {
        println!("Comparison: {note}.");
    }
    println!(
        "Viewing {} splats (SH degree {}) from {source}.",
        model.len(),
        model.sh_degree
    );
    let options = viewer::ViewerOptions {
        title: format!("metasplat — {source}"),
        model,
        captures,
        start,
        fov_y: (a.fov as f32).to_radians(),
        size: [
            a.width.unwrap_or(default_size[0]),
            a.height.unwrap_or(default_size[1]),
        ],
        background: Vec3::ZERO,
        compare: comparison.map(|c| Box::new(c) as Box<dyn viewer::CompareSource>),
        live: watch.map(|w| Box::new(w) as Box<dyn viewer::LiveSource>),
        screenshot: a.screenshot.clone().map(|path| viewer::Screenshot {
            path,
            frames: a.frames,
            with_panel: a.with_panel,
            compare: a.compare,
        }),
    };
    let report = viewer::run(options)?;
    if let Some(p) = &a.screenshot {
        println!("Saved a screenshot of the viewer to {}.", p.display());
        if let Some(ms) = report.mean_render_ms {
            println!(
                "{} frames rendered; after the first, a frame took {ms:.1} ms ({:.1} fps).",
                report.renders,
                1e3 / ms
            );
        }
    }
    Ok(())
}

/// The capture's cameras as the viewer lists them, held-out views marked.
fn capture_views(c: &CaptureComparison) -> Vec<viewer::CaptureView> {
    let cap = c.capture();
    cap.cameras
        .iter()
        .enumerate()
        .map(|(i, cam)| viewer::CaptureView {
            name: cam.name.clone(),
            camera: metasplat::splats::convert::splat_camera(cam),
            held_out: cap.split.test.contains(&i),
        })
        .collect()
}
