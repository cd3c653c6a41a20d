//! Photos as a run reads them when that is not as their files hold them (shrunk from
//! `images/` for a `--downsample` the capture has no folder for, or undistorted), kept beside
//! the capture (`CAPTURE/photo_cache/`) so that the next run decodes, shrinks and remaps
//! nothing: a cached photo is read back bit for bit.
//!
//! An entry is named by the XXH3 of everything that decides its pixels: the photo file's
//! bytes (an edited photo is another entry), the shrink, the remap's fingerprint and
//! [`CACHE_VERSION`]. It is a safetensors file (`safetensors.numpy.load_file(p)["photo"]`:
//! `[height, width, 3]` float32) that also holds its own key and the XXH3 of its pixels; one
//! that does not check out is ignored and made again.

use std::path::{Path, PathBuf};

use crate::cache_entry::{self, Checksum};
use crate::images::Photo;

/// The folder beside the capture's photos.
pub const CACHE_DIR: &str = "photo_cache";
/// Part of every key: bump it when loading changes what it makes of the same file.
pub const CACHE_VERSION: u32 = 1;
/// The tensor an entry holds.
pub const TENSOR: &str = "photo";

/// Where the photos of the capture at `root` are cached: beside them when a file can be made
/// there (tried with a temporary one that is gone at once: permission bits do not tell on a
/// read-only mount, or as root); None when it cannot (a shared read-only data set).
pub fn location(root: &Path) -> Option<PathBuf> {
    let dir = root.join(CACHE_DIR);
    let probe = if dir.is_dir() { &dir } else { root };
    tempfile::NamedTempFile::new_in(probe).ok().map(|_| dir)
}

/// The key of the photo made from a file of `bytes`, shrunk `shrink` times, then remapped by
/// the remap of fingerprint `remap` (if any).
pub fn key(bytes: &[u8], shrink: u32, remap: Option<u64>) -> u64 {
    let mut keyed = Vec::with_capacity(32);
    keyed.extend(CACHE_VERSION.to_le_bytes());
    keyed.extend(base::hash::xxh3(bytes).to_le_bytes());
    keyed.extend(shrink.to_le_bytes());
    keyed.extend(remap.map_or([0; 9], |r| {
        let mut b = [1; 9];
        b[1..].copy_from_slice(&r.to_le_bytes());
        b
    }));
    base::hash::xxh3(&keyed)
}

/// The cached photo for `key`, when there is a whole one of `width` × `height`.
pub fn get(dir: &Path, key: u64, width: u32, height: u32) -> Option<Photo> {
    let shape = [height as usize, width as usize, 3];
    let data = cache_entry::read(dir, key, TENSOR, &shape, Checksum::Xxh3)?;
    Some(Photo {
        width,
        height,
        data,
    })
}

/// Stores `photo` under `key` (atomically; the folder is made if needed).
pub fn put(dir: &Path, key: u64, photo: &Photo) -> std::io::Result<()> {
    let shape = vec![photo.height as usize, photo.width as usize, 3];
    cache_entry::write(dir, key, TENSOR, shape, &photo.data, Checksum::Xxh3)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_entry_comes_back_exactly_and_a_damaged_or_misnamed_one_not_at_all() {
        let dir = tempfile::tempdir().unwrap();
        let photo = Photo {
            width: 4,
            height: 3,
            data: (0..36).map(|i| i as f32 / 7.0).collect(),
        };
        let k = key(b"photo bytes", 2, Some(9));
        assert!(get(dir.path(), k, 4, 3).is_none());
        put(dir.path(), k, &photo).unwrap();
        assert_eq!(get(dir.path(), k, 4, 3).unwrap(), photo);
        // Another file, shrink or remap is another key.
        for other in [
            key(b"photo bytez", 2, Some(9)),
            key(b"photo bytes", 4, Some(9)),
            key(b"photo bytes", 2, Some(8)),
            key(b"photo bytes", 2, None),
        ] {
            assert_ne!(k, other);
        }
        assert!(get(dir.path(), k, 3, 4).is_none());
        let p = cache_entry::path(dir.path(), k);
        let good = std::fs::read(&p).unwrap();
        for at in [20, good.len() - 3] {
            let mut bad = good.clone();
            bad[at] ^= 1;
            std::fs::write(&p, &bad).unwrap();
            assert!(
                get(dir.path(), k, 4, 3).is_none(),
                "a flip at {at} was read"
            );
        }
        std::fs::write(&p, &good[..good.len() - 1]).unwrap();
        assert!(get(dir.path(), k, 4, 3).is_none());
        // Another photo's entry under this one's name is a miss.
        std::fs::write(&p, &good).unwrap();
        let k2 = key(b"another photo", 2, Some(9));
        std::fs::copy(&p, cache_entry::path(dir.path(), k2)).unwrap();
        assert!(get(dir.path(), k2, 4, 3).is_none());
    }
}
