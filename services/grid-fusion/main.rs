//! The grid-fusion stage process: see `psgrasp::stages::run_grid_fusion`.
fn main() -> std::process::ExitCode {
    psgrasp::runtime::stage_main(
        psgrasp_ipc::Stage::GridFusion,
        psgrasp::stages::run_grid_fusion,
    )
}
