//! metasplat: clean Gaussian-splat scenes from metalens-aberrated photos.

mod cli;

use clap::Parser;

// The restorer's tensors are large and short-lived: glibc returns each to the kernel (mmap /
// munmap), and the page faults of zeroing them again took half of inference time (kodim05,
// 500×500, tiny: 14.4 s with glibc, 7.8 s when memory is reused).
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
