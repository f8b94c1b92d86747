//! The C ABI of psgrasp: what a C or C++ cell controller links (`libpsgrasp_c.so`, header
//! `include/psgrasp.h`) to take picks from a running pipeline — connect by pipeline name, get the
//! next pick (waiting for one up to a timeout), report how a pick went, read the pipeline's
//! status. It is a thin layer over [`psgrasp::controller::CellClient`], the same client the HTTP
//! endpoint uses, so every interface hands out the same pick.
//!
//! Rules of the ABI: every function checks its pointers and never unwinds into C (a panic is
//! caught and reported as `PSGRASP_ERROR`); an error's text is read with
//! [`psgrasp_last_error`]; a client is used from the thread that connected it (iceoryx2 ports are
//! per thread; another thread gets `PSGRASP_WRONG_THREAD`).
#![allow(non_camel_case_types)]
#![deny(unsafe_op_in_unsafe_fn)]
use psgrasp::controller::{CellClient, PickAnswer, PickResult};
use psgrasp_ipc::{NextPickMode, NextPickStatus, PickRecord, StatusCode};
use std::cell::RefCell;
use std::ffi::{c_char, CStr, CString};
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::Path;
use std::thread::ThreadId;
use std::time::Duration;

/// The result of a call.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum psgrasp_result {
    /// Done; for the pick functions: a pick was written.
    PSGRASP_OK = 0,
    /// No frame has been processed yet (within the timeout).
    PSGRASP_NO_FRAME_YET = 1,
    /// Every pick of the latest frame was handed out; no newer frame within the timeout.
    PSGRASP_EXHAUSTED = 2,
    /// A pick was reported successful; no frame taken after that within the timeout.
    PSGRASP_AWAITING_NEW_FRAME = 3,
    /// grasp-selection did not answer within the timeout (pipeline not running?).
    PSGRASP_NO_ANSWER = 4,
    /// Something failed; see [`psgrasp_last_error`].
    PSGRASP_ERROR = -1,
    /// A null pointer, a bad string or an unknown constant was passed.
    PSGRASP_INVALID_ARGUMENT = -2,
    /// The client was used from a thread other than the one that connected it.
    PSGRASP_WRONG_THREAD = -3,
}

/// `psgrasp_report_pick`: the pick failed; the next pick is the next one of the same frame.
pub const PSGRASP_PICK_FAILED: i32 = 0;
/// `psgrasp_report_pick`: the object was picked; the next pick comes from a newer frame.
pub const PSGRASP_PICK_SUCCEEDED: i32 = 1;
/// Length of [`psgrasp_status::latest_error`], NUL included.
pub const PSGRASP_ERROR_TEXT_LEN: usize = 256;

/// A rigid pose: position, unit quaternion (x, y, z, w) and the same as a row-major 4×4
/// homogeneous matrix.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct psgrasp_pose {
    /// Position, metres.
    pub position_m: [f64; 3],
    /// Orientation quaternion x, y, z, w.
    pub orientation_xyzw: [f64; 4],
    /// Row-major homogeneous matrix (`matrix[4 * row + column]`).
    pub matrix: [f64; 16],
}

/// One pick. Gripper frame: origin at the TCP midway between the finger pads at grasp depth,
/// x = closing direction, z = approach. The base-frame poses come from `[robot]` in the
/// pipeline's configuration (hand-eye calibration and the gripper on the flange); without a
/// calibration `base_calibrated` is 0 and the base frame is the workspace frame.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct psgrasp_pick {
    /// The frame the pick belongs to.
    pub frame_id: u64,
    /// Rank in the frame's pick order (0 = best).
    pub rank: u32,
    /// 1 if the base frame comes from a configured hand-eye calibration.
    pub base_calibrated: u32,
    /// Contact-to-contact width, metres.
    pub width_m: f64,
    /// Antipodal quality, 0..1.
    pub quality: f64,
    /// Collision score of the chosen approach, 0..1 (1 = free).
    pub collision_score: f64,
    /// TCP at the grasp, robot base frame.
    pub tcp: psgrasp_pose,
    /// TCP at the pre-grasp pose (backed off along −approach), robot base frame.
    pub pregrasp_tcp: psgrasp_pose,
    /// Robot flange that puts the TCP at the grasp, robot base frame.
    pub flange: psgrasp_pose,
    /// Robot flange at the pre-grasp pose, robot base frame.
    pub pregrasp_flange: psgrasp_pose,
    /// The camera that took the frame, robot base frame.
    pub camera: psgrasp_pose,
    /// TCP at the grasp, workspace frame.
    pub workspace_tcp: psgrasp_pose,
    /// TCP at the pre-grasp pose, workspace frame.
    pub workspace_pregrasp_tcp: psgrasp_pose,
}

/// What selection says about a pick beyond its poses ([`psgrasp_last_pick_details`]): a struct
/// of its own, so that `psgrasp_pick` keeps its layout for clients compiled against it.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct psgrasp_pick_details {
    /// The frame of the pick these details belong to.
    pub frame_id: u64,
    /// Its rank in the frame's pick order.
    pub rank: u32,
    /// 1 if the pick comes from selection's fallback tier (`[selection] fallback`: nothing on the
    /// frame passed the primary score thresholds; a controller may approach more slowly or ask
    /// for a new view first).
    pub fallback: u32,
    /// 1 if `pad_fill` was measured (the surface check's height map came with the frame).
    pub pad_fill_measured: u32,
    /// Always 0 (keeps `pad_fill` 8-byte aligned on every compiler).
    pub reserved: u32,
    /// Share of the region the pads close on that lies under the frame's measured surface, 0..1
    /// (near 1: the pads meet the object over their length); 0 when not measured.
    pub pad_fill: f64,
}

/// The pipeline as the client sees it.
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct psgrasp_status {
    /// 1 if every stage has a worker whose statistics are recent.
    pub healthy: u32,
    /// Stage workers whose statistics are recent.
    pub workers_up: u32,
    /// Stage workers seen since connecting.
    pub workers_seen: u32,
    /// 1 if a frame outcome was seen since connecting (the `latest_*` fields are set).
    pub has_latest: u32,
    /// The latest frame's id.
    pub latest_frame_id: u64,
    /// The latest frame's status code (0 = picks; else an error record's status, as in
    /// `docs/architecture.md`).
    pub latest_status: u32,
    /// Picks of the latest frame.
    pub latest_picks: u32,
    /// Frames that ended with picks since connecting.
    pub frames_ok: u64,
    /// Frames that ended as error records since connecting.
    pub frames_failed: u64,
    /// The latest frame's error (stage: message), NUL-terminated; empty if it has picks.
    pub latest_error: [c_char; PSGRASP_ERROR_TEXT_LEN],
}

/// A connection to one pipeline (opaque).
pub struct psgrasp_client {
    client: CellClient,
    thread: ThreadId,
    /// The pick the last `psgrasp_next_pick` / `psgrasp_report_pick` wrote, with its frame.
    last_pick: Option<(u64, PickRecord)>,
}

thread_local! {
    static LAST_ERROR: RefCell<CString> = RefCell::new(CString::default());
}

fn set_error(message: impl std::fmt::Display) {
    let text = message.to_string().replace('\0', " ");
    LAST_ERROR.with(|e| *e.borrow_mut() = CString::new(text).unwrap_or_default());
}

/// Runs `f`, turning a panic into `on_panic` with the panic's message as the last error.
fn guarded<T>(on_panic: T, f: impl FnOnce() -> T) -> T {
    match catch_unwind(AssertUnwindSafe(f)) {
        Ok(v) => v,
        Err(payload) => {
            let m = payload
                .downcast_ref::<String>()
                .map(String::as_str)
                .or_else(|| payload.downcast_ref::<&str>().copied())
                .unwrap_or("unknown panic");
            set_error(format!("internal error: {m}"));
            on_panic
        }
    }
}

/// # Safety
/// `s` is null or a NUL-terminated string.
unsafe fn text<'a>(s: *const c_char, what: &str) -> Result<&'a str, psgrasp_result> {
    if s.is_null() {
        set_error(format!("{what} is NULL"));
        return Err(psgrasp_result::PSGRASP_INVALID_ARGUMENT);
    }
    // SAFETY: the caller passes a NUL-terminated string.
    unsafe { CStr::from_ptr(s) }.to_str().map_err(|_| {
        set_error(format!("{what} is not UTF-8"));
        psgrasp_result::PSGRASP_INVALID_ARGUMENT
    })
}

fn connected(client: anyhow::Result<CellClient>) -> *mut psgrasp_client {
    match client {
        Ok(client) => Box::into_raw(Box::new(psgrasp_client {
            client,
            thread: std::thread::current().id(),
            last_pick: None,
        })),
        Err(e) => {
            set_error(format!("{e:#}"));
            std::ptr::null_mut()
        }
    }
}

/// Connects to the running pipeline named `pipeline_name` (its `[pipeline] name`), assuming
/// the default channel settings and statistics interval. NULL on failure
/// ([`psgrasp_last_error`]). Connecting succeeds before the pipeline is up; picks come once it is.
///
/// # Safety
/// `pipeline_name` is a NUL-terminated string.
#[no_mangle]
pub unsafe extern "C" fn psgrasp_connect(pipeline_name: *const c_char) -> *mut psgrasp_client {
    guarded(std::ptr::null_mut(), || {
        // SAFETY: forwarded from the caller.
        match unsafe { text(pipeline_name, "pipeline_name") } {
            Ok(name) => connected(CellClient::connect(
                name,
                psgrasp_ipc::ChannelConfig::default(),
                Duration::from_millis(psgrasp_config::PipelineSection::default().stats_interval_ms),
            )),
            Err(_) => std::ptr::null_mut(),
        }
    })
}

/// Connects to the pipeline of a pipeline configuration file (its name, channel settings and
/// statistics interval). NULL on failure ([`psgrasp_last_error`]).
///
/// # Safety
/// `config_path` is a NUL-terminated string.
#[no_mangle]
pub unsafe extern "C" fn psgrasp_connect_config(config_path: *const c_char) -> *mut psgrasp_client {
    guarded(std::ptr::null_mut(), || {
        // SAFETY: forwarded from the caller.
        match unsafe { text(config_path, "config_path") } {
            Ok(path) => connected(
                psgrasp_config::PipelineConfig::load(Path::new(path))
                    .map_err(anyhow::Error::from)
                    .and_then(|cfg| CellClient::of(&cfg)),
            ),
            Err(_) => std::ptr::null_mut(),
        }
    })
}

/// Closes a connection (NULL is ignored). Call it from the thread that connected.
///
/// # Safety
/// `client` is NULL or a pointer from `psgrasp_connect*` not yet disconnected.
#[no_mangle]
pub unsafe extern "C" fn psgrasp_disconnect(client: *mut psgrasp_client) {
    if client.is_null() {
        return;
    }
    guarded((), || {
        // SAFETY: the caller passes a live client it no longer uses.
        drop(unsafe { Box::from_raw(client) });
    })
}

/// # Safety
/// `client` is NULL or a live client.
unsafe fn client_mut<'a>(
    client: *mut psgrasp_client,
) -> Result<&'a mut psgrasp_client, psgrasp_result> {
    // SAFETY: the caller passes NULL or a live client.
    let Some(c) = (unsafe { client.as_mut() }) else {
        set_error("client is NULL");
        return Err(psgrasp_result::PSGRASP_INVALID_ARGUMENT);
    };
    if c.thread != std::thread::current().id() {
        set_error("a psgrasp client is used only from the thread that connected it");
        return Err(psgrasp_result::PSGRASP_WRONG_THREAD);
    }
    Ok(c)
}

/// Runs `call` on a live client of this thread and the caller's output struct, inside
/// [`guarded`]: a NULL or foreign-thread client, or a NULL `out` (named `what` in the error),
/// returns `PSGRASP_INVALID_ARGUMENT` / `PSGRASP_WRONG_THREAD` without calling it.
///
/// # Safety
/// `client` is NULL or a live client; `out` is NULL or writable memory for one `T`.
unsafe fn with_client<T>(
    client: *mut psgrasp_client,
    out: *mut T,
    what: &str,
    call: impl FnOnce(&mut psgrasp_client, &mut T) -> psgrasp_result,
) -> psgrasp_result {
    guarded(psgrasp_result::PSGRASP_ERROR, || {
        // SAFETY: forwarded from the caller.
        let client = match unsafe { client_mut(client) } {
            Ok(c) => c,
            Err(r) => return r,
        };
        // SAFETY: the caller passes NULL or writable memory for one `T`.
        let Some(out) = (unsafe { out.as_mut() }) else {
            set_error(format!("{what} is NULL"));
            return psgrasp_result::PSGRASP_INVALID_ARGUMENT;
        };
        call(client, out)
    })
}

fn pose(position: [f32; 3], xyzw: [f32; 4]) -> psgrasp_pose {
    let p = psgrasp_geometry::pose_from_xyzw(position, xyzw).cast::<f64>();
    let rows = psgrasp_geometry::robot::matrix_rows(&p);
    psgrasp_pose {
        position_m: position.map(f64::from),
        orientation_xyzw: xyzw.map(f64::from),
        matrix: std::array::from_fn(|i| rows[i / 4][i % 4]),
    }
}

/// The C view of pick `p` of frame `frame_id`.
pub fn c_pick(frame_id: u64, p: &PickRecord) -> psgrasp_pick {
    psgrasp_pick {
        frame_id,
        rank: p.rank,
        base_calibrated: p.base_calibrated,
        width_m: p.width.into(),
        quality: p.quality.into(),
        collision_score: p.collision_score.into(),
        tcp: pose(p.base_position, p.base_orientation_xyzw),
        pregrasp_tcp: pose(p.base_pregrasp_position, p.base_orientation_xyzw),
        flange: pose(p.flange_position, p.flange_orientation_xyzw),
        pregrasp_flange: pose(p.flange_pregrasp_position, p.flange_orientation_xyzw),
        camera: pose(p.camera_position, p.camera_orientation_xyzw),
        workspace_tcp: pose(p.position, p.orientation_xyzw),
        workspace_pregrasp_tcp: pose(p.pregrasp_position, p.orientation_xyzw),
    }
}

/// The C view of the details of pick `p` of frame `frame_id`.
pub fn c_pick_details(frame_id: u64, p: &PickRecord) -> psgrasp_pick_details {
    let fill = p.pad_fill();
    psgrasp_pick_details {
        frame_id,
        rank: p.rank,
        fallback: p.fallback,
        pad_fill_measured: fill.is_some().into(),
        reserved: 0,
        pad_fill: fill.map_or(0.0, f64::from),
    }
}

fn answer(
    a: anyhow::Result<PickAnswer>,
    out: &mut psgrasp_pick,
    last_pick: &mut Option<(u64, PickRecord)>,
) -> psgrasp_result {
    use psgrasp_result::*;
    match a {
        Ok(PickAnswer::Pick { frame_id, pick }) => {
            *out = c_pick(frame_id, &pick);
            *last_pick = Some((frame_id, pick));
            PSGRASP_OK
        }
        Ok(PickAnswer::NoPick(why)) => match why {
            Some(NextPickStatus::NoFrameYet) => PSGRASP_NO_FRAME_YET,
            Some(NextPickStatus::Exhausted) => PSGRASP_EXHAUSTED,
            Some(NextPickStatus::AwaitingNewFrame) => PSGRASP_AWAITING_NEW_FRAME,
            Some(NextPickStatus::BadRequest) => {
                set_error("grasp-selection refused the request");
                PSGRASP_ERROR
            }
            Some(NextPickStatus::Pick) | None => {
                set_error("grasp-selection did not answer in time: is the pipeline running?");
                PSGRASP_NO_ANSWER
            }
        },
        Err(e) => {
            set_error(format!("{e:#}"));
            PSGRASP_ERROR
        }
    }
}

/// The pick to try now (the same one again until it is reported), waiting up to `timeout_ms`
/// for one; written to `*pick` on `PSGRASP_OK`.
///
/// # Safety
/// `client` is a live client; `pick` points to writable memory for one `psgrasp_pick`.
#[no_mangle]
pub unsafe extern "C" fn psgrasp_next_pick(
    client: *mut psgrasp_client,
    timeout_ms: u32,
    pick: *mut psgrasp_pick,
) -> psgrasp_result {
    // SAFETY: forwarded from the caller.
    unsafe {
        with_client(client, pick, "pick", |client, out| {
            let wait = Duration::from_millis(timeout_ms.into());
            let a = client.client.next_pick(NextPickMode::Current, wait);
            answer(a, out, &mut client.last_pick)
        })
    }
}

/// Reports how the last pick went (`PSGRASP_PICK_SUCCEEDED` or `PSGRASP_PICK_FAILED`) and
/// gets the next pick, waiting up to `timeout_ms`: after a failure the next pick of the same
/// frame, after a success the best pick of a frame taken after the report.
///
/// # Safety
/// `client` is a live client; `next` points to writable memory for one `psgrasp_pick`.
#[no_mangle]
pub unsafe extern "C" fn psgrasp_report_pick(
    client: *mut psgrasp_client,
    result: i32,
    timeout_ms: u32,
    next: *mut psgrasp_pick,
) -> psgrasp_result {
    // SAFETY: forwarded from the caller.
    unsafe {
        with_client(client, next, "next", |client, out| {
            let result = match result {
                PSGRASP_PICK_SUCCEEDED => PickResult::Success,
                PSGRASP_PICK_FAILED => PickResult::Failure,
                other => {
                    set_error(format!(
                        "result {other}: use PSGRASP_PICK_SUCCEEDED (1) or PSGRASP_PICK_FAILED (0)"
                    ));
                    return psgrasp_result::PSGRASP_INVALID_ARGUMENT;
                }
            };
            let wait = Duration::from_millis(timeout_ms.into());
            let a = client.client.report(result, wait);
            answer(a, out, &mut client.last_pick)
        })
    }
}

/// The details of the pick the last successful `psgrasp_next_pick` or `psgrasp_report_pick` of
/// this client wrote (whether it is a fallback pick, its pad fill), written to `*details`;
/// `PSGRASP_ERROR` before any pick was written.
///
/// # Safety
/// `client` is a live client; `details` points to writable memory for one
/// `psgrasp_pick_details`.
#[no_mangle]
pub unsafe extern "C" fn psgrasp_last_pick_details(
    client: *mut psgrasp_client,
    details: *mut psgrasp_pick_details,
) -> psgrasp_result {
    // SAFETY: forwarded from the caller.
    unsafe {
        with_client(client, details, "details", |client, out| {
            match &client.last_pick {
                Some((frame_id, pick)) => {
                    *out = c_pick_details(*frame_id, pick);
                    psgrasp_result::PSGRASP_OK
                }
                None => {
                    set_error("no pick was written to this client yet");
                    psgrasp_result::PSGRASP_ERROR
                }
            }
        })
    }
}

/// The pipeline's health and latest outcome as this client has seen them.
///
/// # Safety
/// `client` is a live client; `status` points to writable memory for one `psgrasp_status`.
#[no_mangle]
pub unsafe extern "C" fn psgrasp_get_status(
    client: *mut psgrasp_client,
    status: *mut psgrasp_status,
) -> psgrasp_result {
    // SAFETY: forwarded from the caller.
    unsafe {
        with_client(client, status, "status", |client, out| {
            let s = match client.client.status() {
                Ok(s) => s,
                Err(e) => {
                    set_error(format!("{e:#}"));
                    return psgrasp_result::PSGRASP_ERROR;
                }
            };
            let ok_name = psgrasp::controller::status_name(StatusCode::Ok);
            let frames_ok = s.outcomes.get(&ok_name).copied().unwrap_or(0);
            let mut latest_error = [0 as c_char; PSGRASP_ERROR_TEXT_LEN];
            let error_text = s.latest_error.clone().unwrap_or_default();
            for (d, b) in latest_error
                .iter_mut()
                .zip(error_text.bytes().take(PSGRASP_ERROR_TEXT_LEN - 1))
            {
                *d = b as c_char;
            }
            *out = psgrasp_status {
                healthy: s.healthy as u32,
                workers_up: s.workers.iter().filter(|w| w.up).count() as u32,
                workers_seen: s.workers.len() as u32,
                has_latest: s.latest_frame_id.is_some() as u32,
                latest_frame_id: s.latest_frame_id.unwrap_or(0),
                latest_status: s.latest_status_code.unwrap_or(0),
                latest_picks: s.latest_picks as u32,
                frames_ok,
                frames_failed: s.outcomes.values().sum::<u64>() - frames_ok,
                latest_error,
            };
            psgrasp_result::PSGRASP_OK
        })
    }
}

/// The last error of this thread's calls, NUL-terminated; valid until the thread's next call.
#[no_mangle]
pub extern "C" fn psgrasp_last_error() -> *const c_char {
    LAST_ERROR.with(|e| e.borrow().as_ptr())
}

/// This library's version, e.g. "0.1.0 (protocol 2)".
#[no_mangle]
pub extern "C" fn psgrasp_version() -> *const c_char {
    static VERSION: std::sync::OnceLock<CString> = std::sync::OnceLock::new();
    VERSION
        .get_or_init(|| {
            CString::new(format!(
                "{} (protocol {})",
                env!("CARGO_PKG_VERSION"),
                psgrasp_ipc::PROTOCOL_VERSION
            ))
            .expect("no NUL in the version")
        })
        .as_ptr()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bad_arguments_are_refused_with_a_reason() {
        // SAFETY: NULL is allowed and refused.
        let c = unsafe { psgrasp_connect(std::ptr::null()) };
        assert!(c.is_null());
        let msg = unsafe { CStr::from_ptr(psgrasp_last_error()) };
        assert_eq!(msg.to_str().unwrap(), "pipeline_name is NULL");
        let mut pick = psgrasp_pick::default();
        // SAFETY: a NULL client is refused.
        let r = unsafe { psgrasp_next_pick(std::ptr::null_mut(), 0, &mut pick) };
        assert_eq!(r, psgrasp_result::PSGRASP_INVALID_ARGUMENT);
        let missing = CString::new("/nonexistent/psgrasp.toml").unwrap();
        // SAFETY: a valid string.
        let c = unsafe { psgrasp_connect_config(missing.as_ptr()) };
        assert!(c.is_null());
        let msg = unsafe { CStr::from_ptr(psgrasp_last_error()) };
        assert!(msg.to_str().unwrap().contains("/nonexistent/psgrasp.toml"));
    }

    #[test]
    fn a_client_refuses_other_threads_and_unknown_results() {
        let name = CString::new(format!("capi-unit-{}", std::process::id())).unwrap();
        // SAFETY: a valid string.
        let c = unsafe { psgrasp_connect(name.as_ptr()) };
        assert!(!c.is_null(), "{:?}", unsafe {
            CStr::from_ptr(psgrasp_last_error())
        });
        let mut pick = psgrasp_pick::default();
        // SAFETY: a live client and a writable pick.
        let r = unsafe { psgrasp_report_pick(c, 7, 0, &mut pick) };
        assert_eq!(r, psgrasp_result::PSGRASP_INVALID_ARGUMENT);
        // No pipeline of that name: no answer within the timeout.
        let r = unsafe { psgrasp_next_pick(c, 50, &mut pick) };
        assert_eq!(r, psgrasp_result::PSGRASP_NO_ANSWER);
        let addr = c as usize;
        let other = std::thread::spawn(move || {
            let mut pick = psgrasp_pick::default();
            // SAFETY: the client is alive; the call must refuse this thread.
            unsafe { psgrasp_next_pick(addr as *mut psgrasp_client, 0, &mut pick) }
        })
        .join()
        .unwrap();
        assert_eq!(other, psgrasp_result::PSGRASP_WRONG_THREAD);
        // Every call that writes a struct refuses a NULL one and names it.
        let refused = |r: psgrasp_result, what: &str| {
            assert_eq!(r, psgrasp_result::PSGRASP_INVALID_ARGUMENT, "{what}");
            // SAFETY: the thread's last error is a NUL-terminated string.
            let msg = unsafe { CStr::from_ptr(psgrasp_last_error()) };
            assert_eq!(msg.to_str().unwrap(), format!("{what} is NULL"));
        };
        // SAFETY: a live client; NULL outputs are refused before anything is written.
        unsafe {
            refused(psgrasp_next_pick(c, 0, std::ptr::null_mut()), "pick");
            refused(psgrasp_report_pick(c, 1, 0, std::ptr::null_mut()), "next");
            refused(psgrasp_get_status(c, std::ptr::null_mut()), "status");
            refused(
                psgrasp_last_pick_details(c, std::ptr::null_mut()),
                "details",
            );
        }
        let mut status = std::mem::MaybeUninit::<psgrasp_status>::uninit();
        // SAFETY: a live client and writable memory.
        let r = unsafe { psgrasp_get_status(c, status.as_mut_ptr()) };
        assert_eq!(r, psgrasp_result::PSGRASP_OK);
        // SAFETY: written on OK.
        let status = unsafe { status.assume_init() };
        assert_eq!((status.healthy, status.has_latest), (0, 0));
        // SAFETY: the client from psgrasp_connect.
        unsafe { psgrasp_disconnect(c) };
    }

    #[test]
    fn pick_details_carry_the_fallback_flag_and_the_pad_fill() {
        let name = CString::new(format!("capi-details-{}", std::process::id())).unwrap();
        // SAFETY: a valid string.
        let c = unsafe { psgrasp_connect(name.as_ptr()) };
        assert!(!c.is_null());
        let mut details = psgrasp_pick_details::default();
        // SAFETY: a live client and writable memory; no pick was written yet.
        let r = unsafe { psgrasp_last_pick_details(c, &mut details) };
        assert_eq!(r, psgrasp_result::PSGRASP_ERROR);
        // SAFETY: a live client; NULL details are refused.
        let r = unsafe { psgrasp_last_pick_details(c, std::ptr::null_mut()) };
        assert_eq!(r, psgrasp_result::PSGRASP_INVALID_ARGUMENT);
        // SAFETY: the client from psgrasp_connect.
        unsafe { psgrasp_disconnect(c) };

        let plain = PickRecord {
            rank: 3,
            ..PickRecord::default()
        };
        let d = c_pick_details(9, &plain);
        assert_eq!((d.frame_id, d.rank, d.fallback), (9, 3, 0));
        assert_eq!((d.pad_fill_measured, d.pad_fill), (0, 0.0));
        let weak = PickRecord {
            fallback: 1,
            ..plain
        }
        .with_pad_fill(Some(0.625));
        let d = c_pick_details(9, &weak);
        assert_eq!((d.fallback, d.pad_fill_measured, d.pad_fill), (1, 1, 0.625));
    }

    #[test]
    fn the_pick_matrix_matches_its_quaternion() {
        let q = [
            0.0f32,
            0.0,
            std::f32::consts::FRAC_1_SQRT_2,
            std::f32::consts::FRAC_1_SQRT_2,
        ];
        let p = pose([1.0, 2.0, 3.0], q);
        // 90° about z: x → y.
        assert!((p.matrix[4] - 1.0).abs() < 1e-6 && p.matrix[0].abs() < 1e-6);
        assert_eq!([p.matrix[3], p.matrix[7], p.matrix[11]], [1.0, 2.0, 3.0]);
        assert_eq!(&p.matrix[12..], &[0.0, 0.0, 0.0, 1.0]);
    }
}
