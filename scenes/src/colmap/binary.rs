//! COLMAP's binary model files (`cameras.bin`, `images.bin`, `points3D.bin`), little-endian.

use std::path::Path;

use glam::DVec3;

use super::first_repeat;
use super::model::{ColmapCamera, ColmapImage, ColmapPoint, Point2D, TrackElement};
use crate::atomic;
use crate::camera::CameraModel;
use crate::error::{Result, SceneError};

/// Reads fixed-size fields and reports the record being read when the file ends early.
struct Reader<'a> {
    data: &'a [u8],
    pos: usize,
    path: &'a Path,
}

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize, what: &dyn Fn() -> String) -> Result<&'a [u8]> {
        if self.data.len() - self.pos < n {
            return Err(SceneError::Truncated {
                path: self.path.to_path_buf(),
                what: what(),
            });
        }
        let bytes = &self.data[self.pos..self.pos + n];
        self.pos += n;
        Ok(bytes)
    }

    fn array<const N: usize>(&mut self, what: &dyn Fn() -> String) -> Result<[u8; N]> {
        let mut out = [0; N];
        out.copy_from_slice(self.take(N, what)?);
        Ok(out)
    }

    fn u64(&mut self, what: &dyn Fn() -> String) -> Result<u64> {
        self.array(what).map(u64::from_le_bytes)
    }

    fn i64(&mut self, what: &dyn Fn() -> String) -> Result<i64> {
        self.array(what).map(i64::from_le_bytes)
    }

    fn u32(&mut self, what: &dyn Fn() -> String) -> Result<u32> {
        self.array(what).map(u32::from_le_bytes)
    }

    fn i32(&mut self, what: &dyn Fn() -> String) -> Result<i32> {
        self.array(what).map(i32::from_le_bytes)
    }

    fn f64(&mut self, what: &dyn Fn() -> String) -> Result<f64> {
        self.array(what).map(f64::from_le_bytes)
    }

    fn remaining(&self) -> usize {
        self.data.len() - self.pos
    }

    /// A record count, checked against the bytes left so that a corrupt count fails cleanly
    /// instead of allocating without bound.
    fn count(&mut self, what: &str, min_record: usize) -> Result<usize> {
        let n = self.u64(&|| format!("the number of {what}"))?;
        let fits = self.remaining() / min_record.max(1);
        if n > fits as u64 {
            return Err(SceneError::Truncated {
                path: self.path.to_path_buf(),
                what: format!(
                    "{n} {what} declared, the {} bytes left hold at most {fits}",
                    self.remaining()
                ),
            });
        }
        Ok(n as usize)
    }

    fn end(&self, what: &str) -> Result<()> {
        if self.remaining() != 0 {
            return Err(SceneError::invalid(
                self.path,
                format!(
                    "{} bytes left after the declared {what}; the count in the header is wrong",
                    self.remaining()
                ),
            ));
        }
        Ok(())
    }
}

fn read_all(path: &Path) -> Result<Vec<u8>> {
    if path.is_file() {
        SceneError::check_file_size(path, base::limits::MAX_MODEL_FILE_BYTES)?;
    }
    base::input::read(path).map_err(|e| match e.kind() {
        std::io::ErrorKind::NotFound => SceneError::NotFound {
            path: path.to_path_buf(),
            what: "COLMAP model file".into(),
        },
        _ => SceneError::io(path, e),
    })
}

pub fn read_cameras(path: &Path) -> Result<Vec<ColmapCamera>> {
    let data = read_all(path)?;
    let mut r = Reader {
        data: &data,
        pos: 0,
        path,
    };
    let n = r.count("cameras", 24)?;
    let mut cameras = Vec::with_capacity(n);
    for i in 0..n {
        let what = || format!("camera {i}");
        let id = r.u32(&what)?;
        let model_id = r.i32(&what)?;
        let model =
            CameraModel::from_id(model_id).ok_or_else(|| SceneError::UnknownCameraModel {
                path: path.to_path_buf(),
                model: format!("id {model_id} (camera {id})"),
            })?;
        let width = r.u64(&what)?;
        let height = r.u64(&what)?;
        let params = (0..model.param_count())
            .map(|_| r.f64(&what))
            .collect::<Result<Vec<_>>>()?;
        cameras.push(ColmapCamera {
            id,
            model,
            width,
            height,
            params,
        });
    }
    r.end("cameras")?;
    if let Some((id, a, b)) = first_repeat(cameras.iter().map(|c| c.id).zip(0..)) {
        return Err(SceneError::invalid(
            path,
            format!("camera id {id} is used by records {a} and {b}"),
        ));
    }
    Ok(cameras)
}

pub fn read_images(path: &Path) -> Result<Vec<ColmapImage>> {
    let data = read_all(path)?;
    let mut r = Reader {
        data: &data,
        pos: 0,
        path,
    };
    let n = r.count("images", 73)?;
    let mut images = Vec::with_capacity(n);
    for i in 0..n {
        let what = || format!("image record {i} (counting from 0)");
        let id = r.u32(&what)?;
        let mut qvec = [0.0; 4];
        for q in &mut qvec {
            *q = r.f64(&what)?;
        }
        let tvec = DVec3::new(r.f64(&what)?, r.f64(&what)?, r.f64(&what)?);
        let camera_id = r.u32(&what)?;
        let rest = &r.data[r.pos..];
        let len = rest
            .iter()
            .position(|&b| b == 0)
            .ok_or_else(|| SceneError::Truncated {
                path: path.to_path_buf(),
                what: format!("the name of image record {i} (no terminating NUL)"),
            })?;
        let name = String::from_utf8(rest[..len].to_vec()).map_err(|_| {
            SceneError::invalid(path, format!("the name of image record {i} is not UTF-8"))
        })?;
        r.pos += len + 1;
        let points = r.count(&format!("2D points of image record {i}"), 24)?;
        let mut points2d = Vec::with_capacity(points);
        for _ in 0..points {
            let xy = [r.f64(&what)?, r.f64(&what)?];
            let point3d_id = r.i64(&what)?;
            points2d.push(Point2D { xy, point3d_id });
        }
        images.push(ColmapImage {
            id,
            qvec,
            tvec,
            camera_id,
            name,
            points2d,
        });
    }
    r.end("images")?;
    if let Some((id, a, b)) = first_repeat(images.iter().map(|im| im.id).zip(0..)) {
        return Err(SceneError::invalid(
            path,
            format!("image id {id} is used by records {a} and {b}"),
        ));
    }
    if let Some((name, a, b)) = first_repeat(images.iter().map(|im| im.name.as_str()).zip(0..)) {
        return Err(SceneError::invalid(
            path,
            format!("image name {name:?} is used by records {a} and {b}"),
        ));
    }
    Ok(images)
}

pub fn read_points3d(path: &Path) -> Result<Vec<ColmapPoint>> {
    let data = read_all(path)?;
    let mut r = Reader {
        data: &data,
        pos: 0,
        path,
    };
    let n = r.count("points", 51)?;
    let mut points = Vec::with_capacity(n);
    for i in 0..n {
        let what = || format!("point record {i} (counting from 0)");
        let id = r.u64(&what)?;
        let xyz = DVec3::new(r.f64(&what)?, r.f64(&what)?, r.f64(&what)?);
        let rgb = r.array::<3>(&what)?;
        let error = r.f64(&what)?;
        let len = r.count(&format!("track elements of point record {i}"), 8)?;
        let mut track = Vec::with_capacity(len);
        for _ in 0..len {
            track.push(TrackElement {
                image_id: r.u32(&what)?,
                point2d_idx: r.u32(&what)?,
            });
        }
        points.push(ColmapPoint {
            id,
            xyz,
            rgb,
            error,
            track,
        });
    }
    r.end("points")?;
    Ok(points)
}

fn put_f64s(out: &mut Vec<u8>, values: &[f64]) {
    for v in values {
        out.extend_from_slice(&v.to_le_bytes());
    }
}

fn write_bytes(path: &Path, bytes: &[u8]) -> Result<()> {
    atomic::write_file(path, |w| {
        std::io::Write::write_all(w, bytes).map_err(|e| SceneError::io(path, e))
    })
}

pub fn write_cameras(path: &Path, cameras: &[ColmapCamera]) -> Result<()> {
    let mut out = (cameras.len() as u64).to_le_bytes().to_vec();
    for c in cameras {
        out.extend_from_slice(&c.id.to_le_bytes());
        out.extend_from_slice(&c.model.id().to_le_bytes());
        out.extend_from_slice(&c.width.to_le_bytes());
        out.extend_from_slice(&c.height.to_le_bytes());
        put_f64s(&mut out, &c.params);
    }
    write_bytes(path, &out)
}

pub fn write_images(path: &Path, images: &[ColmapImage]) -> Result<()> {
    let mut out = (images.len() as u64).to_le_bytes().to_vec();
    for im in images {
        out.extend_from_slice(&im.id.to_le_bytes());
        put_f64s(&mut out, &im.qvec);
        put_f64s(&mut out, &im.tvec.to_array());
        out.extend_from_slice(&im.camera_id.to_le_bytes());
        out.extend_from_slice(im.name.as_bytes());
        out.push(0);
        out.extend_from_slice(&(im.points2d.len() as u64).to_le_bytes());
        for p in &im.points2d {
            put_f64s(&mut out, &p.xy);
            out.extend_from_slice(&p.point3d_id.to_le_bytes());
        }
    }
    write_bytes(path, &out)
}

pub fn write_points3d(path: &Path, points: &[ColmapPoint]) -> Result<()> {
    let mut out = (points.len() as u64).to_le_bytes().to_vec();
    for p in points {
        out.extend_from_slice(&p.id.to_le_bytes());
        put_f64s(&mut out, &p.xyz.to_array());
        out.extend_from_slice(&p.rgb);
        put_f64s(&mut out, &[p.error]);
        out.extend_from_slice(&(p.track.len() as u64).to_le_bytes());
        for t in &p.track {
            out.extend_from_slice(&t.image_id.to_le_bytes());
            out.extend_from_slice(&t.point2d_idx.to_le_bytes());
        }
    }
    write_bytes(path, &out)
}
