//! Prints a capture's summary: `cargo run --release -p scenes --example scene_info -- DIR [DOWNSAMPLE]`.

use std::path::PathBuf;
use std::process::ExitCode;

use scenes::{OpenOptions, Resolution};

fn main() -> ExitCode {
    let mut args = std::env::args().skip(1);
    let Some(dir) = args.next().map(PathBuf::from) else {
        eprintln!("usage: scene_info DIR [DOWNSAMPLE]");
        return ExitCode::FAILURE;
    };
    let downsample = match args.next().map(|a| a.parse::<u32>()) {
        None => 1,
        Some(Ok(n)) => n,
        Some(Err(e)) => {
            eprintln!("DOWNSAMPLE must be a positive integer: {e}");
            return ExitCode::FAILURE;
        }
    };
    let options = OpenOptions {
        resolution: Resolution::Downsample(downsample),
        ..OpenOptions::default()
    };
    match scenes::open(&dir, &options) {
        Ok(capture) => {
            println!("{}", capture.summary());
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}
