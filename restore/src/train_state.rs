//! What a training run needs, besides its weights, to continue exactly where it stopped: the
//! schedule, the step reached, the batch sampler's position and AdamW's moments. Written beside
//! the weights file (`W.state`) at every checkpoint, after the weights, with a hash of them so
//! a pair from two different checkpoints is refused rather than silently mixed.
//!
//! Layout: a safetensors file whose metadata holds the state's JSON under `metasplat`, the
//! format under `format` and, under `crc32`, the CRC-32 of the JSON and of the one tensor,
//! `optimizer` (u8): burn's AdamW record as burnpack bytes (burn's optimizer records have no
//! named-tensor store, so the moments travel as one blob). The earlier layout (magic line,
//! u64 header length, JSON, record, no checksum) still loads.

use crate::error::{RestoreError, Result};
use crate::train::Schedule;
use burn::optim::OptimizerRecord;
use burn::tensor::Bytes;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// The earlier layout's first line; still read.
const MAGIC: &[u8] = b"METASPLAT-RESTORER-STATE 1\n";
const FORMAT: &str = "metasplat-restorer-state 2";
const OPTIMIZER: &str = "optimizer";

/// The schedule and position of a run; the optimizer's moments travel beside it as burnpack.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TrainState {
    /// Steps done.
    pub step: usize,
    /// Flattened: the state file's JSON keeps one flat object.
    #[serde(flatten)]
    pub schedule: Schedule,
    /// Word position of the batch sampler's ChaCha8 stream (u128 as decimal text: JSON
    /// numbers would lose it).
    pub rng_word_pos: String,
    /// Training seconds before this checkpoint, summed over resumed runs.
    pub seconds: f64,
    /// [`crate::weights::fingerprint`] of the weights file written at the same checkpoint
    /// (bare FNV-1a hex in older states).
    pub weights_hash: String,
    /// (step, seconds, val PSNR, val SSIM) at every validation so far.
    pub val_log: Vec<(usize, f64, f64, f64)>,
}

/// Where the state of the run writing `weights` lives.
pub fn state_path(weights: &Path) -> PathBuf {
    let mut s = weights.as_os_str().to_owned();
    s.push(".state");
    PathBuf::from(s)
}

fn bad(path: &Path, message: impl Into<String>) -> RestoreError {
    RestoreError::Weights {
        path: path.to_path_buf(),
        message: message.into(),
    }
}

/// CRC-32 of the state's JSON and of the optimizer bytes.
fn crc(json: &str, record: &[u8]) -> String {
    let mut h = crc32fast::Hasher::new();
    h.update(json.as_bytes());
    h.update(&(record.len() as u64).to_le_bytes());
    h.update(record);
    format!("{:08x}", h.finalize())
}

/// Writes the state and the optimizer record to `path` (temporary name, then rename).
pub fn save(state: &TrainState, optim: OptimizerRecord, path: &Path) -> Result<()> {
    let json = serde_json::to_string(state).map_err(|e| bad(path, e.to_string()))?;
    let record = optim
        .into_bytes()
        .map_err(|e| bad(path, format!("cannot serialise the optimizer state: {e}")))?;
    let metadata = std::collections::HashMap::from([
        ("format".to_string(), FORMAT.to_string()),
        ("crc32".to_string(), crc(&json, &record)),
        ("metasplat".to_string(), json),
    ]);
    let view =
        safetensors::tensor::TensorView::new(safetensors::Dtype::U8, vec![record.len()], &record)
            .map_err(|e| bad(path, e.to_string()))?;
    let bytes = safetensors::serialize([(OPTIMIZER, view)], Some(metadata))
        .map_err(|e| bad(path, e.to_string()))?;
    base::write_bytes_atomically(path, &bytes).map_err(|e| RestoreError::Io(path.to_path_buf(), e))
}

/// The state's JSON and the optimizer bytes of a state file, the checksum checked.
fn split<'a>(bytes: &'a [u8], path: &Path) -> Result<(std::borrow::Cow<'a, str>, &'a [u8])> {
    if bytes.starts_with(MAGIC) {
        if bytes.len() < MAGIC.len() + 8 {
            return Err(bad(path, "truncated header"));
        }
        let start = MAGIC.len() + 8;
        let n = u64::from_le_bytes(bytes[MAGIC.len()..start].try_into().expect("8 bytes"));
        if n > (bytes.len() - start) as u64 {
            return Err(bad(path, "truncated header"));
        }
        let n = n as usize;
        let json = std::str::from_utf8(&bytes[start..start + n])
            .map_err(|e| bad(path, format!("bad header: {e}")))?;
        return Ok((json.into(), &bytes[start + n..]));
    }
    let not_state = |why: String| {
        bad(
            path,
            format!(
                "not a metasplat restorer training state ({why}: damaged, truncated or with bytes appended?)"
            ),
        )
    };
    let file =
        safetensors::SafeTensors::deserialize(bytes).map_err(|e| not_state(e.to_string()))?;
    let (_, meta) =
        safetensors::SafeTensors::read_metadata(bytes).map_err(|e| not_state(e.to_string()))?;
    let meta = meta.metadata().clone().unwrap_or_default();
    let (Some(FORMAT), Some(json), Some(stored)) = (
        meta.get("format").map(String::as_str),
        meta.get("metasplat"),
        meta.get("crc32"),
    ) else {
        return Err(not_state(format!("its metadata does not name '{FORMAT}'")));
    };
    let record = file
        .tensor(OPTIMIZER)
        .map_err(|e| not_state(e.to_string()))?
        .data();
    if crc(json, record) != *stored {
        return Err(bad(
            path,
            "checksum mismatch: the state is damaged, truncated or has bytes changed",
        ));
    }
    Ok((json.clone().into(), record))
}

/// Reads the state of the run whose weights are at `weights`, and checks that the two files
/// were written at the same checkpoint.
pub fn load(weights: &Path) -> Result<(TrainState, OptimizerRecord)> {
    let path = state_path(weights);
    let bytes = base::input::read(&path).map_err(|e| {
        RestoreError::Io(
            path.clone(),
            std::io::Error::new(
                e.kind(),
                format!("{e} (no training state: was this run started by this version?)"),
            ),
        )
    })?;
    let (json, record) = split(&bytes, &path)?;
    let state: TrainState =
        serde_json::from_str(&json).map_err(|e| bad(&path, format!("bad header: {e}")))?;
    if state.step > state.schedule.steps || state.rng_word_pos.parse::<u128>().is_err() {
        return Err(bad(
            &path,
            format!(
                "inconsistent state: step {} of {}, sampler position '{}'",
                state.step, state.schedule.steps, state.rng_word_pos
            ),
        ));
    }
    let weights_bytes =
        base::input::read(weights).map_err(|e| RestoreError::Io(weights.to_path_buf(), e))?;
    if !base::hash::names(&state.weights_hash, &weights_bytes) {
        let hash = crate::weights::fingerprint(&weights_bytes);
        return Err(bad(
            &path,
            format!(
                "written at another checkpoint than {} (weights hash {hash}, state expects {}); \
                 the run was interrupted between the two writes: start again with --init",
                weights.display(),
                state.weights_hash
            ),
        ));
    }
    let optim = OptimizerRecord::from_bytes(Bytes::from_bytes_vec(record.to_vec()))
        .map_err(|e| bad(&path, format!("bad optimizer state: {e}")))?;
    Ok((state, optim))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_state_json_is_one_flat_object_and_older_states_read_without_refresh_or_loss() {
        let state = TrainState {
            step: 7,
            schedule: Schedule {
                steps: 9,
                refresh_every: 3,
                loss: crate::train::Loss::L2,
                ..Default::default()
            },
            rng_word_pos: "340282366920938463463374607431768211455".into(),
            seconds: 2.5,
            weights_hash: "00ff".into(),
            val_log: vec![(7, 2.5, 20.0, 0.5)],
        };
        let json = serde_json::to_value(&state).unwrap();
        assert_eq!(json["steps"], 9);
        assert_eq!(json["refresh_every"], 3);
        assert_eq!(json["loss"], "l2");
        assert!(json.get("schedule").is_none(), "{json}");
        let back: TrainState = serde_json::from_value(json.clone()).unwrap();
        assert_eq!(back, state);
        // Written before `refresh_every` existed: those runs made their pairs once.
        let mut old = json;
        old.as_object_mut().unwrap().remove("refresh_every");
        old.as_object_mut().unwrap().remove("loss");
        let back: TrainState = serde_json::from_value(old).unwrap();
        assert_eq!(back.schedule.refresh_every, 0);
        // and before `loss` existed, with L1.
        assert_eq!(back.schedule.loss, crate::train::Loss::L1);
    }
}
