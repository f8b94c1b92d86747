//! The inference stage process: see `psgrasp::inference`.
fn main() -> std::process::ExitCode {
    psgrasp::stage::stage_main(psgrasp_ipc::Stage::Inference, psgrasp::inference::run)
}
