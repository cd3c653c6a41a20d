//! Progress display for long steps.

use indicatif::{ProgressBar, ProgressStyle};
use std::time::Instant;

/// A bar for `total` units of work.
pub fn bar(total: u64, what: &str) -> ProgressBar {
    let pb = ProgressBar::new(total);
    pb.set_style(
        ProgressStyle::with_template(
            "{msg:>12} [{bar:40}] {pos}/{len} {elapsed_precise} ETA {eta}",
        )
        .expect("static template")
        .progress_chars("=> "),
    );
    pb.set_message(what.to_string());
    pb
}

/// Reads a splat file behind a bar of the bytes read, and says how long it took.
pub fn read_splats(path: &std::path::Path) -> anyhow::Result<splat::Gaussians> {
    let pb = ProgressBar::new(std::fs::metadata(path).map_or(0, |m| m.len()));
    pb.set_style(
        ProgressStyle::with_template(
            "{msg:>12} [{bar:40}] {bytes}/{total_bytes} {elapsed_precise} ETA {eta}",
        )
        .expect("static template")
        .progress_chars("=> "),
    );
    pb.set_message("reading");
    let start = Instant::now();
    let g = splat::formats::files::read_splats_reporting(path, &|done, total| {
        pb.set_length(total);
        pb.set_position(done);
    });
    pb.finish_and_clear();
    let g = g?;
    println!(
        "Read {} splats from {} in {:.1} s.",
        g.len(),
        path.display(),
        start.elapsed().as_secs_f64()
    );
    Ok(g)
}

/// Runs `f` behind a spinner and returns its result with the seconds it took.
pub fn step<T>(what: &str, f: impl FnOnce() -> T) -> (T, f64) {
    let pb = ProgressBar::new_spinner();
    pb.set_style(
        ProgressStyle::with_template("{spinner} {msg} {elapsed}").expect("static template"),
    );
    pb.set_message(what.to_string());
    pb.enable_steady_tick(std::time::Duration::from_millis(120));
    let start = Instant::now();
    let out = f();
    let secs = start.elapsed().as_secs_f64();
    pb.finish_and_clear();
    (out, secs)
}

/// Prints a line above a bar, or plainly when the bar is hidden (output not a terminal:
/// indicatif then drops `println`).
pub fn say(pb: &ProgressBar, line: String) {
    if pb.is_hidden() {
        println!("{line}");
    } else {
        pb.println(line);
    }
}
