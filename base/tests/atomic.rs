//! The shared writer: all or nothing, ordinary permissions.

use std::io::Write;

#[test]
fn a_failed_write_leaves_the_old_file_and_no_temporary() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("out.bin");
    base::write_bytes_atomically(&path, b"first").unwrap();
    let err = base::write_atomically(&path, |w| {
        w.write_all(b"half of it")?;
        Err(std::io::Error::other("disk full"))
    });
    assert!(err.is_err());
    assert_eq!(std::fs::read(&path).unwrap(), b"first");
    let names: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(names, vec![std::ffi::OsString::from("out.bin")]);
}

#[cfg(unix)]
#[test]
fn outputs_get_the_ordinary_mode() {
    use std::os::unix::fs::PermissionsExt;
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("scene.ply");
    base::write_bytes_atomically(&path, b"ply").unwrap();
    let mode = std::fs::metadata(&path).unwrap().permissions().mode() & 0o777;
    // Whatever the umask, a new output is what `File::create` would make beside it.
    let probe = dir.path().join("probe");
    std::fs::File::create(&probe).unwrap();
    let ordinary = std::fs::metadata(&probe).unwrap().permissions().mode() & 0o777;
    assert_eq!(
        mode, ordinary,
        "mode {mode:o}, a plain file gets {ordinary:o}"
    );
}
