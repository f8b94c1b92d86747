//! The camera-ingest stage process: see `psgrasp::stages::run_camera_ingest`.
fn main() -> std::process::ExitCode {
    psgrasp::runtime::stage_main(
        psgrasp_ipc::Stage::CameraIngest,
        psgrasp::stages::run_camera_ingest,
    )
}
