//! `metasplat completions SHELL` and `metasplat man`: what a shell and `man` need, made from the
//! same clap definitions as the commands, so they never fall behind them.

use std::io::Write;

use anyhow::Result;
use clap::Args;

#[derive(Args)]
pub struct CompletionsArgs {
    /// The shell to complete for; the script goes to standard output (e.g. `metasplat
    /// completions bash > ~/.local/share/bash-completion/completions/metasplat`).
    #[arg(value_enum)]
    pub shell: clap_complete::Shell,
}

pub fn completions(a: CompletionsArgs) -> Result<()> {
    let mut cmd = super::command();
    // Into memory first: the generator panics on a failed write (a closed pipe).
    let mut script = Vec::new();
    clap_complete::generate(a.shell, &mut cmd, "metasplat", &mut script);
    std::io::stdout().write_all(&script)?;
    Ok(())
}

/// The man page (roff) of the whole tool on standard output (`metasplat man > metasplat.1`).
pub fn man() -> Result<()> {
    let page = clap_mangen::Man::new(super::command());
    let mut out = Vec::new();
    page.render(&mut out)?;
    std::io::stdout().write_all(&out)?;
    Ok(())
}
