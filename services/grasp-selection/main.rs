//! The grasp-selection stage process: see `psgrasp::stages::run_grasp_selection`.
fn main() -> std::process::ExitCode {
    psgrasp::runtime::stage_main(
        psgrasp_ipc::Stage::GraspSelection,
        psgrasp::stages::run_grasp_selection,
    )
}
