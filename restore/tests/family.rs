//! Training over a lens family: pairs through drawn lenses at drawn scales, weights that say
//! what they cover, and loading that accepts a lens of the family the run never simulated.
//! Alone in its binary: training reseeds burn's global generator.

use aberration::optics::SimConfig;
use aberration::{Image, NoiseModel, PsfGrid};
use restore::data::TrainSet;
use restore::family::LensFamily;
use restore::train::{
    Schedule, Start, TrainOptions, TrainRun, ValSet, round_seed, train, validate, validate_groups,
};
use restore::{RestorerConfig, weights};

fn photo(seed: f32) -> Image {
    Image::from_fn(80, 72, |x, y| {
        let (x, y) = (x as f32, y as f32);
        [
            0.5 + 0.4 * (0.31 * x + seed).sin() * (0.17 * y).cos(),
            0.5 + 0.3 * (0.23 * y - seed).sin(),
            if (x as usize / 6 + y as usize / 6).is_multiple_of(2) {
                0.8
            } else {
                0.2
            },
        ]
    })
}

#[test]
fn a_family_run_serves_lenses_of_the_family_it_never_simulated_and_no_others() {
    let base = SimConfig::small(21);
    let family = LensFamily {
        psf_px: [9, 31],
        ..LensFamily::default()
    };
    let seed = 4;
    let bank: Vec<PsfGrid> = (0..8)
        .map(|i| family.lens(&base, i, seed).simulate().unwrap())
        .collect();
    let record = family.record(&bank).unwrap();
    assert_eq!(record.drawn["psf_px"], serde_json::json!([9, 31]));
    // Lenses drawn past the bank: inside the envelope of the bank's shapes (all of 32 drawn
    // when this was written).
    for i in 8..20 {
        let lens = family.lens(&base, i, seed).simulate().unwrap();
        assert_eq!(record.envelope.holds(&lens), Ok(()), "lens {i}");
    }
    // Another design (an ideal lens for green, without the metalens's dispersion): outside,
    // its colours' widths far from the family's.
    let mut far = base.clone();
    far.lens = aberration::optics::Lens::ideal(
        base.lens.aperture_um,
        base.lens.focal_um,
        base.lens.pitch_um,
        511.0,
    );
    let far = aberration::optics::simulate_grid(&far, &|_, _| {})
        .unwrap()
        .0;
    let e = record.envelope.holds(&far).unwrap_err();
    assert!(
        e.contains("red width at the centre") && e.contains("green width"),
        "{e}"
    );

    // Pairs: two per photo, each as large as its (possibly turned) photo.
    let mut cfg = RestorerConfig::tiny();
    cfg.crop = 32;
    let photos = [photo(0.0), photo(1.3)];
    let noise = NoiseModel::default();
    let set = TrainSet::build_family(&photos, &bank, &family, &cfg, noise, 17, &|| {}).unwrap();
    assert_eq!(set.samples.len(), 4);
    assert_eq!(set.psf_px, [9, 31]);
    for s in &set.samples {
        assert!(matches!((s.width, s.height), (80, 72) | (72, 80)));
    }
    let again = TrainSet::build_family(&photos, &bank, &family, &cfg, noise, 17, &|| {}).unwrap();
    let mut rng = <rand_chacha::ChaCha8Rng as rand::SeedableRng>::seed_from_u64(1);
    let mut rng2 = <rand_chacha::ChaCha8Rng as rand::SeedableRng>::seed_from_u64(1);
    assert_eq!(set.batch(&mut rng, 2, 32), again.batch(&mut rng2, 2, 32));
    assert!(TrainSet::build_family(&photos, &[], &family, &cfg, noise, 17, &|| {}).is_err());

    // Two steps of a family run: the weights record the family and load for a new lens.
    let make = |round: usize| {
        TrainSet::build_family(
            &photos,
            &bank,
            &family,
            &cfg,
            noise,
            round_seed(5, round),
            &|| {},
        )
    };
    let val = ValSet::build(&[("v".into(), photo(2.1))], &bank[0], &cfg, noise, Some(32)).unwrap();
    let opts = TrainOptions {
        schedule: Schedule {
            steps: 2,
            batch: 1,
            lr: 1e-3,
            seed: 3,
            ..Default::default()
        },
        val_every: 0,
        family: Some(record.clone()),
        ..Default::default()
    };
    let provenance = |_: usize, _: f64, _: (f64, f64)| serde_json::Value::Null;
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("family.bin");
    let run = TrainRun {
        config: &cfg,
        native: &bank[0],
        pairs: &make,
        val: &val,
        options: &opts,
        out: &out,
        provenance: &provenance,
    };
    let (_, _, reached) = train(&run, Start::Fresh, &mut |_| {}).unwrap();
    assert_eq!(reached, 2);
    let (header, _) = weights::read(&out).unwrap();
    assert_eq!(header.family.as_ref(), Some(&record));
    assert_eq!(header.trained_psf_px, Some([9, 31]));
    let device = burn::tensor::Device::flex();
    let unseen = family.lens(&base, 20, seed).simulate().unwrap();
    assert!(weights::load(&out, &device, None, Some(&unseen)).is_ok());
    let e = weights::load(&out, &device, None, Some(&far))
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("family.bin") && e.contains("outside it"), "{e}");

    // Validation reports each group's mean (a family run's PSF scales) beside the whole
    // set's, each equal to the mean over its photos scored alone.
    let restorer = restore::Restorer::from_bytes_any_grid_on(
        &std::fs::read(&out).unwrap(),
        &out,
        device.clone(),
    )
    .unwrap();
    let photos3 = [
        ("p0".to_string(), photo(0.4)),
        ("p1".to_string(), photo(2.7)),
        ("p2".to_string(), photo(5.0)),
    ];
    let mut val3 = ValSet::build(&photos3, &bank[0], &cfg, noise, Some(32)).unwrap();
    val3.groups = ["9 px", "31 px", "9 px"].map(String::from).to_vec();
    let alone = |i: usize| {
        let one = ValSet {
            names: vec![val3.names[i].clone()],
            banks: vec![val3.banks[i].clone()],
            clean: vec![val3.clean[i].clone()],
            groups: Vec::new(),
        };
        validate(&restorer, &one).unwrap().0
    };
    let (p0, p1, p2) = (alone(0), alone(1), alone(2));
    let ((mean, _), groups) = validate_groups(&restorer, &val3).unwrap();
    assert!(
        (mean - (p0 + p1 + p2) / 3.0).abs() < 1e-9,
        "{mean} against {p0} {p1} {p2}"
    );
    assert_eq!(groups.len(), 2, "{groups:?}");
    assert_eq!(
        (groups[0].0.as_str(), groups[1].0.as_str()),
        ("9 px", "31 px")
    );
    assert!((groups[0].1 - (p0 + p2) / 2.0).abs() < 1e-9, "{groups:?}");
    assert!((groups[1].1 - p1).abs() < 1e-9, "{groups:?}");
    // A set of one group reports none.
    val3.groups.clear();
    assert!(validate_groups(&restorer, &val3).unwrap().1.is_empty());
}
