//! An interrupted training run, resumed from its checkpoint, ends where the uninterrupted run
//! ends. Alone in its binary: training reseeds burn's global generator.

use aberration::{Image, NoiseModel, PsfGrid};
use burn::module::Module;
use burn::tensor::{Device, Tensor, TensorData};
use restore::data::TrainSet;
use restore::train::{Schedule, Start, TrainOptions, TrainRun, ValSet, round_seed, train};
use restore::train_state::{self, state_path};
use restore::{RestoreError, RestorerConfig, RestorerNet, weights};
use std::path::Path;

fn photo(seed: f32) -> Image {
    Image::from_fn(48, 48, |x, y| {
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

fn blur_grid() -> PsfGrid {
    let k = [0.1f32, 0.2, 0.4, 0.2, 0.1];
    let data = (0..9 * 3)
        .flat_map(|_| (0..25).map(|i| k[i / 5] * k[i % 5]))
        .collect();
    PsfGrid::from_planar(3, 5, data).unwrap()
}

/// Network outputs on a fixed input, as f32 on the inference device.
fn outputs(net: &RestorerNet) -> Vec<f32> {
    let device = Device::flex();
    let x: Vec<f32> = (0..39 * 32 * 32)
        .map(|i| 0.5 + 0.3 * (i as f32 * 0.37).sin())
        .collect();
    let x = Tensor::<4>::from_data(TensorData::new(x, [1, 39, 32, 32]), &device);
    net.forward(x).try_into_vec_as::<f32>().unwrap()
}

fn max_diff(a: &[f32], b: &[f32]) -> f32 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max)
}

#[test]
fn a_resumed_run_ends_where_the_uninterrupted_run_ends() {
    let mut cfg = RestorerConfig::tiny();
    cfg.crop = 32;
    let psf = blur_grid();
    let noise = NoiseModel::default();
    let photos = [photo(0.0), photo(1.3)];
    let make =
        |round: usize| TrainSet::build(&photos, &psf, &cfg, noise, round_seed(5, round), &|| {});
    let val = ValSet::build(&[("v".into(), photo(2.1))], &psf, &cfg, noise, Some(32)).unwrap();
    let device = Device::flex().autodiff();
    device.seed(11);
    let init = RestorerNet::new(&cfg, &device);
    let opts = TrainOptions {
        schedule: Schedule {
            steps: 4,
            batch: 1,
            lr: 2e-3,
            seed: 3,
            // A new round of training pairs at step 3: after the resume point, so the resumed
            // run must make the same pairs as the straight one.
            refresh_every: 3,
            ..Default::default()
        },
        val_every: 0,
        ..Default::default()
    };
    let provenance = |_: usize, _: f64, _: (f64, f64)| serde_json::Value::Null;
    let dir = tempfile::tempdir().unwrap();
    let run = |start: Start, opts: &TrainOptions, out: &Path| {
        let run = TrainRun {
            config: &cfg,
            native: &psf,
            pairs: &make,
            val: &val,
            options: opts,
            out,
            provenance: &provenance,
        };
        train(&run, start, &mut |_| {}).unwrap()
    };

    let whole = dir.path().join("whole.bin");
    let (straight, _, reached) = run(Start::Init(init.clone()), &opts, &whole);
    assert_eq!(reached, 4);

    // Interrupted after 2 steps: the checkpoint is written where it stopped.
    let cut = dir.path().join("cut.bin");
    let first_half = TrainOptions {
        stop_after_steps: Some(2),
        ..opts.clone()
    };
    let (_, _, reached) = run(Start::Init(init.clone()), &first_half, &cut);
    assert_eq!(reached, 2);
    let (state, record) = train_state::load(&cut).unwrap();
    assert_eq!((state.step, &state.schedule), (2, &opts.schedule));
    assert_eq!(state.val_log.len(), 1);
    let (net, _) = weights::load(&cut, &device, Some(&cfg), Some(&psf)).unwrap();
    let halfway = outputs(&net.valid());

    // Resumed: the options passed now are overridden by the saved schedule.
    let other = TrainOptions {
        schedule: Schedule {
            steps: 50,
            lr: 1.0,
            seed: 99,
            refresh_every: 1,
            ..opts.schedule.clone()
        },
        ..opts.clone()
    };
    let (resumed, _, reached) = run(
        Start::Resume(net.clone(), Box::new(state), record),
        &other,
        &cut,
    );
    assert_eq!(reached, 4);
    let (state, _) = train_state::load(&cut).unwrap();
    assert_eq!(state.step, 4);
    assert_eq!(state.val_log.len(), 2);

    let (a, b) = (outputs(&straight), outputs(&resumed));
    assert!(a.iter().all(|v| v.is_finite()));
    let d = max_diff(&a, &b);
    assert!(d < 1e-5, "resumed differs from uninterrupted by {d}");

    // Weights alone (fresh AdamW, restarted schedule and sampler) do not get there: the test
    // can tell a real resume from a restart.
    let restart = TrainOptions {
        schedule: Schedule {
            steps: 2,
            ..opts.schedule.clone()
        },
        ..opts.clone()
    };
    let (restarted, _, _) = run(Start::Init(net), &restart, &dir.path().join("restart.bin"));
    let moved = max_diff(&a, &halfway);
    let off = max_diff(&a, &outputs(&restarted));
    assert!(moved > 1e-3, "two steps barely moved the network ({moved})");
    assert!(off > 100.0 * d.max(1e-7), "restart {off} vs resume {d}");
}

#[test]
fn a_state_from_another_checkpoint_is_refused_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("w.bin");
    let err = train_state::load(&missing).unwrap_err().to_string();
    assert!(err.contains("w.bin.state"), "{err}");

    // A state written with the hash of other weights.
    std::fs::write(&missing, b"weights at step 20").unwrap();
    let state = train_state::TrainState {
        step: 10,
        schedule: Schedule {
            steps: 40,
            batch: 1,
            lr: 1e-3,
            refresh_every: 0,
            ..Default::default()
        },
        rng_word_pos: "123".into(),
        seconds: 1.0,
        weights_hash: weights::fingerprint(b"weights at step 10"),
        val_log: vec![],
    };
    train_state::save(
        &state,
        burn::optim::OptimizerRecord::default(),
        &state_path(&missing),
    )
    .unwrap();
    match train_state::load(&missing) {
        Err(RestoreError::Weights { path, message }) => {
            assert_eq!(path, state_path(&missing));
            assert!(message.contains("another checkpoint"), "{message}");
        }
        other => panic!("expected a refusal, got {other:?}"),
    }
    // Same hash: accepted, and the state round-trips.
    std::fs::write(&missing, b"weights at step 10").unwrap();
    let (back, record) = train_state::load(&missing).unwrap();
    assert_eq!(back, state);
    assert!(record.is_empty());

    // A safetensors file with the state in its metadata; a flipped byte in the optimizer's
    // bytes or in the JSON is refused by the checksum, naming the file.
    let bytes = std::fs::read(state_path(&missing)).unwrap();
    let (_, meta) = safetensors::SafeTensors::read_metadata(&bytes).unwrap();
    let meta = meta.metadata().clone().unwrap();
    assert_eq!(meta["format"], "metasplat-restorer-state 2");
    let json = meta["metasplat"].clone();
    let at = bytes
        .windows(6)
        .position(|w| w == b"step\\\"")
        .unwrap_or(bytes.len() - 1);
    for at in [bytes.len() - 1, at] {
        let mut bad = bytes.clone();
        bad[at] ^= 0x01;
        std::fs::write(state_path(&missing), &bad).unwrap();
        let err = train_state::load(&missing).unwrap_err().to_string();
        assert!(err.contains("w.bin.state"), "{err}");
    }
    // The earlier layout (magic line, header length, JSON, burnpack record) still loads.
    let record = burn::optim::OptimizerRecord::default()
        .into_bytes()
        .unwrap();
    let old = [
        b"METASPLAT-RESTORER-STATE 1\n".as_slice(),
        &(json.len() as u64).to_le_bytes(),
        json.as_bytes(),
        &record,
    ]
    .concat();
    std::fs::write(state_path(&missing), &old).unwrap();
    assert_eq!(train_state::load(&missing).unwrap().0, state);

    // Truncated: refused, not a panic.
    for bytes in [&bytes, &old] {
        std::fs::write(state_path(&missing), &bytes[..bytes.len() / 3]).unwrap();
        assert!(train_state::load(&missing).is_err());
    }
}

#[test]
fn each_refresh_round_aberrates_the_photos_anew_and_reproducibly() {
    let cfg = RestorerConfig::tiny();
    let (psf, noise) = (blur_grid(), NoiseModel::default());
    let photos = [photo(0.4)];
    let pairs = |round| TrainSet::build(&photos, &psf, &cfg, noise, round_seed(8, round), &|| {});
    let crops = |set: TrainSet| {
        let mut rng = <rand_chacha::ChaCha8Rng as rand::SeedableRng>::seed_from_u64(1);
        set.batch(&mut rng, 2, 32)
    };
    let (a, again, next) = (
        crops(pairs(0).unwrap()),
        crops(pairs(0).unwrap()),
        crops(pairs(1).unwrap()),
    );
    assert_eq!(a, again);
    // Same crops and clean targets; new noise (and PSF position) in the inputs.
    assert_eq!(a.1, next.1);
    let changed = a.0.iter().zip(&next.0).filter(|(x, y)| x != y).count();
    assert!(
        changed > a.0.len() / 2,
        "{changed} of {} inputs changed",
        a.0.len()
    );
    assert_eq!(round_seed(8, 0), 8);
    assert_ne!(round_seed(8, 1), round_seed(8, 2));
}
