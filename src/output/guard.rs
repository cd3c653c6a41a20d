//! Outputs never land on inputs: a command refuses, before it writes anything, an output path
//! that is one of the files it reads, lies inside an input folder (`render --out
//! CAPTURE/images` would otherwise replace the capture's own photos) or contains an input
//! (`train --init RUN/point_cloud.ply --out RUN --overwrite` would remove its own start).
//!
//! Paths are compared as the files they name, not as written: every input is resolved to its
//! canonical path, and an input folder contributes what its links lead to (a capture whose
//! `images/` links to a shared photo folder reads that folder), so no alias of an input slips
//! through.

use std::collections::HashSet;
use std::path::{Path, PathBuf};

use crate::error::{Result, TrainError};

/// How deep inside an input folder links are followed: a capture's links sit one or two
/// levels down (`images/`, `sparse/0/`).
const LINK_DEPTH: usize = 4;
/// Entries looked at per input folder, so that a huge folder named by mistake costs
/// milliseconds, not minutes; what lies beyond is still covered when it is physically inside.
const MAX_ENTRIES: usize = 200_000;

/// `path` made absolute with every existing part resolved (links, `..`), so that two names of
/// one file compare equal even when the output does not exist yet.
fn resolved(path: &Path) -> PathBuf {
    let abs = if path.is_absolute() {
        path.to_path_buf()
    } else {
        std::env::current_dir().unwrap_or_default().join(path)
    };
    let mut existing = abs.as_path();
    let mut rest = Vec::new();
    loop {
        if let Ok(real) = existing.canonicalize() {
            let mut out = real;
            out.extend(rest.iter().rev());
            return out;
        }
        match (existing.parent(), existing.file_name()) {
            (Some(parent), Some(name)) => {
                rest.push(name.to_owned());
                existing = parent;
            }
            _ => return abs,
        }
    }
}

/// One input as the user named it and as the file system resolves it.
struct Input {
    /// What it is and where, for the message: `--scene S`, `S/images (a link inside
    /// --scene S)`.
    label: String,
    real: PathBuf,
    is_dir: bool,
}

/// Everything a command reads, resolved.
#[derive(Default)]
pub struct Inputs {
    items: Vec<Input>,
    seen: HashSet<PathBuf>,
}

impl Inputs {
    pub fn new() -> Self {
        Self::default()
    }

    /// The inputs named by flags, as `(flag, path)`.
    pub fn of(inputs: &[(&str, &Path)]) -> Self {
        let mut all = Self::new();
        for (flag, path) in inputs {
            all.add(flag, path);
        }
        all
    }

    /// Adds `path` (given with `what`); a folder adds the targets of the links inside it.
    pub fn add(&mut self, what: &str, path: &Path) {
        let real = resolved(path);
        if !self.push(format!("{what} {}", path.display()), real.clone()) {
            return;
        }
        if real.is_dir() {
            let mut budget = MAX_ENTRIES;
            self.add_links(what, path, &real, LINK_DEPTH, &mut budget);
        }
    }

    /// Adds files read that a folder walk would not find (a capture's photos named by its
    /// model file), each described as `what`.
    pub fn add_files<'a>(&mut self, what: &str, paths: impl IntoIterator<Item = &'a PathBuf>) {
        for p in paths {
            self.add(what, p);
        }
    }

    /// Adds the files of `--scene` a folder walk would not find: the photos its model file
    /// names and the point file (a `ply_file_path` may lie anywhere in the capture).
    pub fn add_capture(&mut self, capture: &scenes::Capture) {
        self.add_files("a photo of --scene", &capture.image_paths);
        if let scenes::PointSource::Sparse(p) = &capture.point_source {
            self.add("the points of --scene", p);
        }
    }

    fn push(&mut self, label: String, real: PathBuf) -> bool {
        if !self.seen.insert(real.clone()) {
            return false;
        }
        let is_dir = real.is_dir();
        self.items.push(Input {
            label,
            real,
            is_dir,
        });
        true
    }

    fn add_links(&mut self, what: &str, top: &Path, dir: &Path, depth: usize, budget: &mut usize) {
        let Ok(entries) = std::fs::read_dir(dir) else {
            return;
        };
        for entry in entries.flatten() {
            if *budget == 0 {
                return;
            }
            *budget -= 1;
            let Ok(kind) = entry.file_type() else {
                continue;
            };
            let path = entry.path();
            if kind.is_symlink() {
                let Ok(real) = path.canonicalize() else {
                    continue;
                };
                let label = format!(
                    "{} (a link inside {what} {})",
                    path.display(),
                    top.display()
                );
                if self.push(label, real.clone()) && real.is_dir() && depth > 0 {
                    self.add_links(what, top, &real, depth - 1, budget);
                }
            } else if kind.is_dir() && depth > 0 {
                self.add_links(what, top, &path, depth - 1, budget);
            }
        }
    }

    /// Refuses output `out` (given with `flag`) when it is an input, lies inside an input
    /// folder or contains an input.
    pub fn refuse(&self, flag: &str, out: &Path) -> Result<()> {
        let o = resolved(out);
        for i in &self.items {
            let label = &i.label;
            let problem = if o == i.real {
                format!("is the same file as {label}: refusing to write over an input")
            } else if i.is_dir && o.starts_with(&i.real) {
                format!("lies inside {label}: refusing to write into an input")
            } else if i.real.starts_with(&o) {
                format!(
                    "contains {label}, at {}: refusing to write where an input lies",
                    i.real.display()
                )
            } else {
                continue;
            };
            return Err(TrainError::Invalid(format!(
                "{flag} {} {problem}",
                out.display()
            )));
        }
        Ok(())
    }
}

/// Refuses output `out` (given with `flag`) when it is any of `inputs` (`(flag, path)`), lies
/// inside one of them or contains one (see [`Inputs`]).
pub fn refuse_overwrite(flag: &str, out: &Path, inputs: &[(&str, &Path)]) -> Result<()> {
    Inputs::of(inputs).refuse(flag, out)
}

/// Refuses, before any work, an output file (given with `flag`) that cannot be written where
/// it is named: an existing folder, or a file whose folder does not exist (or is a file). A
/// command with several outputs checks them all first, so that one it cannot write does not
/// fail after the others were written.
pub fn refuse_unwritable_file(flag: &str, path: &Path) -> Result<()> {
    let problem = if path.is_dir() {
        "is a folder; name the file to write".to_string()
    } else {
        let parent = match path.parent() {
            Some(p) if !p.as_os_str().is_empty() => p,
            _ => Path::new("."),
        };
        if parent.is_dir() {
            return Ok(());
        }
        if parent.exists() {
            format!("cannot be written: {} is not a folder", parent.display())
        } else {
            format!(
                "cannot be written: its folder {} does not exist",
                parent.display()
            )
        }
    };
    Err(TrainError::Invalid(format!(
        "{flag} {} {problem}",
        path.display()
    )))
}

/// Refuses an output folder (given with `flag`) that exists as a file: the command would
/// fail at its first write, after the work.
pub fn refuse_file_as_folder(flag: &str, path: &Path) -> Result<()> {
    if path.exists() && !path.is_dir() {
        return Err(TrainError::Invalid(format!(
            "{flag} {} is a file; this command writes a folder there, so name a folder",
            path.display()
        )));
    }
    Ok(())
}

/// Refuses, before any work, an image output (given with `flag`) whose name says another
/// format than the PNG bytes every image command writes (`--out a.jpg` would hold a PNG).
fn refuse_non_png(flag: &str, path: &Path) -> Result<()> {
    refuse_other_extension(flag, path, "png", "images are written as PNG")
}

/// An image output checked as every image command checks it: named `.png`
/// ([`refuse_non_png`]) and writable where it is named ([`refuse_unwritable_file`]).
pub fn refuse_unwritable_image(flag: &str, path: &Path) -> Result<()> {
    refuse_non_png(flag, path)?;
    refuse_unwritable_file(flag, path)
}

/// Refuses an output file (given with `flag`) not named with `.ext`, the format written
/// (`what` says which).
pub fn refuse_other_extension(flag: &str, path: &Path, ext: &str, what: &str) -> Result<()> {
    let named = path
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case(ext));
    if named {
        return Ok(());
    }
    Err(TrainError::Invalid(format!(
        "{flag} {}: {what}; name the file with .{ext}",
        path.display()
    )))
}

/// Refuses to make an aberrated capture from one that already is (it holds
/// `aberration.json`): its blurred photos would become the new clean images and be blurred a
/// second time.
pub fn refuse_aberrated_source(flag: &str, scene: &Path) -> Result<()> {
    let record = scene.join(scenes::aberrated::RECORD_FILE);
    if record.is_file() {
        return Err(TrainError::Invalid(format!(
            "{flag} {} is already an aberrated capture ({} exists): its photos are blurred, and \
             aberrating them again would make them the clean images; start from the clean capture",
            scene.display(),
            record.display()
        )));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn aliases_of_an_input_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        std::fs::create_dir(d.join("scene")).unwrap();
        std::fs::write(d.join("a.png"), b"x").unwrap();
        let a = d.join("a.png");
        let scene = d.join("scene");
        let inputs = [("--in", a.as_path()), ("--scene", scene.as_path())];
        for bad in [
            d.join("a.png"),
            d.join("scene/../a.png"),
            d.join("scene"),
            d.join("scene/images"),
            d.join("scene/new/deeper"),
            d.to_path_buf(),
        ] {
            let err = refuse_overwrite("--out", &bad, &inputs)
                .unwrap_err()
                .to_string();
            assert!(err.contains("--out"), "{err}");
        }
        for good in [d.join("b.png"), d.join("out/scene"), d.join("scene2")] {
            refuse_overwrite("--out", &good, &inputs).unwrap();
        }
    }

    #[test]
    fn an_output_file_needs_an_existing_folder_and_must_not_be_one() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        std::fs::write(d.join("file"), b"x").unwrap();
        refuse_unwritable_file("--out", &d.join("new.png")).unwrap();
        refuse_unwritable_file("--out", &d.join("file")).unwrap();
        for (bad, says) in [
            (d.to_path_buf(), "is a folder"),
            (d.join("missing/new.png"), "does not exist"),
            (d.join("file/new.png"), "is not a folder"),
        ] {
            let err = refuse_unwritable_file("--out", &bad)
                .unwrap_err()
                .to_string();
            assert!(err.contains("--out") && err.contains(says), "{err}");
        }
    }

    #[cfg(unix)]
    #[test]
    fn what_links_inside_an_input_folder_lead_to_is_an_input() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let shared = d.join("shared/photos");
        std::fs::create_dir_all(&shared).unwrap();
        std::fs::write(shared.join("a.png"), b"x").unwrap();
        std::fs::create_dir_all(d.join("scene/sparse")).unwrap();
        std::os::unix::fs::symlink(&shared, d.join("scene/images")).unwrap();
        std::os::unix::fs::symlink(d.join("scene"), d.join("linked")).unwrap();
        let scene = d.join("linked");
        for bad in [
            shared.clone(),
            shared.join("a.png"),
            shared.join("new"),
            d.join("shared"),
            d.join("scene/sparse/x"),
        ] {
            let err = refuse_overwrite("--out", &bad, &[("--scene", &scene)])
                .unwrap_err()
                .to_string();
            assert!(err.contains("--out") && err.contains("input"), "{err}");
        }
        refuse_overwrite("--out", &d.join("shared2"), &[("--scene", &scene)]).unwrap();
    }
}
