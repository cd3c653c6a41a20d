//! COLMAP's text model files (`cameras.txt`, `images.txt`, `points3D.txt`).
//!
//! Lines starting with `#` are comments. `images.txt` holds two lines per image, the second
//! (its 2D points) possibly empty, so blank lines only separate records where a header is due.

use std::fmt::Write as _;
use std::path::Path;
use std::str::FromStr;

use glam::DVec3;

use super::first_repeat;
use super::model::{ColmapCamera, ColmapImage, ColmapPoint, Point2D, TrackElement};
use crate::atomic;
use crate::camera::CameraModel;
use crate::error::{Result, SceneError};

fn read_lines(path: &Path) -> Result<Vec<(usize, String)>> {
    if path.is_file() {
        SceneError::check_file_size(path, base::limits::MAX_MODEL_FILE_BYTES)?;
    }
    let text = base::input::read_to_string(path).map_err(|e| match e.kind() {
        std::io::ErrorKind::NotFound => SceneError::NotFound {
            path: path.to_path_buf(),
            what: "COLMAP model file".into(),
        },
        _ => SceneError::io(path, e),
    })?;
    Ok(text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim_start().starts_with('#'))
        .map(|(i, l)| (i + 1, l.trim().to_string()))
        .collect())
}

/// Whitespace-separated fields of one line, parsed with the line number in every error.
struct Fields<'a> {
    path: &'a Path,
    line: usize,
    text: &'a str,
    tokens: Vec<&'a str>,
    next: usize,
}

impl<'a> Fields<'a> {
    fn new(path: &'a Path, line: usize, text: &'a str) -> Self {
        Fields {
            path,
            line,
            text,
            tokens: text.split_whitespace().collect(),
            next: 0,
        }
    }

    fn error(&self, problem: String) -> SceneError {
        SceneError::Parse {
            path: self.path.to_path_buf(),
            line: self.line,
            problem,
        }
    }

    fn token(&mut self, what: &str) -> Result<&'a str> {
        let t = self
            .tokens
            .get(self.next)
            .copied()
            .ok_or_else(|| self.error(format!("missing {what}")))?;
        self.next += 1;
        Ok(t)
    }

    fn parse<T: FromStr>(&mut self, what: &str) -> Result<T> {
        let t = self.token(what)?;
        t.parse()
            .map_err(|_| self.error(format!("cannot parse {what} from {t:?}")))
    }

    /// The rest of the line after the fields read so far, as written (inner spaces kept).
    fn rest(&self) -> &'a str {
        let mut s = self.text.trim_start();
        for _ in 0..self.next {
            let end = s.find(char::is_whitespace).unwrap_or(s.len());
            s = s[end..].trim_start();
        }
        s
    }

    fn left(&self) -> usize {
        self.tokens.len() - self.next
    }

    fn end(&self) -> Result<()> {
        if self.left() != 0 {
            return Err(self.error(format!("{} unexpected extra fields", self.left())));
        }
        Ok(())
    }
}

pub fn read_cameras(path: &Path) -> Result<Vec<ColmapCamera>> {
    let mut cameras = Vec::new();
    let mut lines = Vec::new();
    for (line, text) in read_lines(path)? {
        if text.is_empty() {
            continue;
        }
        let mut f = Fields::new(path, line, &text);
        let id = f.parse("camera id")?;
        let name = f.token("camera model")?;
        let model = CameraModel::from_name(name).ok_or_else(|| SceneError::UnknownCameraModel {
            path: path.to_path_buf(),
            model: format!("{name} (line {line})"),
        })?;
        let width = f.parse("width")?;
        let height = f.parse("height")?;
        let params = (0..model.param_count())
            .map(|i| f.parse(&format!("parameter {i} of {name}")))
            .collect::<Result<Vec<f64>>>()?;
        f.end()?;
        lines.push(line);
        cameras.push(ColmapCamera {
            id,
            model,
            width,
            height,
            params,
        });
    }
    if let Some((id, a, b)) = first_repeat(cameras.iter().map(|c| c.id).zip(lines)) {
        return Err(SceneError::Parse {
            path: path.to_path_buf(),
            line: b,
            problem: format!("camera id {id} is used again (first on line {a})"),
        });
    }
    Ok(cameras)
}

pub fn read_images(path: &Path) -> Result<Vec<ColmapImage>> {
    let lines = read_lines(path)?;
    let mut images = Vec::new();
    let mut at = Vec::new();
    let mut i = 0;
    while i < lines.len() {
        let (line, text) = &lines[i];
        i += 1;
        if text.is_empty() {
            continue;
        }
        let mut f = Fields::new(path, *line, text);
        let id = f.parse("image id")?;
        let mut qvec = [0.0; 4];
        for (q, name) in qvec.iter_mut().zip(["QW", "QX", "QY", "QZ"]) {
            *q = f.parse(name)?;
        }
        let tvec = DVec3::new(f.parse("TX")?, f.parse("TY")?, f.parse("TZ")?);
        let camera_id = f.parse("camera id")?;
        // COLMAP names may not contain spaces, but keep the rest of the line as written (a
        // name with two spaces names its own file) rather than fail.
        let name = f.rest().to_string();
        if name.is_empty() {
            return Err(f.error("missing image name".into()));
        }
        let mut points2d = Vec::new();
        if let Some((pline, ptext)) = lines.get(i) {
            i += 1;
            let mut p = Fields::new(path, *pline, ptext);
            if !p.left().is_multiple_of(3) {
                return Err(p.error(format!(
                    "{} values in the 2D point line, expected triples X Y POINT3D_ID",
                    p.left()
                )));
            }
            while p.left() > 0 {
                let xy = [p.parse("point X")?, p.parse("point Y")?];
                let point3d_id = p.parse("POINT3D_ID")?;
                points2d.push(Point2D { xy, point3d_id });
            }
        }
        at.push(*line);
        images.push(ColmapImage {
            id,
            qvec,
            tvec,
            camera_id,
            name,
            points2d,
        });
    }
    let repeat = |problem: String, b: usize| SceneError::Parse {
        path: path.to_path_buf(),
        line: b,
        problem,
    };
    if let Some((id, a, b)) = first_repeat(images.iter().map(|im| im.id).zip(at.iter().copied())) {
        return Err(repeat(
            format!("image id {id} is used again (first on line {a})"),
            b,
        ));
    }
    if let Some((name, a, b)) = first_repeat(
        images
            .iter()
            .map(|im| im.name.as_str())
            .zip(at.iter().copied()),
    ) {
        return Err(repeat(
            format!("image name {name:?} is used again (first on line {a})"),
            b,
        ));
    }
    Ok(images)
}

pub fn read_points3d(path: &Path) -> Result<Vec<ColmapPoint>> {
    let mut points = Vec::new();
    for (line, text) in read_lines(path)? {
        if text.is_empty() {
            continue;
        }
        let mut f = Fields::new(path, line, &text);
        let id = f.parse("point id")?;
        let xyz = DVec3::new(f.parse("X")?, f.parse("Y")?, f.parse("Z")?);
        let rgb = [f.parse("R")?, f.parse("G")?, f.parse("B")?];
        let error = f.parse("error")?;
        if !f.left().is_multiple_of(2) {
            return Err(f.error("track has an odd number of values".into()));
        }
        let mut track = Vec::with_capacity(f.left() / 2);
        while f.left() > 0 {
            track.push(TrackElement {
                image_id: f.parse("track image id")?,
                point2d_idx: f.parse("track point index")?,
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
    Ok(points)
}

fn write_text(path: &Path, text: &str) -> Result<()> {
    atomic::write_file(path, |w| {
        std::io::Write::write_all(w, text.as_bytes()).map_err(|e| SceneError::io(path, e))
    })
}

// `{}` on f64 prints the shortest string that parses back to the same value, so text and
// binary models hold identical numbers.
pub fn write_cameras(path: &Path, cameras: &[ColmapCamera]) -> Result<()> {
    let mut s = String::from("# CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n");
    for c in cameras {
        let _ = write!(s, "{} {} {} {}", c.id, c.model.name(), c.width, c.height);
        for p in &c.params {
            let _ = write!(s, " {p}");
        }
        s.push('\n');
    }
    write_text(path, &s)
}

pub fn write_images(path: &Path, images: &[ColmapImage]) -> Result<()> {
    let mut s = String::from(
        "# IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n# POINTS2D[] as (X, Y, POINT3D_ID)\n",
    );
    for im in images {
        let [qw, qx, qy, qz] = im.qvec;
        let t = im.tvec;
        let _ = writeln!(
            s,
            "{} {qw} {qx} {qy} {qz} {} {} {} {} {}",
            im.id, t.x, t.y, t.z, im.camera_id, im.name
        );
        let points: Vec<String> = im
            .points2d
            .iter()
            .map(|p| format!("{} {} {}", p.xy[0], p.xy[1], p.point3d_id))
            .collect();
        s.push_str(&points.join(" "));
        s.push('\n');
    }
    write_text(path, &s)
}

pub fn write_points3d(path: &Path, points: &[ColmapPoint]) -> Result<()> {
    let mut s =
        String::from("# POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)\n");
    for p in points {
        let _ = write!(
            s,
            "{} {} {} {} {} {} {} {}",
            p.id, p.xyz.x, p.xyz.y, p.xyz.z, p.rgb[0], p.rgb[1], p.rgb[2], p.error
        );
        for t in &p.track {
            let _ = write!(s, " {} {}", t.image_id, t.point2d_idx);
        }
        s.push('\n');
    }
    write_text(path, &s)
}
