//! A loaded capture and [`open`], which recognises LLFF and COLMAP layouts.
//!
//! Layouts, relative to the scene folder:
//! - LLFF: `poses_bounds.npy` plus `images/` or `images_N/`; when `sparse/0/` holds the COLMAP
//!   model the poses came from, its `points3D` seeds the point cloud and the distortion of its
//!   (single, full-resolution) camera is attached to every camera for reporting.
//! - COLMAP: `sparse/0/` (or `sparse/`) with `cameras`, `images` and optionally `points3D`, as
//!   `.bin` or `.txt` (binary preferred), plus `images/` or `images_N/`. Near/far bounds come
//!   from the depths of each image's observed points, as LLFF's `imgs2poses` computes them.

use std::path::{Path, PathBuf};

use rayon::prelude::*;

use crate::camera::{Bounds, Camera};
use crate::colmap::{self, ColmapModel, ModelFormat};
use crate::error::{Result, SceneError};
use crate::images::{self, Photo};
use crate::limits;
use crate::llff::{self, POSES_BOUNDS};
use crate::nerfstudio;
use crate::points::{self, Normalization, PointCloud};
use crate::split::{self, Split};
use crate::summary::SceneSummary;
use crate::undistort::Remap;

/// The folder of per-image loss masks (white = keep), beside the image folders.
pub const MASK_DIR: &str = "masks";

/// Which image folder to read.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Resolution {
    /// `images/` for 1, `images_N/` otherwise.
    Downsample(u32),
    /// The folder (`images/` or any `images_N/`) with the largest width not above this; when
    /// every folder is wider, the narrowest.
    TargetWidth(u32),
}

impl Default for Resolution {
    fn default() -> Self {
        Resolution::Downsample(1)
    }
}

#[derive(Clone, Debug, PartialEq)]
pub struct OpenOptions {
    pub resolution: Resolution,
    /// Every `llffhold`-th image is held out for testing; 0 holds none out.
    pub llffhold: usize,
    /// Size of the random cloud used when the capture has no `points3D`.
    pub random_points: usize,
    /// Seed of that random cloud.
    pub seed: u64,
    /// Resample distorted photos onto the pinhole camera of the same intrinsics at load
    /// ([`crate::undistort`]); false keeps them as taken.
    pub undistort: bool,
    /// Keep photos shrunk or undistorted at load beside the capture ([`crate::photo_cache`]),
    /// when its folder can be written, and read them from there.
    pub cache_photos: bool,
}

impl Default for OpenOptions {
    fn default() -> Self {
        OpenOptions {
            resolution: Resolution::default(),
            llffhold: split::LLFFHOLD,
            random_points: points::DEFAULT_RANDOM_POINTS,
            seed: 0,
            undistort: true,
            cache_photos: false,
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CaptureFormat {
    Llff,
    Colmap(ModelFormat),
    /// nerfstudio's `transforms.json`.
    Nerfstudio,
}

/// Where the initial point cloud came from.
#[derive(Clone, Debug, PartialEq)]
pub enum PointSource {
    Sparse(PathBuf),
    /// `background` of the `count` points lie on the far shell
    /// ([`points::random_on_background_shell`]), the rest in the frusta.
    Random {
        count: usize,
        seed: u64,
        background: usize,
    },
}

/// Forward-facing captures keep their viewing directions within a cone (fern: a mean
/// direction of length above 0.99); a ring of cameras around an object averages out to its
/// elevation's sine (0.3–0.6 for usual turntable heights).
pub const SURROUND_MAX_MEAN_DIRECTION: f64 = 0.7;

/// See [`Capture::surrounds_scene`].
pub fn surrounds(cameras: &[Camera]) -> bool {
    if cameras.len() < 3 {
        return false;
    }
    let sum = cameras
        .iter()
        .map(|c| c.camera_to_world().rotation * glam::DVec3::Z)
        .fold(glam::DVec3::ZERO, |a, d| a + d.normalize_or_zero());
    (sum / cameras.len() as f64).length() < SURROUND_MAX_MEAN_DIRECTION
}

/// A capture with everything but the pixels loaded; images load on demand.
#[derive(Clone, Debug)]
pub struct Capture {
    pub root: PathBuf,
    pub format: CaptureFormat,
    pub image_dir: PathBuf,
    /// One per camera, same order.
    pub image_paths: Vec<PathBuf>,
    /// Sorted by image file name.
    pub cameras: Vec<Camera>,
    pub bounds: Vec<Bounds>,
    pub points: PointCloud,
    pub point_source: PointSource,
    pub split: Split,
    /// Full-resolution width over loaded width (8 for `images_8/`).
    pub downsample: f64,
    /// The COLMAP cameras file the cameras' distortion came from, if any.
    pub distortion_source: Option<PathBuf>,
    /// How many times smaller than its file each photo is loaded (1: as it is): a downsample
    /// whose `images_N/` the capture lacks is made from `images/` at load.
    pub shrink: u32,
    /// Per camera, the undistortion its photo goes through at load (empty: none); cameras of
    /// the same intrinsics share one.
    pub remaps: Vec<Option<std::sync::Arc<Remap>>>,
    /// Where photos made at load (shrunk or undistorted) are cached; None: made at each load.
    pub photo_cache: Option<PathBuf>,
    /// Per camera, the mask a `transforms.json` frame names (`mask_path`); empty for other
    /// formats and for captures whose frames name none.
    pub mask_paths: Vec<Option<PathBuf>>,
}

impl Capture {
    pub fn len(&self) -> usize {
        self.cameras.len()
    }

    pub fn is_empty(&self) -> bool {
        self.cameras.is_empty()
    }

    /// Decodes image `index`, checking it still has its camera's size.
    pub fn load_image(&self, index: usize) -> Result<Photo> {
        let (Some(path), Some(camera)) = (self.image_paths.get(index), self.cameras.get(index))
        else {
            return Err(SceneError::invalid(
                &self.image_dir,
                format!("image index {index} out of range 0..{}", self.len()),
            ));
        };
        let remap = self.remaps.get(index).and_then(Option::as_deref);
        // A photo made at load is read from the cache when it holds it; the file's bytes are
        // read for the key (a photo edited since is another entry), not decoded.
        let cached = match &self.photo_cache {
            Some(dir) if self.shrink > 1 || remap.is_some() => {
                base::input::read(path).ok().map(|b| {
                    let key =
                        crate::photo_cache::key(&b, self.shrink, remap.map(|r| r.fingerprint));
                    (dir, key)
                })
            }
            _ => None,
        };
        if let Some((dir, key)) = &cached
            && let Some(photo) = crate::photo_cache::get(dir, *key, camera.width, camera.height)
        {
            return Ok(photo);
        }
        let mut image = images::load_rgb(path)?;
        if self.shrink > 1 {
            image = image.shrunk(self.shrink);
        }
        if (image.width, image.height) != (camera.width, camera.height) {
            return Err(SceneError::invalid(
                path,
                format!(
                    "decoded {}x{}, expected {}x{}",
                    image.width, image.height, camera.width, camera.height
                ),
            ));
        }
        if let Some(remap) = remap {
            image = remap.apply(&image);
        }
        // A cache that cannot be written costs the next run a decode, nothing more.
        if let Some((dir, key)) = &cached {
            let _ = crate::photo_cache::put(dir, *key, &image);
        }
        Ok(image)
    }

    /// Whether the photos are undistorted at load.
    pub fn undistorted(&self) -> bool {
        self.remaps.iter().any(Option::is_some)
    }

    /// The loss mask of image `index` (1 keeps a pixel, 0 leaves it out of the loss), at the
    /// camera's size: `masks/<stem>.png` (or `.jpg`; grey, white = keep) when the capture has a
    /// `masks/` folder, else the photo's own alpha channel, else None (every pixel counts).
    pub fn load_mask(&self, index: usize) -> Result<Option<Vec<f32>>> {
        let mask = self.load_mask_as_taken(index)?;
        // Undistorted, the pixels the photo has no source for leave the loss too.
        Ok(match self.remaps.get(index) {
            Some(Some(remap)) if mask.is_some() || remap.invalid_count() > 0 => {
                Some(remap.apply_mask(mask.as_deref()))
            }
            _ => mask,
        })
    }

    /// The folder masks come from: `masks_N/` beside `images_N/` when there is one, else
    /// `masks/` (at the photos' size, or at full size and shrunk with them); None without
    /// either.
    pub fn mask_folder(&self) -> Option<PathBuf> {
        let beside = self
            .image_dir
            .file_name()
            .and_then(|n| n.to_str())
            .and_then(|n| n.strip_prefix("images_"))
            .map(|n| self.root.join(format!("{MASK_DIR}_{n}")))
            .filter(|d| d.is_dir());
        beside.or_else(|| Some(self.root.join(MASK_DIR)).filter(|d| d.is_dir()))
    }

    /// Whether the capture has masks of its own (a folder of them or `transforms.json`'s
    /// `mask_path`), besides the photos' alpha and the border undistortion leaves.
    pub fn has_own_masks(&self) -> bool {
        self.mask_paths.iter().any(Option::is_some) || self.mask_folder().is_some()
    }

    /// Where the loss masks come from, in words (`scene info`, `train`).
    pub fn mask_source(&self) -> String {
        if self.mask_paths.iter().any(Option::is_some) {
            return "the mask_path of each frame in transforms.json".into();
        }
        match self.mask_folder() {
            Some(d) if d.file_name().is_some_and(|n| n == MASK_DIR) => format!(
                "{MASK_DIR}/ (at the photos' size, or larger by a whole factor and shrunk to it)"
            ),
            Some(d) => format!("{}/", d.strip_prefix(&self.root).unwrap_or(&d).display()),
            None if self.undistorted() => "none in a folder; the photos' alpha channel where they have one, and the border undistortion leaves without a source".into(),
            None => "none in a folder; the photos' alpha channel where they have one".into(),
        }
    }

    fn load_mask_as_taken(&self, index: usize) -> Result<Option<Vec<f32>>> {
        let (Some(path), Some(camera)) = (self.image_paths.get(index), self.cameras.get(index))
        else {
            return Ok(None);
        };
        let named = self.mask_paths.get(index).cloned().flatten();
        let folder = self.mask_folder();
        let decoded = if let Some(mask) = named {
            let grey = images::load_grey(&mask)?;
            Some((mask, grey))
        } else if let Some(folder) = folder {
            let stem = stem(path);
            let Some(mask) = ["png", "jpg", "jpeg"]
                .iter()
                .map(|e| folder.join(format!("{stem}.{e}")))
                .find(|p| p.is_file())
            else {
                return Err(SceneError::NotFound {
                    path: folder.join(format!("{stem}.png")),
                    what: format!(
                        "mask of {} (the capture has a {}/ folder)",
                        path.display(),
                        folder
                            .file_name()
                            .map_or_else(|| MASK_DIR.into(), |n| n.to_string_lossy().into_owned())
                    ),
                });
            };
            let grey = images::load_grey(&mask)?;
            Some((mask, grey))
        } else {
            images::load_alpha(path)?.map(|m| (path.clone(), m))
        };
        let Some((source, mut mask)) = decoded else {
            return Ok(None);
        };
        // A mask larger than its photo by a whole factor (a full-size `masks/` beside
        // `images_N/`, or beside `images/` shrunk at load) is shrunk by that factor.
        let factor = mask.width / camera.width.max(1);
        if factor > 1
            && (mask.width / factor, mask.height / factor) == (camera.width, camera.height)
        {
            mask = mask.shrunk(factor);
        }
        if (mask.width, mask.height) != (camera.width, camera.height) {
            return Err(SceneError::invalid(
                &source,
                format!(
                    "mask is {}x{}, its image {}x{}",
                    mask.width, mask.height, camera.width, camera.height
                ),
            ));
        }
        Ok(Some(mask.data.chunks_exact(3).map(|p| p[0]).collect()))
    }

    /// Decodes several images in parallel, in the order given, with at most
    /// [`MAX_PIXELS_IN_FLIGHT`] pixels being decoded at once.
    pub fn load_images(&self, indices: &[usize]) -> Result<Vec<Photo>> {
        self.load_images_within(indices, MAX_PIXELS_IN_FLIGHT)
    }

    /// [`Capture::load_images`] decoding at most `budget` file pixels at once (at least one
    /// image at a time): the photos are decoded in consecutive groups that fit, each group in
    /// parallel, so that the decoders' working memory does not grow with the thread count.
    pub fn load_images_within(&self, indices: &[usize], budget: u64) -> Result<Vec<Photo>> {
        let mut photos = Vec::with_capacity(indices.len());
        for group in decode_groups(indices, |i| self.file_pixels(i), budget) {
            let decoded: Vec<Photo> = group
                .par_iter()
                .map(|&i| self.load_image(i))
                .collect::<Result<_>>()?;
            photos.extend(decoded);
        }
        Ok(photos)
    }

    /// Decodes every image, keeping none, at most `budget` file pixels at once: what finds a
    /// damaged photo before a command makes its output (opening a capture reads headers
    /// only).
    pub fn check_images_within(&self, budget: u64) -> Result<()> {
        let all: Vec<usize> = (0..self.len()).collect();
        for group in decode_groups(&all, |i| self.file_pixels(i), budget) {
            group
                .par_iter()
                .try_for_each(|&i| self.load_image(i).map(drop))?;
        }
        Ok(())
    }

    /// [`Capture::check_images_within`] at [`MAX_PIXELS_IN_FLIGHT`].
    pub fn check_images(&self) -> Result<()> {
        self.check_images_within(MAX_PIXELS_IN_FLIGHT)
    }

    /// Pixels of image `index`'s file (before any shrink at load), from its camera.
    fn file_pixels(&self, index: usize) -> u64 {
        self.cameras.get(index).map_or(0, |c| {
            let s = u64::from(self.shrink.max(1));
            u64::from(c.width) * s * u64::from(c.height) * s
        })
    }

    /// True when the cameras look at the scene from around it (an object or room captured
    /// all around) rather than from one side (LLFF's forward-facing captures): their unit
    /// viewing directions average to less than [`SURROUND_MAX_MEAN_DIRECTION`] in length.
    pub fn surrounds_scene(&self) -> bool {
        surrounds(&self.cameras)
    }

    pub fn normalization(&self) -> Normalization {
        Normalization::from_cameras(&self.cameras)
    }

    pub fn summary(&self) -> SceneSummary {
        SceneSummary::of(self)
    }
}

/// Most file pixels the parallel loaders decode at once: as many as the largest image a
/// capture may hold, so a capture of huge photos decodes them one by one while thumbnails
/// still go through every thread together.
pub const MAX_PIXELS_IN_FLIGHT: u64 = base::limits::MAX_IMAGE_PIXELS;

/// `indices` cut into consecutive groups whose `pixels` sum to at most `budget`; an image
/// larger than the budget is a group of its own.
fn decode_groups(indices: &[usize], pixels: impl Fn(usize) -> u64, budget: u64) -> Vec<&[usize]> {
    let mut groups = Vec::new();
    let (mut start, mut sum) = (0, 0u64);
    for (k, &i) in indices.iter().enumerate() {
        let p = pixels(i);
        if k > start && sum.saturating_add(p) > budget {
            groups.push(&indices[start..k]);
            (start, sum) = (k, 0);
        }
        sum = sum.saturating_add(p);
    }
    if start < indices.len() {
        groups.push(&indices[start..]);
    }
    groups
}

/// Opens the capture in `dir`, LLFF if it has `poses_bounds.npy`, else COLMAP.
pub fn open(dir: &Path, options: &OpenOptions) -> Result<Capture> {
    if dir.exists() && !dir.is_dir() {
        return Err(SceneError::invalid(
            dir,
            "is a file, not a capture folder (a folder holding images/ and poses)",
        ));
    }
    if !dir.is_dir() {
        return Err(SceneError::NotFound {
            path: dir.to_path_buf(),
            what: "scene folder".into(),
        });
    }
    let mut capture = if dir.join(POSES_BOUNDS).exists() {
        open_llff(dir, options)?
    } else {
        match colmap::sparse_dir(dir) {
            Some(sparse) if colmap::find_file(&sparse, "images").is_some() => {
                open_colmap(dir, &sparse, options)?
            }
            _ if dir.join(nerfstudio::TRANSFORMS).is_file() => open_transforms(dir, options)?,
            _ => {
                return Err(SceneError::invalid(
                    dir,
                    "not a capture: no poses_bounds.npy, no sparse/0/{cameras,images}.{bin,txt} and no transforms.json",
                ));
            }
        }
    };
    if options.undistort {
        capture.remaps = remaps(&capture.cameras);
    }
    if options.cache_photos && (capture.shrink > 1 || capture.undistorted()) {
        capture.photo_cache = crate::photo_cache::location(&capture.root);
    }
    Ok(capture)
}

/// One [`Remap`] per distinct distorted camera (the same intrinsics and coefficients share
/// one), None for the pinhole ones.
fn remaps(cameras: &[Camera]) -> Vec<Option<std::sync::Arc<Remap>>> {
    let mut made: Vec<(Vec<u64>, std::sync::Arc<Remap>)> = Vec::new();
    cameras
        .iter()
        .map(|c| {
            let d = c.distortion.filter(|d| !d.is_zero())?;
            let key: Vec<u64> = [c.fx, c.fy, c.cx, c.cy, d.k1, d.k2, d.p1, d.p2]
                .iter()
                .chain(&d.rational)
                .map(|v| v.to_bits())
                .chain([c.width as u64, c.height as u64])
                .collect();
            if let Some((_, r)) = made.iter().find(|(k, _)| *k == key) {
                return Some(r.clone());
            }
            let r = std::sync::Arc::new(Remap::new(c, &d));
            made.push((key, r.clone()));
            Some(r)
        })
        .collect()
}

fn image_folders(root: &Path) -> Vec<PathBuf> {
    let mut folders: Vec<PathBuf> = std::fs::read_dir(root)
        .into_iter()
        .flatten()
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.is_dir())
        .filter(|p| {
            let name = p.file_name().and_then(|n| n.to_str()).unwrap_or("");
            name == "images"
                || name
                    .strip_prefix("images_")
                    .is_some_and(|n| n.parse::<u32>().is_ok())
        })
        .collect();
    folders.sort();
    folders
}

/// The downsample an image folder holds: 1 for `images/`, N for `images_N/`.
fn folder_downsample(dir: &Path) -> Option<u32> {
    let name = dir.file_name()?.to_str()?;
    match name.strip_prefix("images_") {
        Some(n) => n.parse().ok(),
        None => (name == "images").then_some(1),
    }
}

/// The downsample factors a capture has image folders for (1 for `images/`), ascending.
pub fn image_downsamples(root: &Path) -> Vec<u32> {
    let mut found: Vec<u32> = image_folders(root)
        .iter()
        .filter_map(|p| folder_downsample(p))
        .collect();
    found.sort_unstable();
    found
}

/// The image folder to read and how many times to shrink its photos at load: `images_N/`
/// as it is when the capture has it, else `images/` shrunk `N` times.
fn image_source(root: &Path, resolution: Resolution) -> Result<(PathBuf, u32)> {
    if let Resolution::Downsample(n) = resolution
        && n > 1
        && !root.join(llff::image_folder_name(n)).is_dir()
        && root.join("images").is_dir()
    {
        return Ok((root.join("images"), n));
    }
    Ok((choose_image_dir(root, resolution)?, 1))
}

/// `(w, h)` of a photo shrunk `n` times, refused when nothing would be left.
fn shrunk_size(path: &Path, (w, h): (u32, u32), n: u32) -> Result<(u32, u32)> {
    let (sw, sh) = (w / n.max(1), h / n.max(1));
    if sw == 0 || sh == 0 {
        return Err(SceneError::invalid(
            path,
            format!("{w}x{h} px shrunk {n} times leaves no pixel: use a smaller --downsample"),
        ));
    }
    Ok((sw, sh))
}

fn choose_image_dir(root: &Path, resolution: Resolution) -> Result<PathBuf> {
    let available = || {
        let names: Vec<String> = image_folders(root)
            .iter()
            .filter_map(|p| p.file_name().map(|n| n.to_string_lossy().into_owned()))
            .collect();
        if names.is_empty() {
            "no images/ or images_N/ folders".to_string()
        } else {
            format!("available: {}", names.join(", "))
        }
    };
    match resolution {
        Resolution::Downsample(n) => {
            let dir = root.join(llff::image_folder_name(n));
            if dir.is_dir() {
                Ok(dir)
            } else {
                Err(SceneError::NotFound {
                    path: dir,
                    what: format!("image folder for downsample {n} ({})", available()),
                })
            }
        }
        Resolution::TargetWidth(target) => {
            let mut sized = Vec::new();
            for dir in image_folders(root) {
                let first = images::list_images(&dir)?.remove(0);
                sized.push((images::image_size(&first)?.0, dir));
            }
            let below = sized
                .iter()
                .filter(|(w, _)| *w <= target)
                .max_by_key(|(w, _)| *w);
            let chosen = below.or_else(|| sized.iter().min_by_key(|(w, _)| *w));
            chosen
                .map(|(_, d)| d.clone())
                .ok_or_else(|| SceneError::NotFound {
                    path: root.join("images"),
                    what: format!("image folder ({})", available()),
                })
        }
    }
}

fn stem(path: &Path) -> String {
    path.file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default()
}

fn open_llff(root: &Path, options: &OpenOptions) -> Result<Capture> {
    let poses_path = root.join(POSES_BOUNDS);
    let poses = llff::read_poses_bounds(&poses_path)?;
    let (image_dir, shrink) = image_source(root, options.resolution)?;
    let image_paths = images::list_images(&image_dir)?;
    if image_paths.len() != poses.len() {
        return Err(SceneError::CountMismatch {
            poses_file: poses_path,
            poses: poses.len(),
            image_dir,
            images: image_paths.len(),
        });
    }
    check_stems(&image_paths)?;
    let (width, height) = shrunk_size(&image_paths[0], images::common_size(&image_paths)?, shrink)?;
    let mut cameras = Vec::with_capacity(poses.len());
    for (row, (pose, path)) in poses.iter().zip(&image_paths).enumerate() {
        limits::check_downsample((pose.width, pose.height), (width, height)).map_err(|p| {
            SceneError::invalid(path, format!("{p} (row {row} of {})", poses_path.display()))
        })?;
        if !limits::same_aspect((pose.width, pose.height), (width, height)) {
            return Err(SceneError::invalid(
                path,
                format!(
                    "image is {width}x{height} but row {row} of {} records {}x{} (aspect differs)",
                    poses_path.display(),
                    pose.width,
                    pose.height
                ),
            ));
        }
        cameras.push(pose.to_camera(&stem(path), width, height));
    }
    let bounds: Vec<Bounds> = poses.iter().map(|p| p.bounds).collect();

    let sparse = colmap::sparse_dir(root);
    let mut distortion_source = None;
    if let Some((cameras_path, _)) = sparse
        .as_deref()
        .and_then(|d| colmap::find_file(d, "cameras"))
    {
        let model_cameras = colmap::read_cameras(&cameras_path)?;
        // Only a single full-resolution camera unambiguously describes every LLFF image.
        if let [c] = model_cameras.as_slice()
            && poses
                .iter()
                .all(|p| p.width == c.width as f64 && p.height == c.height as f64)
            && let Some(d) = c.intrinsics().distortion
        {
            for camera in &mut cameras {
                camera.distortion = Some(d);
            }
            distortion_source = Some(cameras_path);
        }
    }
    let (points, point_source) =
        initial_points(sparse.as_deref(), None, &cameras, &bounds, options)?;
    Ok(Capture {
        root: root.to_path_buf(),
        format: CaptureFormat::Llff,
        image_dir,
        split: split::split(cameras.len(), options.llffhold),
        downsample: poses[0].width / width as f64,
        image_paths,
        cameras,
        bounds,
        points,
        point_source,
        distortion_source,
        remaps: Vec::new(),
        photo_cache: None,
        mask_paths: Vec::new(),
        shrink,
    })
}

fn open_transforms(root: &Path, options: &OpenOptions) -> Result<Capture> {
    // Frames name their photos wherever they are at full size (not always under images/);
    // a downsample reads images_N/, or images/ shrunk, as the other layouts do.
    let (folder, shrink) = match options.resolution {
        Resolution::Downsample(1) => (1, 1),
        // Photos in another folder than images/ (and no images_N/): read as named, shrunk.
        Resolution::Downsample(n)
            if !root.join(llff::image_folder_name(n)).is_dir() && !root.join("images").is_dir() =>
        {
            (1, n)
        }
        resolution => {
            let (dir, shrink) = image_source(root, resolution)?;
            (folder_downsample(&dir).unwrap_or(1), shrink)
        }
    };
    let nerfstudio::Transforms {
        mut frames,
        ply_file,
    } = nerfstudio::read_transforms(root, folder)?;
    if shrink > 1 {
        for f in &mut frames {
            let (w, h) = shrunk_size(&f.path, (f.camera.width, f.camera.height), shrink)?;
            f.camera = f.camera.resized(w, h);
        }
    }
    frames.sort_by(|a, b| {
        let name = |f: &nerfstudio::Frame| f.path.file_name().map(|n| n.to_os_string());
        name(a).cmp(&name(b))
    });
    let image_paths: Vec<PathBuf> = frames.iter().map(|f| f.path.clone()).collect();
    check_stems(&image_paths)?;
    images::common_size(&image_paths)?;
    let mask_paths: Vec<Option<PathBuf>> = frames.iter().map(|f| f.mask.clone()).collect();
    let cameras: Vec<Camera> = frames.into_iter().map(|f| f.camera).collect();
    let bounds = nerfstudio::rig_bounds(&cameras);
    let (points, point_source) = match ply_file {
        Some(ply) => (
            crate::point_ply::read_points_ply(&ply)?,
            PointSource::Sparse(ply),
        ),
        None => initial_points(None, None, &cameras, &bounds, options)?,
    };
    let distortion_source = cameras
        .iter()
        .any(|c| c.distortion.is_some())
        .then(|| root.join(nerfstudio::TRANSFORMS));
    Ok(Capture {
        root: root.to_path_buf(),
        format: CaptureFormat::Nerfstudio,
        image_dir: root.join(llff::image_folder_name(folder)),
        split: split::split(cameras.len(), options.llffhold),
        downsample: (folder * shrink) as f64,
        image_paths,
        cameras,
        bounds,
        points,
        point_source,
        distortion_source,
        remaps: Vec::new(),
        photo_cache: None,
        mask_paths,
        shrink,
    })
}

/// Renders, clean copies and caches are named by each image's stem, so two images may not
/// share one (`a.png` and `a.jpg`): refused naming both before anything is written.
fn check_stems(image_paths: &[PathBuf]) -> Result<()> {
    let stems = image_paths.iter().map(|p| stem(p)).zip(image_paths);
    if let Some((name, first, second)) = crate::colmap::first_repeat(stems) {
        return Err(SceneError::invalid(
            second,
            format!(
                "has the name {name:?} of {} too: the outputs of both would have one name; rename one",
                first.display()
            ),
        ));
    }
    Ok(())
}

/// `points3D` from the sparse folder when present (already-read points passed in are used
/// as is), else a seeded random cloud in the frusta.
fn initial_points(
    sparse: Option<&Path>,
    model: Option<&ColmapModel>,
    cameras: &[Camera],
    bounds: &[Bounds],
    options: &OpenOptions,
) -> Result<(PointCloud, PointSource)> {
    if let Some((path, _)) = sparse.and_then(|d| colmap::find_file(d, "points3D")) {
        let read;
        let points = match model {
            Some(m) => &m.points,
            None => {
                read = colmap::read_points3d(&path)?;
                &read
            }
        };
        if !points.is_empty() {
            let cloud = PointCloud {
                positions: points.iter().map(|p| p.xyz).collect(),
                colors: points
                    .iter()
                    .map(|p| p.rgb.map(|c| c as f32 / 255.0))
                    .collect(),
            };
            return Ok((cloud, PointSource::Sparse(path)));
        }
    }
    let count = options.random_points;
    let background = if surrounds(cameras) {
        (count as f64 * points::BACKGROUND_FRACTION).round() as usize
    } else {
        0
    };
    let mut cloud = points::random_in_frusta(cameras, bounds, count - background, options.seed);
    let shell =
        points::random_on_background_shell(cameras, background, options.seed ^ 0x5348454c4c);
    cloud.positions.extend(shell.positions);
    cloud.colors.extend(shell.colors);
    Ok((
        cloud,
        PointSource::Random {
            count,
            seed: options.seed,
            background,
        },
    ))
}

fn open_colmap(root: &Path, sparse: &Path, options: &OpenOptions) -> Result<Capture> {
    let model = colmap::read_model(sparse)?;
    let (images_path, format) =
        colmap::find_file(sparse, "images").ok_or_else(|| SceneError::NotFound {
            path: sparse.join("images.bin"),
            what: "COLMAP images file (.bin or .txt)".into(),
        })?;
    if model.images.is_empty() {
        return Err(SceneError::invalid(
            &images_path,
            "model has no registered images",
        ));
    }
    let (image_dir, shrink) = image_source(root, options.resolution)?;
    let mut entries: Vec<_> = model.images.iter().collect();
    entries.sort_by(|a, b| a.name.as_bytes().cmp(b.name.as_bytes()));

    let mut cameras = Vec::with_capacity(entries.len());
    let mut image_paths = Vec::with_capacity(entries.len());
    let mut bounds = Vec::with_capacity(entries.len());
    for image in &entries {
        let model_camera = model
            .cameras
            .iter()
            .find(|c| c.id == image.camera_id)
            .ok_or_else(|| {
                SceneError::invalid(
                    &images_path,
                    format!(
                        "image {} refers to missing camera {}",
                        image.name, image.camera_id
                    ),
                )
            })?;
        let path = image_dir.join(&image.name);
        if !path.is_file() {
            return Err(SceneError::NotFound {
                path,
                what: format!("image listed in {}", images_path.display()),
            });
        }
        let (w, h) = shrunk_size(&path, images::image_size(&path)?, shrink)?;
        let full = image.camera(model_camera);
        limits::check_downsample((full.width as f64, full.height as f64), (w, h)).map_err(|p| {
            SceneError::invalid(
                &path,
                format!(
                    "{p} (camera {} of {})",
                    model_camera.id,
                    images_path.display()
                ),
            )
        })?;
        if !limits::same_aspect((full.width as f64, full.height as f64), (w, h)) {
            return Err(SceneError::invalid(
                &path,
                format!(
                    "image is {w}x{h} but its COLMAP camera {} is {}x{} (aspect differs)",
                    model_camera.id, full.width, full.height
                ),
            ));
        }
        let camera = full.resized(w, h);
        bounds.push(depth_bounds(&model, image.id, &camera).ok_or_else(|| {
            SceneError::invalid(
                sparse,
                format!(
                    "no 3D points in front of image {}; cannot derive its near/far bounds",
                    image.name
                ),
            )
        })?);
        cameras.push(camera);
        image_paths.push(path);
    }
    check_stems(&image_paths)?;
    let downsample = entries
        .first()
        .and_then(|im| model.cameras.iter().find(|c| c.id == im.camera_id))
        .map(|c| c.width as f64 / cameras[0].width as f64)
        .unwrap_or(1.0);
    let distortion_source = cameras
        .iter()
        .any(|c| c.distortion.is_some())
        .then(|| colmap::find_file(sparse, "cameras").map(|(p, _)| p))
        .flatten();
    let (points, point_source) =
        initial_points(Some(sparse), Some(&model), &cameras, &bounds, options)?;
    Ok(Capture {
        root: root.to_path_buf(),
        format: CaptureFormat::Colmap(format),
        image_dir,
        split: split::split(cameras.len(), options.llffhold),
        downsample,
        image_paths,
        cameras,
        bounds,
        points,
        point_source,
        distortion_source,
        remaps: Vec::new(),
        photo_cache: None,
        mask_paths: Vec::new(),
        shrink,
    })
}

/// LLFF's `imgs2poses` bounds: the 0.1 and 99.9 percentiles of the depths of the points the
/// image observes (its track entries), falling back to every point projecting into the image
/// when the model has no tracks.
fn depth_bounds(model: &ColmapModel, image_id: u32, camera: &Camera) -> Option<Bounds> {
    let observed = |p: &&colmap::ColmapPoint| p.track.iter().any(|t| t.image_id == image_id);
    let mut depths: Vec<f64> = model
        .points
        .iter()
        .filter(observed)
        .filter_map(|p| camera.project(p.xyz).map(|pr| pr.depth))
        .collect();
    if depths.is_empty() {
        depths = model
            .points
            .iter()
            .filter_map(|p| camera.project(p.xyz))
            .filter(|pr| camera.contains(pr))
            .map(|pr| pr.depth)
            .collect();
    }
    if depths.is_empty() {
        return None;
    }
    depths.sort_by(f64::total_cmp);
    let near = percentile(&depths, 0.1);
    let far = percentile(&depths, 99.9);
    // A single point would give near == far; keep the range non-empty.
    Some(Bounds {
        near,
        far: if far > near { far } else { near * 1.0001 },
    })
}

/// numpy's default (linear) percentile of sorted values.
fn percentile(sorted: &[f64], q: f64) -> f64 {
    let pos = q / 100.0 * (sorted.len() - 1) as f64;
    let lo = pos.floor() as usize;
    let hi = pos.ceil() as usize;
    sorted[lo] + (sorted[hi] - sorted[lo]) * (pos - lo as f64)
}

#[cfg(test)]
mod tests {
    use super::decode_groups;

    #[test]
    fn decode_groups_keep_order_and_stay_within_the_budget() {
        let sizes = [3u64, 3, 3, 10, 1, 1, 1, 1, 2];
        let indices: Vec<usize> = (0..sizes.len()).collect();
        let groups = decode_groups(&indices, |i| sizes[i], 6);
        let flat: Vec<usize> = groups.iter().flat_map(|g| g.iter().copied()).collect();
        assert_eq!(flat, indices, "every image once, in order");
        for g in &groups {
            let sum: u64 = g.iter().map(|&i| sizes[i]).sum();
            assert!(sum <= 6 || g.len() == 1, "{g:?} holds {sum}");
        }
        assert_eq!(groups, vec![&[0, 1][..], &[2], &[3], &[4, 5, 6, 7, 8]]);
        assert!(decode_groups(&[], |_| 1, 6).is_empty());
        // A budget of nothing still decodes, one image at a time.
        assert_eq!(decode_groups(&indices[..3], |i| sizes[i], 0).len(), 3);
    }
}
