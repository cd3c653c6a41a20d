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
            // The chain as `{e:#}` prints it, less a cause whose text the message already
            // holds (file errors name their path and their I/O cause in one line).
            let mut message = String::new();
            for cause in e.chain() {
                let text = cause.to_string();
                if message.contains(&text) {
                    continue;
                }
                if !message.is_empty() {
                    message.push_str(": ");
                }
                message.push_str(&text);
            }
            eprintln!("error: {message}");
            std::process::ExitCode::FAILURE
        }
    }
}
