//! What `metasplat scene info` reports about a capture.

use std::fmt;
use std::path::PathBuf;

use crate::camera::Distortion;
use crate::capture::{Capture, CaptureFormat, PointSource};
use crate::colmap::ModelFormat;

#[derive(Clone, Debug, PartialEq)]
pub struct SceneSummary {
    pub root: PathBuf,
    pub format: CaptureFormat,
    pub image_dir: PathBuf,
    pub cameras: usize,
    /// Distinct image sizes in camera order (one for a well-formed LLFF capture).
    pub resolutions: Vec<(u32, u32)>,
    pub downsample: f64,
    /// Smallest and largest focal lengths, x and y together, in pixels of the loaded images.
    pub focal_range: (f64, f64),
    pub train: usize,
    pub test: usize,
    pub llffhold: usize,
    /// Smallest near and largest far over all images.
    pub near: f64,
    pub far: f64,
    pub points: usize,
    pub point_source: PointSource,
    /// 3DGS's scene extent (`getNerfppNorm` radius).
    pub extent: f64,
    pub distortion: Option<Distortion>,
    pub distortion_source: Option<PathBuf>,
    /// Pixels of the first undistorted photo with no source in it (None: kept as taken).
    pub undistorted_without_source: Option<usize>,
    /// Where the loss masks come from ([`Capture::mask_source`]).
    pub masks: String,
}

impl SceneSummary {
    pub fn of(capture: &Capture) -> SceneSummary {
        let mut resolutions = Vec::new();
        for c in &capture.cameras {
            if !resolutions.contains(&(c.width, c.height)) {
                resolutions.push((c.width, c.height));
            }
        }
        let focals = capture.cameras.iter().flat_map(|c| [c.fx, c.fy]);
        let focal_range = focals.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), f| {
            (lo.min(f), hi.max(f))
        });
        SceneSummary {
            root: capture.root.clone(),
            format: capture.format,
            image_dir: capture.image_dir.clone(),
            cameras: capture.len(),
            resolutions,
            downsample: capture.downsample,
            focal_range,
            train: capture.split.train.len(),
            test: capture.split.test.len(),
            llffhold: capture.split.llffhold,
            near: capture
                .bounds
                .iter()
                .map(|b| b.near)
                .fold(f64::INFINITY, f64::min),
            far: capture
                .bounds
                .iter()
                .map(|b| b.far)
                .fold(f64::NEG_INFINITY, f64::max),
            points: capture.points.len(),
            point_source: capture.point_source.clone(),
            extent: capture.normalization().radius,
            distortion: capture.cameras.iter().find_map(|c| c.distortion),
            distortion_source: capture.distortion_source.clone(),
            undistorted_without_source: capture
                .remaps
                .iter()
                .flatten()
                .next()
                .map(|r| r.invalid_count()),
            masks: capture.mask_source(),
        }
    }
}

impl fmt::Display for SceneSummary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let format = match self.format {
            CaptureFormat::Llff => "LLFF (poses_bounds.npy)",
            CaptureFormat::Colmap(ModelFormat::Binary) => "COLMAP sparse model, binary",
            CaptureFormat::Colmap(ModelFormat::Text) => "COLMAP sparse model, text",
            CaptureFormat::Nerfstudio => "nerfstudio (transforms.json; bounds from the camera rig)",
        };
        writeln!(f, "scene       {}", self.root.display())?;
        writeln!(f, "format      {format}")?;
        writeln!(f, "images      {}", self.image_dir.display())?;
        writeln!(f, "masks       {}", self.masks)?;
        writeln!(f, "cameras     {}", self.cameras)?;
        let sizes: Vec<String> = self
            .resolutions
            .iter()
            .map(|(w, h)| format!("{w}x{h}"))
            .collect();
        writeln!(
            f,
            "resolution  {} (downsample {} from full resolution)",
            sizes.join(", "),
            self.downsample
        )?;
        let (lo, hi) = self.focal_range;
        if (hi - lo).abs() <= 1e-9 * hi.abs() {
            writeln!(f, "focal       {lo:.4} px")?;
        } else {
            writeln!(f, "focal       {lo:.4} .. {hi:.4} px")?;
        }
        let hold = if self.llffhold == 0 {
            "none held out".to_string()
        } else {
            format!("every {}th image held out", self.llffhold)
        };
        writeln!(
            f,
            "split       {} train, {} test ({hold})",
            self.train, self.test
        )?;
        writeln!(f, "bounds      near {:.4}, far {:.4}", self.near, self.far)?;
        match &self.point_source {
            PointSource::Sparse(p) => {
                writeln!(f, "points      {} from {}", self.points, p.display())?
            }
            PointSource::Random {
                count,
                seed,
                background: 0,
            } => writeln!(
                f,
                "points      {count} random in the camera frusta (seed {seed})"
            )?,
            PointSource::Random {
                count,
                seed,
                background,
            } => writeln!(
                f,
                "points      {count} random (seed {seed}): {} in the camera frusta, {background} on a background shell behind them",
                count - background
            )?,
        }
        writeln!(
            f,
            "extent      {:.4} (3DGS camera radius x 1.1)",
            self.extent
        )?;
        match (&self.distortion, &self.distortion_source) {
            (Some(d), src) => {
                let from = src
                    .as_ref()
                    .map(|p| format!(" from {}", p.display()))
                    .unwrap_or_default();
                match self.undistorted_without_source {
                    Some(0) => write!(
                        f,
                        "distortion  {d}{from}; images undistorted at load onto the pinhole camera of the same intrinsics"
                    ),
                    Some(n) => write!(
                        f,
                        "distortion  {d}{from}; images undistorted at load onto the pinhole camera of the same intrinsics ({n} border pixels have no source and leave the loss)"
                    ),
                    None => write!(
                        f,
                        "distortion  {d}{from}; kept on the cameras, images NOT undistorted (undistortion turned off)"
                    ),
                }
            }
            (None, _) => write!(f, "distortion  none (pinhole)"),
        }
    }
}
