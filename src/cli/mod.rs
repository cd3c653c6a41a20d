//! Command-line interface: argument parsing and one module per command.

mod aberrate;
mod bench;
mod deconvolve;
mod demo;
mod experiment;
mod export;
mod progress;
mod psf;
mod render;
mod restorer;
mod scene;
mod shell;
mod train;
mod view;

use clap::{CommandFactory, FromArgMatches, Parser, Subcommand};

#[derive(Parser)]
#[command(
    name = "metasplat",
    version,
    about = "Clean Gaussian-splat scenes from metalens-aberrated photos"
)]
pub struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Simulate or inspect metalens PSF grids.
    #[command(subcommand)]
    Psf(psf::PsfCommand),
    /// Blur an image through a PSF grid and add sensor noise.
    Aberrate(aberrate::AberrateArgs),
    /// Wiener-deconvolve an aberrated image (single K or the 13-filter MAFG bank).
    Deconvolve(deconvolve::DeconvolveArgs),
    /// Inspect scene captures (LLFF, COLMAP).
    #[command(subcommand)]
    Scene(scene::SceneCommand),
    /// Train a splat scene from an (aberrated) capture: aware, restored or plain.
    Train(metasplat::settings::RunRequest),
    /// Render a splat scene (PLY, GLB or SPZ) from a capture's cameras or its spiral path.
    Render(render::RenderArgs),
    /// Open a splat scene in an interactive window; compare it with a capture, follow a run.
    View(view::ViewArgs),
    /// Convert a splat scene between PLY, glTF (GLB with KHR_gaussian_splatting) and SPZ.
    Export(export::ExportArgs),
    /// The paper's comparison (plain, restored, aware) on a capture, with speed against error.
    #[command(subcommand)]
    Experiment(experiment::ExperimentCommand),
    /// Train or evaluate the aberration-correcting transformer.
    #[command(subcommand)]
    Restorer(restorer::RestorerCommand),
    /// Restore an aberrated image with trained weights.
    Restore(restorer::RestoreArgs),
    /// Measure where the time of a training step goes.
    #[command(subcommand)]
    Bench(bench::BenchCommand),
    /// Built-in demo: simulate the default PSF grid, render and aberrate a procedural scene, and
    /// train plain and aberration-aware 3DGS on it.
    Demo(demo::DemoArgs),
    /// Print a completion script for a shell.
    Completions(shell::CompletionsArgs),
    /// Print the man page.
    Man,
}

/// [`metasplat::settings::downsample_for`], its choice said.
pub fn downsample_for(dir: &std::path::Path, given: Option<u32>) -> u32 {
    let (d, said) = metasplat::settings::downsample_for(dir, given);
    if let Some(line) = said {
        println!("{line}");
    }
    d
}

/// Decodes every image of `capture`, nothing kept and a bounded number of pixels at once
/// ([`scenes::Capture::check_images`]): opening a capture reads image headers only, so this
/// is what finds a damaged image before a command makes its output.
pub fn decode_all(capture: &scenes::Capture) -> anyhow::Result<()> {
    use anyhow::Context;
    capture
        .check_images()
        .with_context(|| format!("cannot open the scene {}", capture.root.display()))
}

impl Cli {
    /// Whether the command stops at safe points when asked ([`base::interrupt`]): long work
    /// that stages its output or checkpoints. Others (the viewer, one image) keep Ctrl-C's
    /// usual meaning, an immediate end.
    pub fn stops_when_asked(&self) -> bool {
        matches!(
            self.command,
            Command::Train(_)
                | Command::Render(_)
                | Command::Experiment(_)
                | Command::Demo(_)
                | Command::Scene(scene::SceneCommand::Aberrate(_))
                | Command::Restorer(restorer::RestorerCommand::Train(_))
                | Command::Restore(_)
        )
    }
}

pub fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Psf(c) => psf::run(c),
        Command::Aberrate(a) => aberrate::run(a),
        Command::Deconvolve(a) => deconvolve::run(a),
        Command::Scene(c) => scene::run(c),
        Command::Train(a) => train::run(a),
        Command::Render(a) => render::run(a),
        Command::Bench(c) => bench::run(c),
        Command::View(a) => view::run(a),
        Command::Export(a) => export::run(a),
        Command::Experiment(c) => experiment::run(c),
        Command::Restorer(c) => restorer::run(c),
        Command::Restore(a) => restorer::run_restore(a),
        Command::Demo(a) => demo::run(a),
        Command::Completions(a) => shell::completions(a),
        Command::Man => shell::man(),
    }
}

/// Short flags for the flags most commands share, given wherever a command has the long
/// one and the letter is free; `-s` and `-r` as INRIA's `train.py` uses them (source,
/// resolution).
const SHORT_FLAGS: [(&str, char); 7] = [
    ("scene", 's'),
    ("out", 'o'),
    ("in", 'i'),
    ("mode", 'm'),
    ("iters", 'n'),
    ("downsample", 'r'),
    ("device", 'd'),
];

fn with_short_flags(mut cmd: clap::Command) -> clap::Command {
    for (long, short) in SHORT_FLAGS {
        let taken = cmd.get_arguments().any(|a| a.get_short() == Some(short));
        let id = cmd
            .get_arguments()
            .find(|a| a.get_long() == Some(long))
            .map(|a| a.get_id().to_string());
        if let (Some(id), false) = (id, taken) {
            cmd = cmd.mut_arg(id, |a| a.short(short));
        }
    }
    cmd.mut_subcommands(with_short_flags)
}

/// The whole command line as parsed, completed and documented: the derived commands with
/// their short flags.
pub fn command() -> clap::Command {
    with_short_flags(Cli::command())
}

/// Parses the process's arguments (exiting with clap's message on an error).
pub fn parse() -> Cli {
    let matches = command().get_matches();
    let mut cli = Cli::from_arg_matches(&matches).unwrap_or_else(|e| e.exit());
    // `train` without --downsample trains at the folder the capture has (images_8/ when it
    // has one), as render and view open it, instead of shrinking images/ eight times.
    if let Command::Train(r) = &mut cli.command
        && matches
            .subcommand_matches("train")
            .and_then(|m| m.value_source("downsample"))
            == Some(clap::parser::ValueSource::DefaultValue)
    {
        r.data.downsample = downsample_for(&r.scene, None);
    }
    cli
}

#[cfg(test)]
mod tests {
    use clap::FromArgMatches;

    /// clap's own consistency checks over the whole tree (a letter given twice in one
    /// command among them), and the short flags parse as the long ones.
    #[test]
    fn short_flags_are_unique_and_mean_the_long_ones() {
        super::command().debug_assert();
        let parse = |args: &[&str]| {
            let m = super::command()
                .try_get_matches_from(args)
                .unwrap_or_else(|e| panic!("{args:?}: {e}"));
            let cli = super::Cli::from_arg_matches(&m).unwrap();
            match cli.command {
                super::Command::Train(r) => (
                    r.scene,
                    r.out,
                    r.training.mode,
                    r.training.iters,
                    r.data.downsample,
                    r.device,
                ),
                _ => panic!("not train"),
            }
        };
        let short = parse(&[
            "metasplat",
            "train",
            "-s",
            "cap",
            "-o",
            "run",
            "-m",
            "plain",
            "-n",
            "7",
            "-r",
            "2",
            "-d",
            "cpu",
        ]);
        let long = parse(&[
            "metasplat",
            "train",
            "--scene",
            "cap",
            "--out",
            "run",
            "--mode",
            "plain",
            "--iters",
            "7",
            "--downsample",
            "2",
            "--device",
            "cpu",
        ]);
        assert_eq!(short, long);
        let help = super::command()
            .find_subcommand_mut("train")
            .unwrap()
            .render_help()
            .to_string();
        assert!(help.contains("-s, --scene"), "{help}");
    }

    /// Every flag and argument of every command has help text (`--help` lists nothing bare).
    #[test]
    fn every_flag_says_what_it_is_for() {
        fn walk(cmd: &clap::Command, path: &str, missing: &mut Vec<String>) {
            for a in cmd.get_arguments() {
                let id = a.get_id().as_str();
                if a.get_help().is_none() && !["help", "version"].contains(&id) {
                    missing.push(format!("{path}: {id}"));
                }
            }
            for sub in cmd.get_subcommands() {
                walk(sub, &format!("{path} {}", sub.get_name()), missing);
            }
        }
        let mut missing = Vec::new();
        walk(&super::command(), "metasplat", &mut missing);
        assert!(missing.is_empty(), "flags without help: {missing:#?}");
    }
}
