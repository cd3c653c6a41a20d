//! Running the `metasplat` binary from end-to-end tests.

use std::ffi::OsStr;
use std::fmt::Debug;
use std::path::Path;
use std::process::{Command, Output};

pub fn metasplat() -> Command {
    Command::new(env!("CARGO_BIN_EXE_metasplat"))
}

pub fn output<S: AsRef<OsStr>>(args: &[S]) -> Output {
    metasplat().args(args).output().expect("the binary runs")
}

/// Runs the binary, which must succeed; its stdout and stderr.
pub fn ok<S: AsRef<OsStr> + Debug>(args: &[S]) -> String {
    let out = output(args);
    let text =
        String::from_utf8_lossy(&out.stdout).to_string() + &String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "metasplat {args:?} failed:\n{text}");
    text
}

/// Runs the binary, which must fail without panicking; its stderr.
pub fn fails<S: AsRef<OsStr> + Debug>(args: &[S]) -> String {
    let out = output(args);
    let text = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(
        !out.status.success(),
        "metasplat {args:?} should have failed"
    );
    assert!(
        !text.contains("panicked"),
        "metasplat {args:?} panicked:\n{text}"
    );
    text
}

pub fn s(p: &Path) -> &str {
    p.to_str().expect("test paths are UTF-8")
}

/// `scene procedural` of `views` views at `width`×`height` into `out`.
pub fn procedural(out: &Path, width: u32, height: u32, views: u32) {
    let (w, h, v) = (width.to_string(), height.to_string(), views.to_string());
    ok(&[
        "scene",
        "procedural",
        "--out",
        s(out),
        "--width",
        &w,
        "--height",
        &h,
        "--views",
        &v,
    ]);
}

/// A small lens (same f-number as the paper's) so simulation takes well under a second.
pub const SMALL_LENS: &[&str] = &[
    "--grid",
    "3",
    "--size",
    "21",
    "--aperture-um",
    "100",
    "--focal-um",
    "200",
    "--fft-size",
    "700",
    "--max-field-deg",
    "10",
];

/// `psf simulate` of the small lens ([`SMALL_LENS`]) into `out`.
pub fn small_psf(out: &Path) {
    let mut args = vec!["psf", "simulate", "--out", s(out)];
    args.extend_from_slice(SMALL_LENS);
    ok(&args);
}

/// `train` in plain mode for `iters` steps on `scene` at its own size into `out`, then
/// `extra`: the arguments most end-to-end runs start from.
pub fn plain_train<'a>(
    scene: &'a Path,
    out: &'a Path,
    iters: &'a str,
    extra: &[&'a str],
) -> Vec<&'a str> {
    let mut args = vec![
        "train",
        "--scene",
        s(scene),
        "--out",
        s(out),
        "--mode",
        "plain",
        "--iters",
        iters,
        "--downsample",
        "1",
    ];
    args.extend_from_slice(extra);
    args
}

/// [`plain_train`] with no spiral frames, on the CPU: a run whose outputs a test reads.
pub fn quick_train<'a>(
    scene: &'a Path,
    out: &'a Path,
    iters: &'a str,
    extra: &[&'a str],
) -> Vec<&'a str> {
    let mut args = plain_train(scene, out, iters, &["--spiral", "0", "--device", "cpu"]);
    args.extend_from_slice(extra);
    args
}
