//! The parameter-wise mean of networks fine-tuned from one starting point (a "model soup",
//! Wortsman et al., ICML 2022): runs that differ in seed or schedule land near each other,
//! and their mean can restore better than each, at one network's cost (where a
//! self-ensemble, [`crate::ensemble`], costs one pass per member). Two seeds of the shipped
//! wide-blur network's run averaged scored as each (RESULTS.md).
//!
//! Only networks of one configuration (the same layout and the same input switches: bank K,
//! residual base) trained on the same PSF-scale range average; the mean keeps the first
//! file's grid, family and range, and records every member in its provenance.

use crate::error::{RestoreError, Result};
use crate::net::RestorerNet;
use crate::weights::{self, Header};
use burn::module::{Module, ModuleMapper, ModuleVisitor, Param};
use burn::tensor::{Device, Tensor, TensorData};
use std::path::{Path, PathBuf};

/// Every float parameter's values, in the network's visiting order.
fn parameters(net: &RestorerNet) -> Vec<Vec<f32>> {
    struct Collect(Vec<Vec<f32>>);
    impl ModuleVisitor for Collect {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            let values = param
                .val()
                .try_into_vec_as::<f32>()
                .expect("CPU parameters");
            self.0.push(values);
        }
    }
    let mut c = Collect(Vec::new());
    net.visit(&mut c);
    c.0
}

/// The mean (summed in f64) of the networks in `paths`, with its header: the first file's,
/// its provenance replaced by the members' (file, fingerprint, provenance). Refused, naming
/// the file: fewer than two members, a member of another configuration or scale range, one
/// with or without a lens family where the first differs.
pub fn average(paths: &[PathBuf], device: &Device) -> Result<(RestorerNet, Header)> {
    if paths.len() < 2 {
        return Err(RestoreError::BadInput(format!(
            "averaging takes two or more weights files, got {}",
            paths.len()
        )));
    }
    let (first, header, first_member) = load(&paths[0], device)?;
    let mut sums: Vec<Vec<f64>> = parameters(&first)
        .into_iter()
        .map(|p| p.into_iter().map(f64::from).collect())
        .collect();
    let mut members = vec![first_member];
    for path in &paths[1..] {
        let (net, h, m) = load(path, device)?;
        refuse_unlike(path, &h, &paths[0], &header)?;
        for (sum, values) in sums.iter_mut().zip(parameters(&net)) {
            for (s, v) in sum.iter_mut().zip(values) {
                *s += f64::from(v);
            }
        }
        members.push(m);
    }
    let n = paths.len() as f64;
    struct Replace<'a>(std::slice::Iter<'a, Vec<f64>>, f64);
    impl ModuleMapper for Replace<'_> {
        fn map_float<const D: usize>(&mut self, param: Param<Tensor<D>>) -> Param<Tensor<D>> {
            let sum = self.0.next().expect("one sum per parameter");
            let n = self.1;
            param.map(|t| {
                let (dims, device) = (t.dims(), t.device());
                let mean: Vec<f32> = sum.iter().map(|s| (s / n) as f32).collect();
                Tensor::from_data(TensorData::new(mean, dims), &device)
            })
        }
    }
    let net = first.map(&mut Replace(sums.iter(), n));
    let mut header = header;
    header.provenance = serde_json::json!({ "average_of": members });
    Ok((net, header))
}

/// A member's network and header, and its record in the mean's provenance (file,
/// fingerprint of the bytes loaded, provenance), from one read of the file.
fn load(path: &Path, device: &Device) -> Result<(RestorerNet, Header, serde_json::Value)> {
    let bytes = std::fs::read(path).map_err(|e| RestoreError::Io(path.to_path_buf(), e))?;
    let (net, header) = weights::load_bytes(&bytes, path, device, None, None)?;
    let member = serde_json::json!({
        "file": path.display().to_string(),
        "fingerprint": weights::fingerprint(&bytes),
        "provenance": header.provenance,
    });
    Ok((net, header, member))
}

/// Refuses a member `path` unlike the first file.
fn refuse_unlike(path: &Path, h: &Header, first_path: &Path, first: &Header) -> Result<()> {
    let why = if h.config != first.config {
        Some(format!(
            "config '{}' differs from {}'s '{}' (another network, or another bank K or residual base)",
            h.config.name,
            first_path.display(),
            first.config.name
        ))
    } else if h.trained_psf_px != first.trained_psf_px {
        Some(format!(
            "trained on PSF scales {:?} px, {} on {:?}",
            h.trained_psf_px,
            first_path.display(),
            first.trained_psf_px
        ))
    } else if h.family.is_some() != first.family.is_some() {
        Some(format!(
            "{} a lens family, {} {}",
            if h.family.is_some() { "has" } else { "has no" },
            first_path.display(),
            if first.family.is_some() {
                "has one"
            } else {
                "has none"
            }
        ))
    } else {
        None
    };
    match why {
        Some(message) => Err(RestoreError::Weights {
            path: path.to_path_buf(),
            message: format!("cannot be averaged with the first file: {message}"),
        }),
        None => Ok(()),
    }
}
