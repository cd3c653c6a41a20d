//! A cache of `I_ac`, the restorer's images of the training views: they cost seconds per view
//! on a CPU and are the same for every run that uses the same restorer on the same photos.
//! A run keeps it beside the capture (`CAPTURE/i_ac_cache/`, [`for_run`]), so that every later
//! run on that capture with that restorer, and `metasplat view --scene CAPTURE`, reads it;
//! in its own folder (`RUN/i_ac_cache/`) when the capture's folder cannot be written or the
//! run already has one there. An experiment shares one between its restored and aware runs.
//!
//! An entry is named by a hash (XXH3) of everything that decides its pixels: the restorer's
//! identity (its config and the fingerprint of its weights, or the Wiener stand-in), the PSF
//! grid it was given, the image size and the observed pixels, and [`CACHE_VERSION`]. An entry
//! is a safetensors file (`safetensors.numpy.load_file(p)["i_ac"]` in Python) that also holds
//! its own key (an entry copied or renamed onto another view's name belongs to that other view)
//! and a CRC-32; one that does not check out is ignored and recomputed. Entries named as
//! caches before XXH3 named them (FNV-1a of the restorer's identity as it was then written),
//! safetensors or the layout before it (`.iac`), are still read.

use std::path::{Path, PathBuf};

use aberration::PsfGrid;
use glam::Vec3;
use scenes::cache_entry::{self, Checksum};

/// The layout of the entries before safetensors (still read).
const MAGIC: &[u8; 16] = b"METASPLAT-IAC 2\n";
/// Part of every key: bump it when restoring changes what it computes for the same inputs.
pub const CACHE_VERSION: u32 = 1;
/// The folder a run keeps its cache in.
pub const CACHE_DIR: &str = "i_ac_cache";

/// Where a run on the capture `scene` into the folder `run` keeps `I_ac`: beside the capture,
/// unless the run folder already holds a cache (a run resumed from before caches were kept
/// beside captures) or the capture's folder cannot be written (a shared read-only data set),
/// when it is the run's own. Nothing is written here: the entries come once the run's inputs
/// are checked.
pub fn for_run(scene: &Path, run: &Path) -> PathBuf {
    let own = run.join(CACHE_DIR);
    if own.is_dir() {
        return own;
    }
    let beside = scene.join(CACHE_DIR);
    // Whether a file can be made there, tried with a temporary one that is gone at once:
    // permission bits do not tell (a read-only mount, or root, which ignores them).
    let probe = if beside.is_dir() { &beside } else { scene };
    if tempfile::NamedTempFile::new_in(probe).is_ok() {
        beside
    } else {
        own
    }
}

/// Where `I_ac` of the capture `scene` is read from for viewing: the capture's cache when it
/// has one, else that of the run followed.
pub fn for_viewing(scene: &Path, run: Option<&Path>) -> Option<PathBuf> {
    let beside = scene.join(CACHE_DIR);
    if beside.is_dir() {
        Some(beside)
    } else {
        run.map(|r| r.join(CACHE_DIR))
    }
}

/// Names a restorer's entries: what a key holds besides the photo (the restorer's identity,
/// the PSF grid, [`CACHE_VERSION`]) hashed once, since it is the same for every view; and
/// the same as caches before XXH3 named them, so that their entries are still found.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Keyer {
    prefix: u64,
    legacy_prefix: u64,
}

/// The name of one view's entry, and the name caches before XXH3 gave it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Key {
    pub now: u64,
    pub before: u64,
}

impl Keyer {
    /// `restorer` and `legacy_restorer`: the restorer's identity as runs write it now and as
    /// they wrote it before XXH3 ([`crate::train::iac::IacSource::identity`] and its legacy).
    pub fn new(restorer: &str, legacy_restorer: &str, psf: &PsfGrid) -> Self {
        Self {
            prefix: base::hash::xxh3(&Self::prefix_bytes(restorer, psf)),
            legacy_prefix: base::hash::fnv1a64(&Self::prefix_bytes(legacy_restorer, psf)),
        }
    }

    fn prefix_bytes(restorer: &str, psf: &PsfGrid) -> Vec<u8> {
        let mut bytes = Vec::with_capacity(64 + restorer.len() + 4 * psf.planar().len());
        bytes.extend(CACHE_VERSION.to_le_bytes());
        bytes.extend((restorer.len() as u64).to_le_bytes());
        bytes.extend(restorer.as_bytes());
        bytes.extend(
            [psf.grid() as u64, psf.size() as u64]
                .map(u64::to_le_bytes)
                .concat(),
        );
        bytes.extend(psf.planar().iter().flat_map(|v| v.to_le_bytes()));
        bytes
    }

    /// The key of `I_ac` for one view.
    pub fn key(&self, width: u32, height: u32, observed: &[Vec3]) -> Key {
        let view = |prefix: u64| {
            let mut bytes = Vec::with_capacity(16 + 12 * observed.len());
            bytes.extend(prefix.to_le_bytes());
            bytes.extend(width.to_le_bytes());
            bytes.extend(height.to_le_bytes());
            bytes.extend(
                observed
                    .iter()
                    .flat_map(|p| p.to_array())
                    .flat_map(f32::to_le_bytes),
            );
            bytes
        };
        Key {
            now: base::hash::xxh3(&view(self.prefix)),
            before: base::hash::fnv1a64(&view(self.legacy_prefix)),
        }
    }
}

/// An entry as the caches before safetensors wrote it (still read).
fn legacy_path(dir: &Path, key: u64) -> PathBuf {
    dir.join(format!("{key:016x}.iac"))
}

/// The tensor an entry holds: `[pixels, 3]` float32, row-major RGB, with the key and the
/// CRC-32 of the key and the pixels in its metadata ([`scenes::cache_entry`]).
pub const TENSOR: &str = "i_ac";

fn floats(body: &[u8]) -> Option<Vec<Vec3>> {
    let floats: Vec<f32> = body
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes(b.try_into().expect("4 bytes")))
        .collect();
    if floats.iter().any(|v| !v.is_finite()) {
        return None;
    }
    Some(floats.chunks_exact(3).map(Vec3::from_slice).collect())
}

/// The cached image for `key`, when there is a whole one of `pixels` pixels: under its name,
/// or under the name caches before XXH3 gave it.
pub fn get(dir: &Path, key: Key, pixels: usize) -> Option<Vec<Vec3>> {
    get_entry(dir, key.now, pixels)
        .or_else(|| get_entry(dir, key.before, pixels))
        .or_else(|| get_legacy(dir, key.before, pixels))
}

fn get_entry(dir: &Path, key: u64, pixels: usize) -> Option<Vec<Vec3>> {
    let values = cache_entry::read(dir, key, TENSOR, &[pixels, 3], Checksum::Crc32)?;
    Some(values.chunks_exact(3).map(Vec3::from_slice).collect())
}

fn get_legacy(dir: &Path, key: u64, pixels: usize) -> Option<Vec<Vec3>> {
    let bytes = base::input::read(&legacy_path(dir, key)).ok()?;
    let payload = bytes.len().checked_sub(MAGIC.len() + 16)?;
    if !bytes.starts_with(MAGIC) || payload != 12 * pixels {
        return None;
    }
    let (keyed, sum) = bytes[MAGIC.len()..].split_at(8 + payload);
    if base::hash::fnv1a64(keyed).to_le_bytes() != sum || keyed[..8] != key.to_le_bytes() {
        return None;
    }
    floats(&keyed[8..])
}

/// Stores an image under `key` (atomically; the folder is made if needed). A cache folder
/// that is a symbolic link is refused: its entries would land in whatever folder it names.
pub fn put(dir: &Path, key: Key, image: &[Vec3]) -> std::io::Result<()> {
    let key = key.now;
    if std::fs::symlink_metadata(dir).is_ok_and(|m| m.file_type().is_symlink()) {
        return Err(std::io::Error::other(format!(
            "{} is a symbolic link; the cache writes only into a folder of its own (remove the link; the cache is made again)",
            dir.display()
        )));
    }
    let values: Vec<f32> = image.iter().flat_map(|p| p.to_array()).collect();
    cache_entry::write(
        dir,
        key,
        TENSOR,
        vec![image.len(), 3],
        &values,
        Checksum::Crc32,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_run_keeps_its_cache_beside_the_capture_unless_it_cannot() {
        let tmp = tempfile::tempdir().unwrap();
        let (scene, run) = (tmp.path().join("scene"), tmp.path().join("run"));
        std::fs::create_dir_all(&scene).unwrap();
        assert_eq!(for_run(&scene, &run), scene.join(CACHE_DIR));
        // Deciding wrote nothing.
        assert_eq!(std::fs::read_dir(&scene).unwrap().count(), 0);
        assert_eq!(for_viewing(&scene, Some(&run)), Some(run.join(CACHE_DIR)));
        std::fs::create_dir_all(scene.join(CACHE_DIR)).unwrap();
        assert_eq!(for_viewing(&scene, Some(&run)), Some(scene.join(CACHE_DIR)));
        // A run folder with a cache of its own keeps using it.
        std::fs::create_dir_all(run.join(CACHE_DIR)).unwrap();
        assert_eq!(for_run(&scene, &run), run.join(CACHE_DIR));
        std::fs::remove_dir_all(run.join(CACHE_DIR)).unwrap();
        // A capture that cannot be written: the run's own.
        use std::os::unix::fs::PermissionsExt;
        std::fs::remove_dir_all(scene.join(CACHE_DIR)).unwrap();
        std::fs::set_permissions(&scene, std::fs::Permissions::from_mode(0o555)).unwrap();
        if tempfile::NamedTempFile::new_in(&scene).is_ok() {
            eprintln!("SKIP: a read-only folder is writable here (running as root)");
        } else {
            assert_eq!(for_run(&scene, &run), run.join(CACHE_DIR));
        }
        std::fs::set_permissions(&scene, std::fs::Permissions::from_mode(0o755)).unwrap();
    }

    #[test]
    fn a_cache_folder_that_is_a_link_is_not_written_through() {
        let tmp = tempfile::tempdir().unwrap();
        let elsewhere = tmp.path().join("elsewhere");
        std::fs::create_dir_all(&elsewhere).unwrap();
        let link = tmp.path().join(CACHE_DIR);
        std::os::unix::fs::symlink(&elsewhere, &link).unwrap();
        let k = Keyer::new("net", "net before", &PsfGrid::delta(3, 5)).key(2, 1, &[Vec3::ZERO; 2]);
        let err = put(&link, k, &[Vec3::ONE; 2]).unwrap_err().to_string();
        assert!(
            err.contains("symbolic link") && err.contains(CACHE_DIR),
            "{err}"
        );
        assert_eq!(std::fs::read_dir(&elsewhere).unwrap().count(), 0);
        // A real folder takes the entry.
        let real = tmp.path().join("real");
        put(&real, k, &[Vec3::ONE; 2]).unwrap();
        assert_eq!(get(&real, k, 2).unwrap(), vec![Vec3::ONE; 2]);
    }

    #[test]
    fn an_entry_comes_back_exactly_and_a_damaged_one_not_at_all() {
        let dir = tempfile::tempdir().unwrap();
        let psf = PsfGrid::delta(3, 5);
        let observed = vec![Vec3::new(0.1, 0.2, 0.3); 12];
        let image: Vec<Vec3> = (0..12).map(|i| Vec3::splat(i as f32 / 7.0)).collect();
        let key = |net: &str, psf: &PsfGrid, w, h, obs: &[Vec3]| {
            Keyer::new(net, &format!("{net} before"), psf).key(w, h, obs)
        };
        let k = key("net a", &psf, 4, 3, &observed);
        assert!(get(dir.path(), k, 12).is_none());
        put(dir.path(), k, &image).unwrap();
        assert_eq!(get(dir.path(), k, 12).unwrap(), image);
        // Another restorer, PSF, size or photo is another key.
        assert_ne!(k, key("net b", &psf, 4, 3, &observed));
        assert_ne!(k, key("net a", &PsfGrid::delta(3, 7), 4, 3, &observed));
        assert_ne!(k, key("net a", &psf, 3, 4, &observed));
        let mut other = observed.clone();
        other[5].y += 1e-6;
        assert_ne!(k, key("net a", &psf, 4, 3, &other));
        // The wrong size, a flipped byte or a truncation is a miss, not an image.
        assert!(get(dir.path(), k, 13).is_none());
        let p = cache_entry::path(dir.path(), k.now);
        let good = std::fs::read(&p).unwrap();
        for at in [20, good.len() - 3] {
            let mut bad = good.clone();
            bad[at] ^= 1;
            std::fs::write(&p, &bad).unwrap();
            assert!(
                get(dir.path(), k, 12).is_none(),
                "a flip at byte {at} was read"
            );
        }
        std::fs::write(&p, &good[..good.len() - 1]).unwrap();
        assert!(get(dir.path(), k, 12).is_none());
        // Another view's entry under this view's name (swapped or copied files) is a miss.
        std::fs::write(&p, &good).unwrap();
        let k2 = key("net a", &psf, 4, 3, &other);
        std::fs::copy(&p, cache_entry::path(dir.path(), k2.now)).unwrap();
        assert!(get(dir.path(), k2, 12).is_none());
        assert_eq!(get(dir.path(), k, 12).unwrap(), image);
        // The entry is plain safetensors: its header, read by hand, names the tensor.
        let n = u64::from_le_bytes(good[..8].try_into().unwrap()) as usize;
        let header: serde_json::Value = serde_json::from_slice(&good[8..8 + n]).unwrap();
        assert_eq!(header[TENSOR]["shape"], serde_json::json!([12, 3]));
        assert_eq!(header["__metadata__"]["key"], format!("{:016x}", k.now));
        // An entry named as caches before XXH3 named it is still read, and one named so for
        // another restorer is not.
        std::fs::remove_file(&p).unwrap();
        let then = Key {
            now: k.before,
            before: 0,
        };
        put(dir.path(), then, &image).unwrap();
        assert_eq!(get(dir.path(), k, 12).unwrap(), image);
        assert!(get(dir.path(), key("net b", &psf, 4, 3, &observed), 12).is_none());
        // So is an entry of the layout before safetensors.
        std::fs::remove_file(cache_entry::path(dir.path(), k.before)).unwrap();
        let body: Vec<u8> = image
            .iter()
            .flat_map(|v| v.to_array())
            .flat_map(f32::to_le_bytes)
            .collect();
        let mut keyed = k.before.to_le_bytes().to_vec();
        keyed.extend(&body);
        let mut old = MAGIC.to_vec();
        old.extend(&keyed);
        old.extend(base::hash::fnv1a64(&keyed).to_le_bytes());
        std::fs::write(legacy_path(dir.path(), k.before), &old).unwrap();
        assert_eq!(get(dir.path(), k, 12).unwrap(), image);
    }
}
