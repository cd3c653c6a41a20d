//! The PSF grid file (paper layout), its validation, and the resolution mapping.

use aberration::resample::resampled_size;
use aberration::{AberrationError, PsfGrid};
use npyz::WriterBuilder;
use std::path::Path;

fn write_npy<T: npyz::Serialize + npyz::AutoSerialize + Copy>(
    path: &Path,
    shape: &[u64],
    data: &[T],
) {
    let mut file = std::fs::File::create(path).unwrap();
    let mut w = npyz::WriteOptions::new()
        .default_dtype()
        .shape(shape)
        .writer(&mut file)
        .begin_nd()
        .unwrap();
    w.extend(data.iter().copied()).unwrap();
    w.finish().unwrap();
}

fn sample_grid() -> PsfGrid {
    let (g, k) = (3, 5);
    let data = (0..g * g * 3 * k * k)
        .map(|i| 1.0 + (i % 7) as f32)
        .collect();
    PsfGrid::from_planar(g, k, data).unwrap()
}

#[test]
fn round_trip_is_exact_and_uses_the_paper_layout() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("psf.npy");
    let grid = sample_grid();
    grid.save_npy(&path).unwrap();
    let back = PsfGrid::load_npy(&path).unwrap();
    assert!(grid == back, "the grid changed in a save/load round trip");
    // Layout (G·G, K, K, 3): element [g, y, x, c] is kernel(g, c)[y*K + x].
    let npy = npyz::NpyFile::new(std::fs::File::open(&path).unwrap()).unwrap();
    assert_eq!(npy.shape(), &[9, 5, 5, 3]);
    let raw: Vec<f32> = npy.into_vec().unwrap();
    assert_eq!(
        raw[((4 * 5 + 2) * 5 + 3) * 3 + 1],
        grid.kernel(4, 1)[2 * 5 + 3]
    );
    // Nothing but the output is left in the directory.
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
}

#[test]
fn float64_files_are_accepted_and_normalised() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("psf64.npy");
    let data: Vec<f64> = (0..4 * 3 * 3 * 3).map(|i| (i % 5) as f64 + 0.5).collect();
    write_npy(&path, &[4, 3, 3, 3], &data);
    let grid = PsfGrid::load_npy(&path).unwrap();
    assert_eq!((grid.grid(), grid.size()), (2, 3));
    let s: f32 = grid.kernel(3, 2).iter().sum();
    assert!((s - 1.0).abs() < 1e-6);
}

fn load_err(name: &str, shape: &[u64], data: &[f32]) -> String {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join(name);
    write_npy(&path, shape, data);
    let err = PsfGrid::load_npy(&path).unwrap_err();
    assert!(matches!(err, AberrationError::BadPsfFile { .. }), "{err:?}");
    let msg = err.to_string();
    assert!(msg.contains(name), "error does not name the file: {msg}");
    msg
}

#[test]
fn bad_files_are_rejected_with_the_file_and_the_problem() {
    let ones = vec![1.0f32; 1000];
    assert!(load_err("flat.npy", &[100], &ones[..100]).contains("shape"));
    assert!(load_err("grey.npy", &[4, 5, 5], &ones[..100]).contains("shape"));
    assert!(load_err("nonsquare.npy", &[2, 5, 5, 3], &ones[..150]).contains("square grid"));
    assert!(load_err("rect.npy", &[4, 5, 4, 3], &ones[..240]).contains("square"));
    let mut nan = ones[..4 * 9 * 3].to_vec();
    nan[17] = f32::NAN;
    assert!(load_err("nan.npy", &[4, 3, 3, 3], &nan).contains("non-finite"));
    let mut zero = ones[..4 * 9 * 3].to_vec();
    for y in 0..9 {
        zero[(2 * 9 + y) * 3 + 1] = 0.0; // PSF 2, green channel
    }
    let msg = load_err("zero.npy", &[4, 3, 3, 3], &zero);
    assert!(
        msg.contains("PSF 2 channel 1") && msg.contains("sums to 0"),
        "{msg}"
    );

    let dir = tempfile::tempdir().unwrap();
    let ints = dir.path().join("ints.npy");
    let mut file = std::fs::File::create(&ints).unwrap();
    let mut w = npyz::WriteOptions::new()
        .default_dtype()
        .shape(&[1, 2, 2, 3])
        .writer(&mut file)
        .begin_nd()
        .unwrap();
    w.extend([1i32; 12]).unwrap();
    w.finish().unwrap();
    let msg = PsfGrid::load_npy(&ints).unwrap_err().to_string();
    assert!(msg.contains("ints.npy") && msg.contains("dtype"), "{msg}");

    let truncated = dir.path().join("trunc.npy");
    write_npy(&truncated, &[4, 3, 3, 3], &ones[..108]);
    let bytes = std::fs::read(&truncated).unwrap();
    std::fs::write(&truncated, &bytes[..bytes.len() - 40]).unwrap();
    let msg = PsfGrid::load_npy(&truncated).unwrap_err().to_string();
    assert!(msg.contains("trunc.npy"), "{msg}");

    let garbage = dir.path().join("garbage.npy");
    std::fs::write(&garbage, b"not a numpy file at all").unwrap();
    assert!(
        PsfGrid::load_npy(&garbage)
            .unwrap_err()
            .to_string()
            .contains("garbage.npy")
    );

    let missing = dir.path().join("missing.npy");
    let msg = PsfGrid::load_npy(&missing).unwrap_err().to_string();
    assert!(msg.contains("missing.npy"), "{msg}");
}

#[test]
fn failed_save_leaves_no_file() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("no_such_dir").join("psf.npy");
    assert!(sample_grid().save_npy(&path).is_err());
    assert!(!path.exists());
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
}

#[test]
fn resolution_mapping_preserves_energy_centre_and_width() {
    // A Gaussian of sigma 6 px at 135 px, mapped to a 504-px image of a 1215-px sensor.
    let k = 135;
    let sigma = 6.0f64;
    let c = (k / 2) as f64;
    let kernel: Vec<f32> = (0..k * k)
        .map(|i| {
            let (y, x) = ((i / k) as f64 - c, (i % k) as f64 - c);
            (-(x * x + y * y) / (2.0 * sigma * sigma)).exp() as f32
        })
        .collect();
    let grid = PsfGrid::uniform(9, k, [&kernel, &kernel, &kernel]).unwrap();
    let mapped = grid.for_image(504, 378, None).unwrap();
    let scale = 504.0 / 1215.0;
    let n = mapped.size();
    assert_eq!(n, resampled_size(k, scale));
    assert_eq!(n, 57, "135 px at 504/1215 should need 57 px");
    let m = mapped.kernel(40, 1);
    let sum: f64 = m.iter().map(|v| *v as f64).sum();
    assert!((sum - 1.0).abs() < 1e-5);
    let cn = (n / 2) as f64;
    let (mut mx, mut var) = (0.0, 0.0);
    for (i, v) in m.iter().enumerate() {
        let x = (i % n) as f64 - cn;
        mx += x * *v as f64;
    }
    for (i, v) in m.iter().enumerate() {
        let x = (i % n) as f64 - cn;
        var += (x - mx).powi(2) * *v as f64;
    }
    assert!(mx.abs() < 1e-4, "centre moved by {mx}");
    // Area resampling adds the variance of a box of one output pixel (1/12).
    let expect = (sigma * scale).powi(2) + 1.0 / 12.0;
    assert!(
        (var / expect - 1.0).abs() < 0.02,
        "variance {var}, expected {expect}"
    );
    // Identity mapping returns the grid unchanged; upsampling keeps unit sum too.
    assert_eq!(grid.for_image(1215, 1215, None).unwrap(), grid);
    // A sensor far smaller than the image is refused before anything is allocated.
    let err = grid.for_image(64, 48, Some(1)).unwrap_err().to_string();
    assert!(err.contains("sensor") && err.contains("at most"), "{err}");
    let up = grid.resampled(1.7);
    let s: f64 = up.kernel(0, 0).iter().map(|v| *v as f64).sum();
    assert!((s - 1.0).abs() < 1e-5);
}

#[test]
fn small_negative_noise_is_clamped_and_more_is_refused() {
    // PSF 1, red channel: 9 values of 1, then a negative value of 5% or 0.5% of that energy.
    let ones = vec![1.0f32; 4 * 9 * 3];
    let at = (9 + 4) * 3; // PSF 1, pixel 4, channel 0
    let mut big = ones.clone();
    big[at] = -0.45;
    let msg = load_err("negative.npy", &[4, 3, 3, 3], &big);
    assert!(
        msg.contains("PSF 1 channel 0") && msg.contains("negative") && msg.contains("1%"),
        "{msg}"
    );
    let mut small = ones.clone();
    small[at] = -0.04;
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("noise.npy");
    write_npy(&path, &[4, 3, 3, 3], &small);
    let grid = PsfGrid::load_npy(&path).unwrap();
    let k = grid.kernel(1, 0);
    assert!(k.iter().all(|v| *v >= 0.0), "{k:?}");
    assert_eq!(k[4], 0.0);
    assert!((k.iter().sum::<f32>() - 1.0).abs() < 1e-6);
    // The other kernels are untouched: 9 equal values.
    assert!(
        grid.kernel(1, 1)
            .iter()
            .all(|v| (*v - 1.0 / 9.0).abs() < 1e-7)
    );
}

#[test]
fn shapes_that_overflow_or_claim_more_than_the_file_are_refused_before_allocation() {
    let dir = tempfile::tempdir().unwrap();
    let good = dir.path().join("good.npy");
    write_npy(&good, &[4, 3, 3, 3], &vec![1.0f32; 108]);
    let bytes = std::fs::read(&good).unwrap();
    let text = String::from_utf8_lossy(&bytes[10..]).to_string();
    for (shape, expect) in [
        ("(1, 4294967296, 4294967296, 3)", "1 GiB"),
        ("(18446744073709551615, 3, 3, 3)", "1 GiB"),
        ("(100000, 300, 300, 3)", "1 GiB"),
        ("(9, 3, 3, 3)", "needs 972 bytes"),
        ("(1, 3, 3, 3)", "needs 108 bytes"),
    ] {
        // Same header length: pad the shape into the same number of characters.
        let open = text.find("'shape': (").unwrap() + "'shape': ".len();
        let close = open + text[open..].find(')').unwrap() + 1;
        let header = format!("{}{shape}{}", &text[..open], &text[close..]);
        let pad = header.find('}').unwrap() + 1;
        let old_len = u16::from_le_bytes([bytes[8], bytes[9]]) as usize;
        let mut h = header[..pad].to_string();
        while h.len() < old_len - 1 {
            h.push(' ');
        }
        h.push('\n');
        let mut file = bytes[..8].to_vec();
        file.extend_from_slice(&(h.len() as u16).to_le_bytes());
        file.extend_from_slice(h.as_bytes());
        file.extend_from_slice(&bytes[10 + old_len..]);
        let path = dir.path().join("lying.npy");
        std::fs::write(&path, &file).unwrap();
        let msg = PsfGrid::load_npy(&path).unwrap_err().to_string();
        assert!(
            msg.contains("lying.npy") && msg.contains(expect),
            "{shape}: {msg}"
        );
    }
}

#[test]
fn a_chosen_psf_scale_is_reached_on_any_photo_size() {
    let k = 135;
    let kernel = vec![1.0f32 / (k * k) as f32; k * k];
    let grid = PsfGrid::uniform(9, k, [&kernel, &kernel, &kernel]).unwrap();
    for (w, h) in [(500, 500), (768, 512), (504, 378), (4032, 3024), (33, 97)] {
        for px in [15usize, 19, 38, 57, 85, 113, 135, 140] {
            let sensor = grid.sensor_for_psf_px(w, h, px);
            let n = grid.for_image(w, h, Some(sensor)).map(|g| g.size());
            // A mapped side is odd: an odd target exactly, an even one a neighbour.
            let ok = |n: usize| {
                if px % 2 == 1 {
                    n == px
                } else {
                    n.abs_diff(px) == 1
                }
            };
            match n {
                Ok(n) => assert!(ok(n), "{w}x{h} at {px} px: sensor {sensor} maps to {n}"),
                // Only where the PSF would exceed twice the photo.
                Err(_) => assert!(px > 2 * w.max(h), "{w}x{h} at {px} px refused"),
            }
        }
    }
}
