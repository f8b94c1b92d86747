//! The HTTP/JSON endpoint for cell controllers that speak only TCP/HTTP (PLCs, robot
//! controllers, scripts): next pick, pick results, the latest frames' outcomes, health and
//! Prometheus metrics, on localhost by default. `[http]` in the pipeline configuration turns it on
//! in `psgrasp up`; `psgrasp http` serves a pipeline started elsewhere.
//!
//! | method | path | answer |
//! |---|---|---|
//! | GET | `/v1/pick?wait_ms=N` | the next pick (`200`), or `503` with the reason after `N` ms |
//! | POST | `/v1/pick/result?wait_ms=N` | body `{"result": "success" \| "failure"}`; answers the next pick as above |
//! | GET | `/v1/frames/latest` | the latest frame's outcome: its picks or its error record |
//! | GET | `/v1/frames/{id}` | the outcome of frame `id` (one of the last 64 seen), else `404` |
//! | GET | `/v1/status` | health, latest frame and outcome counts |
//! | GET | `/v1/health` | `200` if every stage has a live worker, else `503` |
//! | GET | `/metrics` | OpenMetrics text: outcomes, stage latency histograms, worker counters |
//!
//! Requests for picks wait on their own thread (with their own connection to the pipeline), so a
//! long `wait_ms` never holds up health checks or metric scrapes.
use crate::controller::{CellClient, PickAnswer, PickResult};
use crate::metrics::CellMetrics;
use crate::monitor::FrameOutcome;
use crate::pick_json::{pick_json, picks_json};
use anyhow::{Context, Result};
use psgrasp_config::PipelineConfig;
use psgrasp_ipc::{NextPickMode, NextPickStatus, Stage, StatusCode};
use serde_json::{json, Value};
use std::io::Read;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{mpsc, Arc};
use std::thread::JoinHandle;
use std::time::Duration;
use tiny_http::{Header, Method, Request, Response, Server};

/// Largest request body read (a pick result is a few bytes).
const MAX_BODY_BYTES: u64 = 4096;
/// How often the serving threads look for a stop request and new outcomes.
const POLL: Duration = Duration::from_millis(50);

/// A running HTTP endpoint; stops when dropped.
pub struct HttpEndpoint {
    addr: SocketAddr,
    stop: Arc<AtomicBool>,
    server: Arc<Server>,
    threads: Vec<JoinHandle<()>>,
}

impl HttpEndpoint {
    /// Binds `[http] bind:port` and serves the pipeline of `cfg` from two threads.
    pub fn start(cfg: &PipelineConfig) -> Result<Self> {
        let http = &cfg.http;
        let bind = format!("{}:{}", http.bind, http.port);
        let server = Arc::new(
            Server::http(&bind)
                .map_err(|e| anyhow::anyhow!("HTTP endpoint: binding {bind}: {e}"))?,
        );
        let addr = server
            .server_addr()
            .to_ip()
            .context("HTTP endpoint: not bound to an IP address")?;
        let stop = Arc::new(AtomicBool::new(false));
        let max_wait = Duration::from_millis(http.max_wait_ms);
        let (to_picker, picks_queue) = mpsc::channel::<Request>();
        let picker = std::thread::Builder::new()
            .name("http-picks".into())
            .spawn({
                let cfg = cfg.clone();
                let stop = stop.clone();
                move || serve_picks(&cfg, picks_queue, &stop, max_wait)
            })?;
        let front = std::thread::Builder::new().name("http".into()).spawn({
            let cfg = cfg.clone();
            let stop = stop.clone();
            let server = server.clone();
            move || serve_front(&cfg, &server, to_picker, &stop)
        })?;
        tracing::info!("HTTP endpoint on http://{addr}");
        Ok(Self {
            addr,
            stop,
            server,
            threads: vec![picker, front],
        })
    }

    /// The address it listens on (the port the system chose for `port = 0`).
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }
}

impl Drop for HttpEndpoint {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        self.server.unblock();
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
}

fn json_response(code: u16, body: &Value) -> Response<std::io::Cursor<Vec<u8>>> {
    Response::from_string(body.to_string() + "\n")
        .with_status_code(code)
        .with_header(
            Header::from_bytes(&b"Content-Type"[..], &b"application/json"[..])
                .expect("a valid header"),
        )
}

fn respond(request: Request, code: u16, body: &Value) {
    if let Err(e) = request.respond(json_response(code, body)) {
        tracing::debug!("HTTP: the client went away before the answer: {e}");
    }
}

fn error(request: Request, code: u16, message: impl std::fmt::Display) {
    respond(request, code, &json!({ "error": message.to_string() }));
}

/// Splits `/path?query` and reads `wait_ms` from the query (default `default`, at most `max`).
fn path_and_wait(url: &str, default: Duration, max: Duration) -> Result<(&str, Duration), String> {
    let (path, query) = url.split_once('?').unwrap_or((url, ""));
    let mut wait = default;
    for pair in query.split('&').filter(|p| !p.is_empty()) {
        match pair.split_once('=') {
            Some(("wait_ms", v)) => {
                let ms: u64 = v
                    .parse()
                    .map_err(|_| format!("wait_ms={v}: not a whole number of milliseconds"))?;
                wait = Duration::from_millis(ms);
            }
            _ => return Err(format!("unknown query parameter {pair:?} (only wait_ms)")),
        }
    }
    if wait > max {
        return Err(format!(
            "wait_ms={} is over the endpoint's max_wait_ms={}",
            wait.as_millis(),
            max.as_millis()
        ));
    }
    Ok((path, wait))
}

/// The front thread: health, status, frames and metrics here; pick requests to the pick thread.
fn serve_front(
    cfg: &PipelineConfig,
    server: &Server,
    to_picker: mpsc::Sender<Request>,
    stop: &AtomicBool,
) {
    let mut client = match CellClient::of(cfg) {
        Ok(c) => c,
        Err(e) => {
            tracing::error!("HTTP endpoint: connecting to the pipeline: {e:#}");
            return;
        }
    };
    let mut metrics = CellMetrics::new();
    while !stop.load(Ordering::SeqCst) {
        if let Err(e) = observe(&mut client, &mut metrics) {
            tracing::warn!("HTTP endpoint: reading the pipeline: {e:#}");
        }
        let request = match server.recv_timeout(POLL) {
            Ok(Some(r)) => r,
            Ok(None) => continue,
            Err(e) => {
                tracing::warn!("HTTP endpoint: {e}");
                continue;
            }
        };
        let path = request.url().split('?').next().unwrap_or("").to_owned();
        if path.starts_with("/v1/pick") {
            if let Err(mpsc::SendError(r)) = to_picker.send(request) {
                error(r, 503, "the pick thread has stopped");
            }
            continue;
        }
        if request.method() != &Method::Get {
            error(request, 405, format!("{path} answers GET only"));
            continue;
        }
        if let Err(e) = observe(&mut client, &mut metrics) {
            error(request, 500, format!("reading the pipeline: {e:#}"));
            continue;
        }
        match path.as_str() {
            "/metrics" => {
                let response = Response::from_string(metrics.encode()).with_header(
                    Header::from_bytes(
                        &b"Content-Type"[..],
                        &b"application/openmetrics-text; version=1.0.0; charset=utf-8"[..],
                    )
                    .expect("a valid header"),
                );
                if let Err(e) = request.respond(response) {
                    tracing::debug!("HTTP: {e}");
                }
            }
            "/v1/health" | "/v1/status" => match client.status() {
                Ok(status) => {
                    let code = if path == "/v1/health" && !status.healthy {
                        503
                    } else {
                        200
                    };
                    respond(request, code, &json!(status));
                }
                Err(e) => error(request, 500, format!("{e:#}")),
            },
            "/v1/frames/latest" => match client.latest() {
                Ok(Some(o)) => respond(request, 200, &outcome_json(o)),
                Ok(None) => error(
                    request,
                    404,
                    "no frame has ended since the endpoint started",
                ),
                Err(e) => error(request, 500, format!("{e:#}")),
            },
            p if p.starts_with("/v1/frames/") => {
                let id = &p["/v1/frames/".len()..];
                match id.parse::<u64>() {
                    Err(_) => error(request, 400, format!("{id:?} is not a frame id")),
                    Ok(id) => match client.outcome(id) {
                        Ok(Some(o)) => respond(request, 200, &outcome_json(o)),
                        Ok(None) => error(
                            request,
                            404,
                            format!(
                                "frame {id} is not among the last {} frames seen",
                                crate::controller::RECENT_OUTCOMES
                            ),
                        ),
                        Err(e) => error(request, 500, format!("{e:#}")),
                    },
                }
            }
            _ => error(request, 404, format!("no such endpoint: {path}")),
        }
    }
}

/// Takes in new outcomes and statistics, into the metrics too.
fn observe(client: &mut CellClient, metrics: &mut CellMetrics) -> Result<()> {
    for o in client.poll()? {
        metrics.observe_outcome(&o);
    }
    for (st, up) in client.worker_stats() {
        metrics.observe_stats(st, up);
    }
    Ok(())
}

/// A frame's outcome as JSON: its picks, or its error record.
pub fn outcome_json(o: &FrameOutcome) -> Value {
    let mut v = picks_json(o.frame_id(), &o.picks);
    v["status"] = json!(crate::controller::status_name(o.status()));
    if o.status() != StatusCode::Ok {
        v["error"] = json!({
            "stage": o.error_stage().map(Stage::name),
            "message": o.header.error_text(),
        });
    }
    let h = &o.header;
    use psgrasp_ipc::Stamp::*;
    v["timings_ms"] = json!({
        "fusion": h.span_ms(FusionStart, FusionEnd),
        "inference": h.span_ms(InferenceStart, InferenceEnd),
        "selection": h.span_ms(SelectionStart, SelectionEnd),
        "end_to_end": h.span_ms(IngestPublished, SelectionEnd),
    });
    v
}

/// The pick thread: next-pick requests and results, each waiting up to its `wait_ms`.
fn serve_picks(
    cfg: &PipelineConfig,
    queue: mpsc::Receiver<Request>,
    stop: &AtomicBool,
    max_wait: Duration,
) {
    let mut client = match CellClient::of(cfg) {
        Ok(c) => c,
        Err(e) => {
            tracing::error!("HTTP endpoint: connecting to the pipeline: {e:#}");
            return;
        }
    };
    let default_wait = Duration::from_millis(cfg.http.default_wait_ms);
    while !stop.load(Ordering::SeqCst) {
        let mut request = match queue.recv_timeout(POLL) {
            Ok(r) => r,
            Err(mpsc::RecvTimeoutError::Timeout) => continue,
            Err(mpsc::RecvTimeoutError::Disconnected) => return,
        };
        let parsed = path_and_wait(request.url(), default_wait, max_wait)
            .map(|(path, wait)| (path.to_owned(), wait));
        let (path, wait) = match parsed {
            Ok(p) => p,
            Err(m) => {
                error(request, 400, m);
                continue;
            }
        };
        let method = request.method().clone();
        let mode = match (&method, path.as_str()) {
            (Method::Get, "/v1/pick") => NextPickMode::Current,
            (Method::Post, "/v1/pick/result") => match read_result(&mut request) {
                Ok(PickResult::Success) => NextPickMode::AfterSuccess,
                Ok(PickResult::Failure) => NextPickMode::AfterFailure,
                Err(m) => {
                    error(request, 400, m);
                    continue;
                }
            },
            (_, "/v1/pick") => {
                error(request, 405, "/v1/pick answers GET only");
                continue;
            }
            (_, "/v1/pick/result") => {
                error(request, 405, "/v1/pick/result answers POST only");
                continue;
            }
            _ => {
                error(request, 404, format!("no such endpoint: {path}"));
                continue;
            }
        };
        match client.next_pick(mode, wait) {
            Ok(answer) => {
                let (code, body) = pick_answer_json(&answer);
                respond(request, code, &body);
            }
            Err(e) => error(request, 500, format!("{e:#}")),
        }
    }
}

/// `{"result": "success" | "failure"}` from the request body.
fn read_result(request: &mut Request) -> Result<PickResult, String> {
    let mut body = String::new();
    request
        .as_reader()
        .take(MAX_BODY_BYTES)
        .read_to_string(&mut body)
        .map_err(|e| format!("reading the body: {e}"))?;
    let v: Value = serde_json::from_str(&body).map_err(|e| {
        format!("the body must be JSON {{\"result\": \"success\" | \"failure\"}}: {e}")
    })?;
    match v.get("result").and_then(Value::as_str) {
        Some("success") => Ok(PickResult::Success),
        Some("failure") => Ok(PickResult::Failure),
        _ => Err(format!(
            "\"result\" must be \"success\" or \"failure\", got {}",
            v.get("result").unwrap_or(&Value::Null)
        )),
    }
}

/// The HTTP status and body of a pick answer.
pub fn pick_answer_json(answer: &PickAnswer) -> (u16, Value) {
    match answer {
        PickAnswer::Pick { frame_id, pick } => (
            200,
            json!({ "status": "pick", "pick": pick_json(*frame_id, pick) }),
        ),
        PickAnswer::NoPick(why) => {
            let (status, message) = match why {
                Some(NextPickStatus::NoFrameYet) => {
                    ("no_frame_yet", "no frame has been processed yet")
                }
                Some(NextPickStatus::Exhausted) => (
                    "exhausted",
                    "every pick of the latest frame was handed out; waiting for the next frame",
                ),
                Some(NextPickStatus::AwaitingNewFrame) => (
                    "awaiting_new_frame",
                    "the last pick succeeded; no frame taken since has been processed yet",
                ),
                Some(NextPickStatus::BadRequest) => {
                    ("bad_request", "grasp-selection refused the request")
                }
                Some(NextPickStatus::Pick) | None => (
                    "no_answer",
                    "grasp-selection did not answer: is the pipeline running?",
                ),
            };
            (503, json!({ "status": status, "message": message }))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wait_times_are_read_bounded_and_unknown_parameters_refused() {
        let d = Duration::from_millis(100);
        let max = Duration::from_secs(10);
        assert_eq!(path_and_wait("/v1/pick", d, max).unwrap(), ("/v1/pick", d));
        assert_eq!(
            path_and_wait("/v1/pick?wait_ms=2500", d, max).unwrap(),
            ("/v1/pick", Duration::from_millis(2500))
        );
        assert!(path_and_wait("/v1/pick?wait_ms=-1", d, max)
            .unwrap_err()
            .contains("whole number"));
        assert!(path_and_wait("/v1/pick?wait_ms=20000", d, max)
            .unwrap_err()
            .contains("max_wait_ms"));
        assert!(path_and_wait("/v1/pick?timeout=1", d, max)
            .unwrap_err()
            .contains("unknown query parameter"));
    }
}
