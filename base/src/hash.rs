//! Checksums of our own files and fingerprints of what they were made from: XXH3 (64 bits,
//! `xxhash-rust`). Not a defence against a forger, a check against damage. Files written
//! before XXH3 hold FNV-1a; [`fnv1a64`] is kept to read them.

/// XXH3 (64 bits) of `bytes`: a trailing checksum or a cache key.
pub fn xxh3(bytes: &[u8]) -> u64 {
    xxhash_rust::xxh3::xxh3_64(bytes)
}

/// A fingerprint as file headers write it: `xxh3:` and 16 hex digits, so that a reader knows
/// which hash made it.
pub fn tagged(bytes: &[u8]) -> String {
    format!("{TAG}{:016x}", xxh3(bytes))
}

const TAG: &str = "xxh3:";

/// Whether `recorded` names `bytes`: a [`tagged`] fingerprint, or the bare 16 hex digits of
/// FNV-1a that files written before XXH3 hold.
pub fn names(recorded: &str, bytes: &[u8]) -> bool {
    match recorded.strip_prefix(TAG) {
        Some(_) => recorded == tagged(bytes),
        None => recorded == format!("{:016x}", fnv1a64(bytes)),
    }
}

/// FNV-1a of `bytes`: the checksum and fingerprint of files written before XXH3, still read.
pub fn fnv1a64(bytes: &[u8]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for &b in bytes {
        h ^= b as u64;
        h = h.wrapping_mul(0x0100_0000_01b3);
    }
    h
}

#[cfg(test)]
mod tests {
    #[test]
    fn fnv1a_matches_the_published_test_vectors() {
        assert_eq!(super::fnv1a64(b""), 0xcbf2_9ce4_8422_2325);
        assert_eq!(super::fnv1a64(b"a"), 0xaf63_dc4c_8601_ec8c);
        assert_eq!(super::fnv1a64(b"foobar"), 0x85944171f73967e8);
    }

    #[test]
    fn xxh3_matches_the_reference_vectors() {
        // XXH3_64bits with seed 0, from the xxHash repository's sanity checks.
        assert_eq!(super::xxh3(b""), 0x2d06_8005_38d3_94c2);
        assert_eq!(super::tagged(b""), "xxh3:2d06800538d394c2");
    }

    #[test]
    fn a_fingerprint_names_its_bytes_in_either_hash() {
        let bytes = b"a PSF grid";
        assert!(super::names(&super::tagged(bytes), bytes));
        assert!(!super::names(&super::tagged(bytes), b"another grid"));
        let legacy = format!("{:016x}", super::fnv1a64(bytes));
        assert!(super::names(&legacy, bytes));
        assert!(!super::names(&legacy, b"another grid"));
        // A legacy hash is not read as XXH3, nor the other way round.
        assert!(!super::names(&format!("xxh3:{legacy}"), bytes));
        assert!(!super::names(&super::tagged(bytes)[5..], bytes));
    }
}
