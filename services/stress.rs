//! Load tools: push frames through a live pipeline and report throughput, latency percentiles,
//! drops and errors; and compare the shared-memory transport with a copying Unix socket.
use crate::monitor::FrameOutcome;
use crate::run::RunReport;
use anyhow::Result;
use psgrasp_ipc::{ChannelConfig, FrameHeader, PipelineNode, Stamp, StatusCode};
use std::io::{Read, Write};
use std::time::Duration;

/// Percentile (nearest rank) of sorted values.
pub fn percentile(sorted: &[f64], p: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let rank = ((p / 100.0) * sorted.len() as f64).ceil().max(1.0) as usize;
    sorted[rank.min(sorted.len()) - 1]
}

fn stage_spans(h: &FrameHeader) -> [(&'static str, f64); 5] {
    [
        (
            "grid-fusion",
            h.span_ms(Stamp::FusionStart, Stamp::FusionEnd),
        ),
        (
            "inference",
            h.span_ms(Stamp::InferenceStart, Stamp::InferenceEnd),
        ),
        (
            "grasp-selection",
            h.span_ms(Stamp::SelectionStart, Stamp::SelectionEnd),
        ),
        ("transport+queue", {
            let total = h.span_ms(Stamp::IngestPublished, Stamp::SelectionEnd);
            let work = h.span_ms(Stamp::FusionStart, Stamp::FusionEnd)
                + h.span_ms(Stamp::InferenceStart, Stamp::InferenceEnd)
                + h.span_ms(Stamp::SelectionStart, Stamp::SelectionEnd);
            (total - work).max(0.0)
        }),
        (
            "end-to-end",
            h.span_ms(Stamp::IngestPublished, Stamp::SelectionEnd),
        ),
    ]
}

/// Prints the stress report as Markdown tables.
pub fn print_report(report: &RunReport) {
    let ok: Vec<&FrameOutcome> = report
        .outcomes
        .values()
        .filter(|o| o.status() == StatusCode::Ok)
        .collect();
    let sent = report.sent();
    println!(
        "\n## Pipeline run{}\n",
        if report.interrupted {
            " (interrupted)"
        } else {
            ""
        }
    );
    println!("| frames sent | outcomes | ok | error records | unaccounted | second outcomes | restarts | wall (s) | throughput (frames/s) |");
    println!("|---|---|---|---|---|---|---|---|---|");
    println!(
        "| {sent} | {} | {} | {} | {} | {} | {} | {:.2} | {:.2} |",
        report.outcomes.len(),
        ok.len(),
        report.outcomes.len() - ok.len(),
        report.unaccounted().len(),
        report.second_outcomes,
        report.restarts,
        report.wall.as_secs_f64(),
        report.outcomes.len() as f64 / report.wall.as_secs_f64().max(1e-9)
    );
    println!("\nOutcomes by status: {:?}", report.by_status());
    if !report.kills.is_empty() {
        print_kills(report);
    }
    println!("\n| span (ms) | p50 | p90 | p99 | max |\n|---|---|---|---|---|");
    let names = [
        "grid-fusion",
        "inference",
        "grasp-selection",
        "transport+queue",
        "end-to-end",
    ];
    for (i, name) in names.iter().enumerate() {
        let mut v: Vec<f64> = ok.iter().map(|o| stage_spans(&o.header)[i].1).collect();
        v.sort_by(f64::total_cmp);
        println!(
            "| {name} | {:.2} | {:.2} | {:.2} | {:.2} |",
            percentile(&v, 50.0),
            percentile(&v, 90.0),
            percentile(&v, 99.0),
            v.last().copied().unwrap_or(f64::NAN)
        );
    }
    print_slowest_frames(&ok, SLOWEST_FRAMES_SHOWN);
    let picks: Vec<usize> = ok.iter().map(|o| o.picks.len()).collect();
    if !picks.is_empty() {
        println!(
            "\nPicks per frame: mean {:.1}",
            picks.iter().sum::<usize>() as f64 / picks.len() as f64
        );
    }
}

/// Frames listed in the report's table of the slowest frames.
const SLOWEST_FRAMES_SHOWN: usize = 5;

/// The `count` frames of longest end-to-end time with their spans, to tell where a tail comes
/// from (a stage, queueing, the first frames) and the order they arrived in.
fn print_slowest_frames(ok: &[&FrameOutcome], count: usize) {
    if ok.is_empty() {
        return;
    }
    let mut by_arrival: Vec<&FrameOutcome> = ok.to_vec();
    by_arrival.sort_by_key(|o| o.frame_id());
    let mut slowest: Vec<(usize, &FrameOutcome)> = by_arrival.into_iter().enumerate().collect();
    slowest.sort_by(|a, b| {
        let e2e = |o: &FrameOutcome| stage_spans(&o.header)[4].1;
        e2e(b.1).total_cmp(&e2e(a.1))
    });
    println!("\nSlowest frames (ms):\n\n| frame (n-th of the run) | grid-fusion | inference | grasp-selection | transport+queue | end-to-end | picks |\n|---|---|---|---|---|---|---|");
    for (n, o) in slowest.into_iter().take(count) {
        let s = stage_spans(&o.header);
        println!(
            "| {} ({}) | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} | {} |",
            o.frame_id(),
            n + 1,
            s[0].1,
            s[1].1,
            s[2].1,
            s[3].1,
            s[4].1,
            o.picks.len()
        );
    }
}

/// Latency of one transport for one payload size.
#[derive(Debug, Clone)]
pub struct TransportFigure {
    /// "iceoryx2" or "unix-socket".
    pub transport: &'static str,
    /// Payload bytes.
    pub bytes: usize,
    /// Sorted one-way latencies in microseconds.
    pub latencies_us: Vec<f64>,
}

/// One-way latency (producer writes the payload → consumer holds all of it) for iceoryx2
/// zero-copy publish-subscribe and for a Unix stream socket, same payloads, ping-pong paced,
/// across two threads with separate iceoryx2 nodes.
pub fn compare_transports(sizes: &[usize], iterations: usize) -> Result<Vec<TransportFigure>> {
    let mut out = Vec::new();
    for &bytes in sizes {
        out.push(iceoryx_latency(bytes, iterations)?);
        out.push(unix_socket_latency(bytes, iterations)?);
    }
    Ok(out)
}

fn iceoryx_latency(bytes: usize, iterations: usize) -> Result<TransportFigure> {
    let pipeline = format!("xport-{}-{bytes}", std::process::id());
    let channel = ChannelConfig {
        drop_policy: psgrasp_ipc::DropPolicy::Block,
        ..ChannelConfig::default()
    };
    let n = bytes / 4;
    let src = vec![1.0f32; n];
    let consumer_pipeline = pipeline.clone();
    let (ready_tx, ready_rx) = std::sync::mpsc::channel();
    let (ack_tx, ack_rx) = std::sync::mpsc::channel::<f64>();
    let consumer = std::thread::spawn(move || -> Result<()> {
        let node = PipelineNode::new(
            &format!("{consumer_pipeline}-rx"),
            &consumer_pipeline,
            channel,
        )?;
        let sub = node.subscriber::<f32>(&node.names.grid())?;
        ready_tx.send(())?;
        let mut got = 0;
        while got < iterations {
            sub.wait(Duration::from_millis(100));
            sub.clear_events();
            while let Some(s) = sub.receive()? {
                let now = psgrasp_ipc::now_ns();
                let sent = s.user_header().stamps_ns[0];
                std::hint::black_box(s.payload()[n - 1]);
                ack_tx.send((now - sent) as f64 / 1000.0)?;
                got += 1;
            }
        }
        Ok(())
    });
    let node = PipelineNode::new(&format!("{pipeline}-tx"), &pipeline, channel)?;
    let publisher = node.publisher::<f32>(&node.names.grid(), n)?;
    ready_rx.recv()?;
    while publisher.subscriber_count() == 0 {
        std::thread::sleep(Duration::from_millis(1));
    }
    let mut lat = Vec::with_capacity(iterations);
    for _ in 0..iterations {
        let header = FrameHeader {
            stamps_ns: [psgrasp_ipc::now_ns(), 0, 0, 0, 0, 0, 0, 0],
            ..FrameHeader::default()
        };
        publisher.send_slice(header, &src)?;
        lat.push(ack_rx.recv_timeout(Duration::from_secs(5))?);
    }
    consumer
        .join()
        .map_err(|_| anyhow::anyhow!("consumer thread panicked"))??;
    lat.sort_by(f64::total_cmp);
    Ok(TransportFigure {
        transport: "iceoryx2 (zero-copy, WaitSet wake-up)",
        bytes,
        latencies_us: lat,
    })
}

fn unix_socket_latency(bytes: usize, iterations: usize) -> Result<TransportFigure> {
    let (mut tx, mut rx) = std::os::unix::net::UnixStream::pair()?;
    let (ack_tx, ack_rx) = std::sync::mpsc::channel::<f64>();
    let consumer = std::thread::spawn(move || -> Result<()> {
        let mut buf = vec![0u8; bytes + 8];
        for _ in 0..iterations {
            rx.read_exact(&mut buf)?;
            let sent = u64::from_le_bytes(buf[..8].try_into().expect("8 bytes"));
            ack_tx.send((psgrasp_ipc::now_ns() - sent) as f64 / 1000.0)?;
        }
        Ok(())
    });
    let mut msg = vec![1u8; bytes + 8];
    let mut lat = Vec::with_capacity(iterations);
    for _ in 0..iterations {
        msg[..8].copy_from_slice(&psgrasp_ipc::now_ns().to_le_bytes());
        tx.write_all(&msg)?;
        lat.push(ack_rx.recv_timeout(Duration::from_secs(5))?);
    }
    consumer
        .join()
        .map_err(|_| anyhow::anyhow!("consumer thread panicked"))??;
    lat.sort_by(f64::total_cmp);
    Ok(TransportFigure {
        transport: "Unix socket (copying)",
        bytes,
        latencies_us: lat,
    })
}

/// Prints the transport comparison table.
pub fn print_transport_table(figures: &[TransportFigure]) {
    println!("\n## Transport: producer write → consumer holds payload (µs)\n");
    println!("| transport | payload | p50 | p90 | p99 | throughput bound (msg/s at p50) |\n|---|---|---|---|---|---|");
    for f in figures {
        let p50 = percentile(&f.latencies_us, 50.0);
        println!(
            "| {} | {:.2} MB | {:.1} | {:.1} | {:.1} | {:.0} |",
            f.transport,
            f.bytes as f64 / 1e6,
            p50,
            percentile(&f.latencies_us, 90.0),
            percentile(&f.latencies_us, 99.0),
            1e6 / p50
        );
    }
}

/// Prints the kills of a chaos drill: per stage, how long until the new instance took frames
/// and until picks of a frame admitted after it came back.
fn print_kills(report: &RunReport) {
    let ms = |d: Option<Duration>| {
        d.map_or("–".to_string(), |d| {
            format!("{:.0}", d.as_secs_f64() * 1e3)
        })
    };
    println!("\n## Chaos: kills (SIGKILL) and recovery\n");
    println!("| stage | kills | restarted (ms) p50 / max | picks again (ms) p50 / max | never recovered |");
    println!("|---|---|---|---|---|");
    for stage in psgrasp_ipc::Stage::ALL {
        let kills: Vec<_> = report.kills.iter().filter(|k| k.stage == stage).collect();
        if kills.is_empty() {
            continue;
        }
        let stat = |f: &dyn Fn(&crate::run::Kill) -> Option<Duration>| {
            let mut v: Vec<f64> = kills
                .iter()
                .filter_map(|k| f(k))
                .map(|d| d.as_secs_f64() * 1e3)
                .collect();
            v.sort_by(f64::total_cmp);
            let p50 = (!v.is_empty()).then(|| Duration::from_secs_f64(percentile(&v, 50.0) / 1e3));
            let max = v.last().map(|m| Duration::from_secs_f64(m / 1e3));
            format!("{} / {}", ms(p50), ms(max))
        };
        println!(
            "| {} | {} | {} | {} | {} |",
            stage.name(),
            kills.len(),
            stat(&|k| k.restarted_after),
            stat(&|k| k.recovered_after),
            kills.iter().filter(|k| k.recovered_after.is_none()).count()
        );
    }
}
