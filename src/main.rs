//! metasplat: clean Gaussian-splat scenes from metalens-aberrated photos.

// What the commands print goes through these, which shadow the standard macros in every
// module below: output that cannot be written (a pipe whose reader has gone, `| head`; a full
// device) is dropped instead of panicking, so the work and its files still complete.
macro_rules! println {
    () => {
        $crate::write_out(format_args!("\n"))
    };
    ($($arg:tt)*) => {
        $crate::write_out(format_args!("{}\n", format_args!($($arg)*)))
    };
}
macro_rules! print {
    ($($arg:tt)*) => {
        $crate::write_out(format_args!($($arg)*))
    };
}
macro_rules! eprintln {
    () => {
        $crate::write_err(format_args!("\n"))
    };
    ($($arg:tt)*) => {
        $crate::write_err(format_args!("{}\n", format_args!($($arg)*)))
    };
}

mod cli;

/// Writes to standard output, dropping what cannot be written (see the macros above).
fn write_out(args: std::fmt::Arguments) {
    use std::io::Write;
    let _ = std::io::stdout().lock().write_fmt(args);
}

/// Writes to standard error, dropping what cannot be written.
fn write_err(args: std::fmt::Arguments) {
    use std::io::Write;
    let _ = std::io::stderr().lock().write_fmt(args);
}

// The restorer's tensors are large and short-lived: glibc returns each to the kernel (mmap /
// munmap), and the page faults of zeroing them again dominate inference; mimalloc reuses the
// memory (the measurement is in RESULTS.md).
#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

/// mimalloc's `mi_option_purge_delay` (its place in `mi_option_t`, the same in mimalloc 2 and 3).
const MI_OPTION_PURGE_DELAY: libmimalloc_sys::mi_option_t = 15;

/// Keeps freed memory for reuse instead of handing it back to the kernel after a short delay:
/// the restorer frees and makes tensors of tens of MB all the time, and faulting fresh pages
/// in again cost more than the work done in them (`metasplat bench restorer`: three times the
/// system time; restore/README.md). `MIMALLOC_PURGE_DELAY` in the environment still decides.
fn keep_freed_memory() {
    if std::env::var_os("MIMALLOC_PURGE_DELAY").is_none() {
        // SAFETY: sets an integer option; mimalloc reads it at its next purge.
        unsafe { libmimalloc_sys::mi_option_set(MI_OPTION_PURGE_DELAY, -1) };
    }
}

/// The exit status after an interruption, as shells report a process ended by SIGINT.
const INTERRUPTED: u8 = 130;

/// Ctrl-C, SIGTERM and SIGHUP (the terminal closed) ask long work to stop at its next safe
/// point ([`base::interrupt`]); a second one ends the process at once.
fn handle_signals() {
    use signal_hook::consts::{SIGHUP, SIGINT, SIGTERM};
    let flag = base::interrupt::flag();
    for signal in [SIGINT, SIGTERM, SIGHUP] {
        // Registered first, so it sees the flag as the earlier signal left it.
        let _ = signal_hook::flag::register_conditional_shutdown(
            signal,
            INTERRUPTED as i32,
            flag.clone(),
        );
        let _ = signal_hook::flag::register(signal, flag.clone());
    }
}

fn main() -> std::process::ExitCode {
    keep_freed_memory();
    let args = cli::parse();
    if args.stops_when_asked() {
        handle_signals();
    }
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
            if base::interrupt::requested() {
                std::process::ExitCode::from(INTERRUPTED)
            } else {
                std::process::ExitCode::FAILURE
            }
        }
    }
}
