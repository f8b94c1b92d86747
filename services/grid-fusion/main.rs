//! The grid-fusion stage process: see `psgrasp::grid_fusion`.
fn main() -> std::process::ExitCode {
    psgrasp::stage::stage_main(psgrasp_ipc::Stage::GridFusion, psgrasp::grid_fusion::run)
}
