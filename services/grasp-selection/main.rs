//! The grasp-selection stage process: see `psgrasp::grasp_selection`.
fn main() -> std::process::ExitCode {
    psgrasp::stage::stage_main(
        psgrasp_ipc::Stage::GraspSelection,
        psgrasp::grasp_selection::run,
    )
}
