//! The camera-ingest stage process: see `psgrasp::camera_ingest`.
fn main() -> std::process::ExitCode {
    psgrasp::stage::stage_main(
        psgrasp_ipc::Stage::CameraIngest,
        psgrasp::camera_ingest::run,
    )
}
