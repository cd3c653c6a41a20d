//! COLMAP sparse models, binary and text.

pub mod binary;
mod model;
pub mod text;

use std::path::{Path, PathBuf};

pub use model::{
    ColmapCamera, ColmapImage, ColmapModel, ColmapPoint, Intrinsics, Point2D, TrackElement,
};

use crate::error::{Result, SceneError};

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
        .find(|(p, _)| p.is_file())
}

/// The folder holding a scene's sparse model: `sparse/0`, else `sparse`, if it has cameras.
pub fn sparse_dir(scene: &Path) -> Option<PathBuf> {
    [scene.join("sparse").join("0"), scene.join("sparse")]
        .into_iter()
        .find(|d| find_file(d, "cameras").is_some() || find_file(d, "points3D").is_some())
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

pub fn read_cameras(path: &Path) -> Result<Vec<ColmapCamera>> {
    match format_of(path)? {
        ModelFormat::Binary => binary::read_cameras(path),
        ModelFormat::Text => text::read_cameras(path),
    }
}

pub fn read_images(path: &Path) -> Result<Vec<ColmapImage>> {
    match format_of(path)? {
        ModelFormat::Binary => binary::read_images(path),
        ModelFormat::Text => text::read_images(path),
    }
}

pub fn read_points3d(path: &Path) -> Result<Vec<ColmapPoint>> {
    match format_of(path)? {
        ModelFormat::Binary => binary::read_points3d(path),
        ModelFormat::Text => text::read_points3d(path),
    }
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
