//! metasplat: clean Gaussian-splat scenes from metalens-aberrated photos.

mod cli;

use clap::Parser;

// The restorer's tensors are large and short-lived: glibc returns each to the kernel (mmap /
// munmap), and the page faults of zeroing them again dominate inference; mimalloc reuses the
// memory (the measurement is in RESULTS.md).
#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

fn main() -> std::process::ExitCode {
    let args = cli::Cli::parse();
    match cli::run(args) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}
