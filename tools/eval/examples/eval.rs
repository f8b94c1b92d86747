//! `psgrasp eval` without the workspace CLI: `cargo run --release -p psgrasp-eval --example eval -- --help`.
use clap::Parser;

#[derive(Parser)]
#[command(about = "Simulated clutter clearing (the paper's Table I protocol)")]
struct Cli {
    #[command(flatten)]
    args: psgrasp_eval::EvalArgs,
}

fn main() -> anyhow::Result<()> {
    psgrasp_eval::run_eval(&Cli::parse().args)
}
