//! One entry of a cache kept on disk, as the photo cache and the training's `I_ac` cache
//! write them: `KEY.safetensors` holding one float32 tensor and, in its metadata, the key
//! (hex) and a checksum of the key and the values. An entry is read back bit for bit or not
//! at all: one that is damaged, cut, of another shape or another key's is a miss.

use std::path::{Path, PathBuf};

/// The checksum an entry's metadata holds (each cache keeps the one it has always written, so
/// its existing entries stay hits).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Checksum {
    /// XXH3-64, hex, under `xxh3`.
    Xxh3,
    /// CRC-32, hex, under `crc32`.
    Crc32,
}

impl Checksum {
    fn field(self) -> &'static str {
        match self {
            Self::Xxh3 => "xxh3",
            Self::Crc32 => "crc32",
        }
    }

    fn of(self, key: u64, body: &[u8]) -> String {
        match self {
            Self::Xxh3 => {
                let mut keyed = key.to_le_bytes().to_vec();
                keyed.extend(body);
                format!("{:016x}", base::hash::xxh3(&keyed))
            }
            Self::Crc32 => {
                let mut h = crc32fast::Hasher::new();
                h.update(&key.to_le_bytes());
                h.update(body);
                format!("{:08x}", h.finalize())
            }
        }
    }
}

/// Where the entry of `key` lies in `dir`.
pub fn path(dir: &Path, key: u64) -> PathBuf {
    dir.join(format!("{key:016x}.safetensors"))
}

/// The values of the entry of `key`, when there is a whole one whose tensor `tensor` has
/// `shape`, whose key and checksum check out and whose values are all finite.
pub fn read(
    dir: &Path,
    key: u64,
    tensor: &str,
    shape: &[usize],
    sum: Checksum,
) -> Option<Vec<f32>> {
    let bytes = base::input::read(&path(dir, key)).ok()?;
    let tensors = safetensors::SafeTensors::deserialize(&bytes).ok()?;
    let (_, meta) = safetensors::SafeTensors::read_metadata(&bytes).ok()?;
    let meta = meta.metadata().clone()?;
    let t = tensors.tensor(tensor).ok()?;
    if t.dtype() != safetensors::Dtype::F32
        || t.shape() != shape
        || meta.get("key")? != &format!("{key:016x}")
        || meta.get(sum.field())? != &sum.of(key, t.data())
    {
        return None;
    }
    let values: Vec<f32> = t
        .data()
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes(b.try_into().expect("4 bytes")))
        .collect();
    values.iter().all(|v| v.is_finite()).then_some(values)
}

/// Stores `values` (of `shape`) as the entry of `key`, atomically; the folder is made if
/// needed.
pub fn write(
    dir: &Path,
    key: u64,
    tensor: &str,
    shape: Vec<usize>,
    values: &[f32],
    sum: Checksum,
) -> std::io::Result<()> {
    std::fs::create_dir_all(dir)?;
    let body: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
    let invalid = |e: safetensors::SafeTensorError| std::io::Error::other(e.to_string());
    let view = safetensors::tensor::TensorView::new(safetensors::Dtype::F32, shape, &body)
        .map_err(invalid)?;
    let meta = std::collections::HashMap::from([
        ("key".to_string(), format!("{key:016x}")),
        (sum.field().to_string(), sum.of(key, &body)),
    ]);
    let bytes = safetensors::serialize([(tensor, view)], Some(meta)).map_err(invalid)?;
    base::atomic::write_bytes_atomically(&path(dir, key), &bytes)
}
