//! Stand-alone front end for trying the commands before they are wired into `psgrasp`:
//! `cargo run --release -p psgrasp-datagen --example datagen_cli -- datagen --scenes 5 --out /tmp/ds`
//! `cargo run --release -p psgrasp-datagen --example datagen_cli -- inspect /tmp/ds/scene_000000.safetensors`
use clap::{Parser, Subcommand};

#[derive(Parser)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Generate a dataset.
    Datagen(psgrasp_datagen::DatagenArgs),
    /// Draw a scene's labels on its depth image.
    Inspect(psgrasp_datagen::InspectArgs),
}

fn main() -> anyhow::Result<()> {
    match Cli::parse().command {
        Command::Datagen(args) => psgrasp_datagen::run_datagen(&args),
        Command::Inspect(args) => psgrasp_datagen::run_inspect(&args),
    }
}
