//! Outputs never land on inputs: a command refuses, before it writes anything, an output path
//! that is one of its inputs or lies inside an input folder (`render --out CAPTURE/images`
//! would otherwise replace the capture's own photos).

use std::path::{Path, PathBuf};

use crate::error::{Result, TrainError};

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

/// Refuses output `out` (given with `flag`) when it is any of `inputs` (`(flag, path)`) or
/// lies inside one of them.
pub fn refuse_overwrite(flag: &str, out: &Path, inputs: &[(&str, &Path)]) -> Result<()> {
    let o = resolved(out);
    for (in_flag, input) in inputs {
        let i = resolved(input);
        if o == i {
            return Err(TrainError::Invalid(format!(
                "{flag} {} is the same file as {in_flag}: refusing to write over an input",
                out.display()
            )));
        }
        if o.starts_with(&i) && i.is_dir() {
            return Err(TrainError::Invalid(format!(
                "{flag} {} lies inside {in_flag} {}: refusing to write into an input",
                out.display(),
                input.display()
            )));
        }
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
}
