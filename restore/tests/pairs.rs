//! Captured pairs: a pair the imaging model made is the synthetic sample it stands for, and
//! a pairs folder whose photos do not pair up is refused naming the photo.

use aberration::{BlurMode, Image, ImagingModel, NoiseModel, PsfGrid};
use restore::RestorerConfig;
use restore::data::{Blur, Sample, TrainSet, load_pairs};

fn photo(seed: f32) -> Image {
    Image::from_fn(72, 64, |x, y| {
        let (x, y) = (x as f32, y as f32);
        [
            0.5 + 0.4 * (0.31 * x + seed).sin() * (0.17 * y).cos(),
            0.5 + 0.3 * (0.23 * y - seed).sin(),
            0.3 + 0.2 * ((x + y) * 0.05).cos(),
        ]
    })
}

fn grid() -> PsfGrid {
    let k = [0.1f32, 0.2, 0.4, 0.2, 0.1];
    let data = (0..9 * 3)
        .flat_map(|g| (0..25).map(move |i| k[i / 5] * k[i % 5] * (1.0 + 0.1 * (g % 3) as f32)))
        .collect();
    PsfGrid::from_planar(3, 5, data).unwrap()
}

#[test]
fn a_pair_made_by_the_imaging_model_is_the_synthetic_sample() {
    let (clean, native) = (photo(0.4), grid());
    let model = ImagingModel::new(
        &native,
        clean.width,
        clean.height,
        BlurMode::Tiled,
        None,
        NoiseModel::none(),
    )
    .unwrap();
    let captured = model.blur(&clean).unwrap();
    let pair = Sample::from_pair(&captured, &clean, &native, true).unwrap();
    let synthetic = Sample::make(&clean, &native, Blur::Grid, NoiseModel::none(), true, 1).unwrap();
    let crop = |s: &Sample| {
        let (mut i, mut t) = (vec![], vec![]);
        s.crop_into(3, 5, 32, &mut i, &mut t);
        (i, t)
    };
    assert_eq!(crop(&pair), crop(&synthetic));
    let cfg = RestorerConfig::tiny();
    let set =
        TrainSet::from_pairs(&[(captured.clone(), clean.clone())], &native, &cfg, &|| {}).unwrap();
    assert_eq!(set.samples.len(), 1);
    // The 3×3 grid of 5 px PSFs is a 15 px sensor: on a 72 px photo its PSFs are 25 px.
    assert_eq!(set.psf_px, [25, 25]);
    // A pair of two sizes is no pair.
    let small = Image::new(70, 64);
    assert!(Sample::from_pair(&small, &clean, &native, true).is_err());
}

#[test]
fn a_pairs_folder_pairs_by_name_and_size() {
    let dir = tempfile::tempdir().unwrap();
    let (cap, cln) = (dir.path().join("captured"), dir.path().join("clean"));
    std::fs::create_dir_all(&cap).unwrap();
    std::fs::create_dir_all(&cln).unwrap();
    for name in ["a.png", "b.png"] {
        photo(1.0).save_png(&cap.join(name)).unwrap();
        photo(2.0).save_png(&cln.join(name)).unwrap();
    }
    let pairs = load_pairs(dir.path(), 32).unwrap();
    assert_eq!(
        pairs.iter().map(|p| p.0.as_str()).collect::<Vec<_>>(),
        ["a.png", "b.png"]
    );
    // A captured photo without its clean one, and the other way round.
    photo(1.0).save_png(&cap.join("c.png")).unwrap();
    let e = load_pairs(dir.path(), 32).err().unwrap().to_string();
    assert!(e.contains("c.png") && e.contains("no clean photo"), "{e}");
    std::fs::remove_file(cap.join("c.png")).unwrap();
    photo(1.0).save_png(&cln.join("d.png")).unwrap();
    let e = load_pairs(dir.path(), 32).err().unwrap().to_string();
    assert!(
        e.contains("d.png") && e.contains("no captured photo"),
        "{e}"
    );
    std::fs::remove_file(cln.join("d.png")).unwrap();
    // Two sizes.
    Image::new(40, 40).save_png(&cln.join("b.png")).unwrap();
    let e = load_pairs(dir.path(), 32).err().unwrap().to_string();
    assert!(e.contains("b.png") && e.contains("one size"), "{e}");
}
