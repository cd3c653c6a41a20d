//! COLMAP sparse models, binary and text.

pub mod binary;
mod model;
pub mod text;

use std::collections::HashMap;
use std::hash::Hash;
use std::path::{Component, Path, PathBuf};

pub use model::{
    ColmapCamera, ColmapImage, ColmapModel, ColmapPoint, Intrinsics, Point2D, TrackElement,
};

use crate::error::{Result, SceneError};
use crate::limits;

/// Which on-disk flavour a model uses.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ModelFormat {
    Binary,
    Text,
}

impl ModelFormat {
    pub fn extension(self) -> &'static str {
        match self {
            ModelFormat::Binary => "bin",
            ModelFormat::Text => "txt",
        }
    }
}

/// `dir/<stem>.bin` if present, else `dir/<stem>.txt` if present.
pub fn find_file(dir: &Path, stem: &str) -> Option<(PathBuf, ModelFormat)> {
    [ModelFormat::Binary, ModelFormat::Text]
        .into_iter()
        .map(|f| (dir.join(format!("{stem}.{}", f.extension())), f))
        // Anything of the name counts, a folder too: its reader then says what is wrong,
        // where skipping it would quietly read another file or none.
        .find(|(p, _)| p.exists())
}

/// The folder holding a scene's sparse model: `sparse/0`, else `sparse`, if it has cameras.
pub fn sparse_dir(scene: &Path) -> Option<PathBuf> {
    [scene.join("sparse").join("0"), scene.join("sparse")]
        .into_iter()
        .find(|d| find_file(d, "cameras").is_some() || find_file(d, "points3D").is_some())
}

/// The first key that appears twice, with where it appeared first and where again.
pub(crate) fn first_repeat<K: Eq + Hash, P: Copy>(
    items: impl IntoIterator<Item = (K, P)>,
) -> Option<(K, P, P)> {
    let mut seen = HashMap::new();
    for (key, at) in items {
        if let Some(&first) = seen.get(&key) {
            return Some((key, first, at));
        }
        seen.insert(key, at);
    }
    None
}

/// Why an image name cannot name a file inside the capture's image folder: absolute, or
/// climbing out with `..`. COLMAP names are relative to the image folder.
fn name_leaves_folder(name: &str) -> Option<&'static str> {
    for c in Path::new(name).components() {
        match c {
            Component::Normal(_) | Component::CurDir => {}
            Component::ParentDir => return Some("climbs out of the image folder with .."),
            Component::RootDir | Component::Prefix(_) => {
                return Some("is an absolute path");
            }
        }
    }
    None
}

fn format_of(path: &Path) -> Result<ModelFormat> {
    match path.extension().and_then(|e| e.to_str()) {
        Some("bin") => Ok(ModelFormat::Binary),
        Some("txt") => Ok(ModelFormat::Text),
        _ => Err(SceneError::invalid(
            path,
            "COLMAP model files must end in .bin or .txt",
        )),
    }
}

/// Reads a cameras file and checks every camera against [`crate::limits`].
pub fn read_cameras(path: &Path) -> Result<Vec<ColmapCamera>> {
    let cameras = match format_of(path)? {
        ModelFormat::Binary => binary::read_cameras(path),
        ModelFormat::Text => text::read_cameras(path),
    }?;
    for c in &cameras {
        check_camera(c).map_err(|p| SceneError::invalid(path, format!("camera {}: {p}", c.id)))?;
    }
    Ok(cameras)
}

fn check_camera(c: &ColmapCamera) -> std::result::Result<(), String> {
    let (w, h) = (c.width as f64, c.height as f64);
    limits::check_size(w, h)?;
    let k = c.intrinsics();
    limits::check_intrinsics(w, h, k.fx, k.fy, k.cx, k.cy)?;
    match &k.distortion {
        Some(d) => {
            limits::check_distortion(d)?;
            limits::check_distortion_folds(d, w, h, k.fx, k.fy, k.cx, k.cy)
        }
        None => Ok(()),
    }
}

/// Reads an images file and checks every pose against [`crate::limits`].
pub fn read_images(path: &Path) -> Result<Vec<ColmapImage>> {
    let images = match format_of(path)? {
        ModelFormat::Binary => binary::read_images(path),
        ModelFormat::Text => text::read_images(path),
    }?;
    for im in &images {
        if let Some(why) = name_leaves_folder(&im.name) {
            return Err(SceneError::invalid(
                path,
                format!(
                    "image {} (id {}): the name {why}; names are relative to the capture's image folder, and only files inside the capture are read",
                    im.name, im.id
                ),
            ));
        }
        let norm = im.qvec.iter().map(|q| q * q).sum::<f64>().sqrt();
        if !(norm.is_finite() && norm >= limits::MIN_QUATERNION_NORM) {
            return Err(SceneError::invalid(
                path,
                format!(
                    "image {}: rotation quaternion {:?} is not finite or has a norm below {}",
                    im.name,
                    im.qvec,
                    limits::MIN_QUATERNION_NORM
                ),
            ));
        }
        if !im.tvec.is_finite() {
            return Err(SceneError::invalid(
                path,
                format!("image {}: translation {} is not finite", im.name, im.tvec),
            ));
        }
        // The camera centre is the rotated translation: as far from the origin.
        limits::check_point(im.tvec.to_array())
            .map_err(|p| SceneError::invalid(path, format!("image {}: camera {p}", im.name)))?;
    }
    Ok(images)
}

/// Reads a points file and checks every position against [`crate::limits`].
pub fn read_points3d(path: &Path) -> Result<Vec<ColmapPoint>> {
    let points = match format_of(path)? {
        ModelFormat::Binary => binary::read_points3d(path),
        ModelFormat::Text => text::read_points3d(path),
    }?;
    for p in &points {
        limits::check_point(p.xyz.to_array())
            .map_err(|e| SceneError::invalid(path, format!("point ID {}: {e}", p.id)))?;
    }
    Ok(points)
}

/// Reads the three files of a model folder, each as binary if present, else text. A missing
/// `points3D` gives an empty point list; missing cameras or images are errors.
pub fn read_model(dir: &Path) -> Result<ColmapModel> {
    let required = |stem: &str| {
        find_file(dir, stem).ok_or_else(|| SceneError::NotFound {
            path: dir.join(format!("{stem}.bin")),
            what: format!("COLMAP {stem} file (.bin or .txt)"),
        })
    };
    let (cameras_path, _) = required("cameras")?;
    let (images_path, _) = required("images")?;
    let cameras = read_cameras(&cameras_path)?;
    let images = read_images(&images_path)?;
    for im in &images {
        if !cameras.iter().any(|c| c.id == im.camera_id) {
            return Err(SceneError::invalid(
                &images_path,
                format!(
                    "image {} refers to camera {}, absent from {}",
                    im.name,
                    im.camera_id,
                    cameras_path.display()
                ),
            ));
        }
    }
    let points = match find_file(dir, "points3D") {
        Some((p, _)) => read_points3d(&p)?,
        None => Vec::new(),
    };
    Ok(ColmapModel {
        cameras,
        images,
        points,
    })
}

/// Writes `cameras`, `images` and `points3D` in the given format into an existing folder.
pub fn write_model(dir: &Path, model: &ColmapModel, format: ModelFormat) -> Result<()> {
    let path = |stem: &str| dir.join(format!("{stem}.{}", format.extension()));
    match format {
        ModelFormat::Binary => {
            binary::write_cameras(&path("cameras"), &model.cameras)?;
            binary::write_images(&path("images"), &model.images)?;
            binary::write_points3d(&path("points3D"), &model.points)
        }
        ModelFormat::Text => {
            text::write_cameras(&path("cameras"), &model.cameras)?;
            text::write_images(&path("images"), &model.images)?;
            text::write_points3d(&path("points3D"), &model.points)
        }
    }
}
