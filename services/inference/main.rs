//! The inference stage process: see `psgrasp::stages::run_inference`.
fn main() -> std::process::ExitCode {
    psgrasp::runtime::stage_main(
        psgrasp_ipc::Stage::Inference,
        psgrasp::stages::run_inference,
    )
}
