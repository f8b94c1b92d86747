//! Delivery over real iceoryx2 shared memory when a subscriber exists before its publisher:
//! what is lost while it has not attached (and that the loss is counted), and that attaching
//! first makes the `block` policy lossless.
use psgrasp_ipc::{ChannelConfig, DropPolicy, FrameHeader, PipelineNode};
use std::sync::mpsc;
use std::time::Duration;

fn channel(buffer: usize) -> ChannelConfig {
    ChannelConfig {
        subscriber_buffer: buffer,
        drop_policy: DropPolicy::Block,
        block_timeout_ms: 10_000,
        ..ChannelConfig::default()
    }
}

fn header(frame_id: u64) -> FrameHeader {
    FrameHeader {
        frame_id,
        ..FrameHeader::default()
    }
}

/// Service names are global: each test gets its own.
fn service(pipeline: &str) -> String {
    format!("psgrasp/{pipeline}/frames")
}

fn pipeline(tag: &str) -> String {
    format!("t-attach-{tag}-{}", std::process::id())
}

#[test]
fn a_full_queue_of_a_subscriber_that_has_not_attached_drops_and_counts() {
    let name = pipeline("late");
    let node = PipelineNode::new(&format!("{name}-sub"), &name, channel(2)).unwrap();
    let sub = node.subscriber::<u32>(&service(&name)).unwrap();
    // The publisher appears after the subscriber, which does not receive (attach) meanwhile.
    let publisher = node.publisher::<u32>(&service(&name), 4).unwrap();
    assert_eq!(publisher.subscriber_count(), 1);
    assert_eq!(sub.publisher_count(), 1);
    let mut delivered = Vec::new();
    for id in 1..=3u64 {
        delivered.push(publisher.send_slice(header(id), &[id as u32]).unwrap());
    }
    // Two fit the queue; the third finds it full and nobody attached: iceoryx2 discards it
    // without an error instead of blocking. We count it.
    assert_eq!(delivered, vec![1, 1, 0]);
    assert_eq!(publisher.dropped(), 1);
    let mut got = Vec::new();
    while let Some(s) = sub.receive().unwrap() {
        got.push(s.user_header().frame_id);
    }
    assert_eq!(got, vec![1, 2]);
}

#[test]
fn an_attached_subscriber_gets_every_message_under_back_pressure() {
    let name = pipeline("attached");
    let node = PipelineNode::new(&format!("{name}-sub"), &name, channel(2)).unwrap();
    let sub = node.subscriber::<u32>(&service(&name)).unwrap();
    let (attached_tx, attached_rx) = mpsc::channel::<()>();
    let producer_name = name.clone();
    let producer = std::thread::spawn(move || {
        let node =
            PipelineNode::new(&format!("{producer_name}-pub"), &producer_name, channel(2)).unwrap();
        let publisher = node.publisher::<u32>(&service(&producer_name), 4).unwrap();
        attached_rx.recv().unwrap();
        for id in 1..=20u64 {
            assert_eq!(publisher.send_slice(header(id), &[id as u32]).unwrap(), 1);
        }
        publisher.dropped()
    });
    // The stages' start-up barrier: wait for the publisher, attach, then let it send.
    let ready = node.wait_until(Duration::from_secs(10), || {
        let present = sub.publisher_count() >= 1;
        sub.attach();
        present
    });
    assert_eq!(ready, Some(true));
    attached_tx.send(()).unwrap();
    let mut got = Vec::new();
    while got.len() < 20 {
        sub.wait(Duration::from_millis(50));
        // A slow consumer: the producer keeps hitting the full queue and has to wait.
        std::thread::sleep(Duration::from_millis(2));
        while let Some(s) = sub.receive().unwrap() {
            assert_eq!(s.payload(), &[s.user_header().frame_id as u32]);
            got.push(s.user_header().frame_id);
        }
    }
    assert_eq!(producer.join().unwrap(), 0);
    assert_eq!(got, (1..=20).collect::<Vec<u64>>());
}

#[test]
fn waiting_for_a_publisher_that_never_comes_times_out() {
    let name = pipeline("none");
    let node = PipelineNode::new(&format!("{name}-sub"), &name, channel(2)).unwrap();
    let sub = node.subscriber::<u32>(&service(&name)).unwrap();
    let ready = node.wait_until(Duration::from_millis(50), || sub.publisher_count() >= 1);
    assert_eq!(ready, Some(false));
    assert_eq!(node.publisher_count::<u32>(&service(&name)).unwrap(), 0);
}

#[test]
fn drop_newest_counts_a_full_queue_once() {
    let name = pipeline("newest");
    let cfg = ChannelConfig {
        drop_policy: DropPolicy::DropNewest,
        ..channel(2)
    };
    let node = PipelineNode::new(&format!("{name}-sub"), &name, cfg).unwrap();
    let sub = node.subscriber::<u32>(&service(&name)).unwrap();
    let publisher = node.publisher::<u32>(&service(&name), 4).unwrap();
    sub.attach();
    let delivered: Vec<usize> = (1..=3u64)
        .map(|id| publisher.send_slice(header(id), &[id as u32]).unwrap())
        .collect();
    assert_eq!(delivered, vec![1, 1, 0]);
    assert_eq!(publisher.dropped(), 1);
}
