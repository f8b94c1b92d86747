//! iceoryx2 plumbing: a node per process, publishers that write straight into shared memory,
//! subscribers that sleep in a WaitSet, and the drop policy under overload.
use crate::header::FrameHeader;
use crate::{PickRecord, ProgressEvent};
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::port::{BackpressureAction, BackpressureInfo};
use iceoryx2::prelude::*;
use iceoryx2::sample::Sample;
use iceoryx2::service::port_factory::publish_subscribe::PortFactory as PubSubFactory;
use serde::{Deserialize, Serialize};
use std::fmt::Debug;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;

/// Errors of the shared-memory transport.
#[derive(Debug, thiserror::Error)]
pub enum IpcError {
    /// A service, node or port could not be created; the message names which and why.
    #[error("iceoryx2 {what} failed: {detail}")]
    Setup {
        /// What was being created.
        what: String,
        /// iceoryx2's error, formatted.
        detail: String,
    },
    /// Loaning or sending a sample failed.
    #[error("sending on {service} failed: {detail}")]
    Send {
        /// Service name.
        service: String,
        /// iceoryx2's error, formatted.
        detail: String,
    },
    /// Receiving failed.
    #[error("receiving on {service} failed: {detail}")]
    Receive {
        /// Service name.
        service: String,
        /// iceoryx2's error, formatted.
        detail: String,
    },
    /// An invalid service name.
    #[error("invalid service name {0:?}")]
    BadName(String),
}

fn setup<E: Debug>(what: impl Into<String>) -> impl FnOnce(E) -> IpcError {
    let what = what.into();
    move |e| IpcError::Setup {
        what,
        detail: format!("{e:?}"),
    }
}

/// Latched termination request: iceoryx2 reports a SIGTERM/SIGINT to the first check only, so
/// without the latch a second check (a later wait in the same process) would miss it.
static TERMINATION_REQUESTED: AtomicBool = AtomicBool::new(false);

/// True once this process received SIGTERM or SIGINT (seen by any [`PipelineNode::sleep`],
/// [`PipelineNode::wait_until`] or [`note_termination`]).
pub fn termination_requested() -> bool {
    TERMINATION_REQUESTED.load(Ordering::Relaxed)
}

/// Records that a termination request was seen (e.g. by a WaitSet).
pub fn note_termination() {
    TERMINATION_REQUESTED.store(true, Ordering::Relaxed);
}

/// Installs iceoryx2's SIGINT/SIGTERM handlers now and latches a request that already came.
/// iceoryx2 installs them only at its first termination check, not when a node is created: a
/// signal between a node's creation and that first check took the default action and killed the
/// process with its node left behind (a SIGINT during `psgrasp stress` start-up left all five
/// nodes). [`PipelineNode::new`] calls this before it creates the node; calling it again is cheap.
pub fn install_termination_handlers() {
    if iceoryx2_bb_posix::signal::SignalHandler::termination_requested() {
        note_termination();
    }
}

/// Outcomes a subscriber of `picks` can queue: at least twice the most frames in flight, so
/// the ledger's error records for every frame in flight fit next to their picks.
pub const OUTCOME_BUFFER: usize = 256;
/// Progress reports a subscriber of `progress` can queue (a few per frame in flight).
pub const PROGRESS_BUFFER: usize = 1024;

/// What a publisher does when a subscriber's buffer is full.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum DropPolicy {
    /// Discard the new message for that subscriber and count it (the frame later ends as a
    /// `Lost` error record). Keeps latency bounded: the default for live cameras.
    #[default]
    DropNewest,
    /// Wait for the subscriber up to `block_timeout_ms`, then discard and count. Gives
    /// back-pressure to the producer: the choice for replaying recorded data without loss.
    Block,
}

/// Queue settings shared by all pipeline channels. Every process of a pipeline must use the
/// same values: the first process to create a service fixes them.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ChannelConfig {
    /// Messages a subscriber can queue before the drop policy applies.
    pub subscriber_buffer: usize,
    /// Maximum publishers per service (≥ the number of workers of a stage).
    pub max_publishers: usize,
    /// Maximum subscribers per service.
    pub max_subscribers: usize,
    /// Overload behaviour.
    pub drop_policy: DropPolicy,
    /// Longest time a blocking publisher waits for a full subscriber.
    pub block_timeout_ms: u64,
}

impl Default for ChannelConfig {
    fn default() -> Self {
        Self {
            subscriber_buffer: 4,
            max_publishers: 8,
            max_subscribers: 8,
            drop_policy: DropPolicy::DropNewest,
            block_timeout_ms: 2000,
        }
    }
}

/// Service names of one pipeline instance; the pipeline name isolates instances (and tests).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ServiceNames {
    prefix: String,
}

impl ServiceNames {
    /// Names under `psgrasp/<pipeline>/…`.
    pub fn new(pipeline: &str) -> Self {
        Self {
            prefix: format!("psgrasp/{pipeline}"),
        }
    }
    /// Depth frames.
    pub fn depth(&self) -> String {
        format!("{}/depth", self.prefix)
    }
    /// Progress reports for the frame ledger ([`crate::ProgressEvent`]).
    pub fn progress(&self) -> String {
        format!("{}/progress", self.prefix)
    }
    /// Normal grids.
    pub fn grid(&self) -> String {
        format!("{}/grid", self.prefix)
    }
    /// Grasp sets.
    pub fn grasps(&self) -> String {
        format!("{}/grasps", self.prefix)
    }
    /// Selected picks.
    pub fn picks(&self) -> String {
        format!("{}/picks", self.prefix)
    }
    /// Stage statistics.
    pub fn stats(&self) -> String {
        format!("{}/stats", self.prefix)
    }
    /// Next-pick request-response.
    pub fn next_pick(&self) -> String {
        format!("{}/next-pick", self.prefix)
    }
}

fn service_name(name: &str) -> Result<ServiceName, IpcError> {
    ServiceName::new(name).map_err(|_| IpcError::BadName(name.to_string()))
}

/// One process's iceoryx2 node plus the pipeline's names and queue settings.
pub struct PipelineNode {
    node: Node<ipc::Service>,
    /// The pipeline's service names.
    pub names: ServiceNames,
    /// Queue settings.
    pub channel: ChannelConfig,
}

impl PipelineNode {
    /// Creates the node `node_name` for pipeline `pipeline`, cleaning up resources of dead
    /// processes first (a crashed stage must not leave the next one stuck).
    pub fn new(node_name: &str, pipeline: &str, channel: ChannelConfig) -> Result<Self, IpcError> {
        install_termination_handlers();
        cleanup_dead_nodes();
        let name =
            NodeName::new(node_name).map_err(|_| IpcError::BadName(node_name.to_string()))?;
        let node = NodeBuilder::new()
            .name(&name)
            .signal_handling_mode(SignalHandlingMode::HandleTerminationRequests)
            .create::<ipc::Service>()
            .map_err(setup(format!("node {node_name}")))?;
        Ok(Self {
            node,
            names: ServiceNames::new(pipeline),
            channel,
        })
    }

    /// The underlying node.
    pub fn node(&self) -> &Node<ipc::Service> {
        &self.node
    }

    /// Sleeps for `d` (0: only checks); false once a termination signal arrived (now or
    /// earlier in this process).
    pub fn sleep(&self, d: Duration) -> bool {
        if termination_requested() {
            return false;
        }
        if self.node.wait(d).is_err() {
            note_termination();
            return false;
        }
        true
    }

    /// Waits in 10 ms steps until `ready()` holds or `timeout` passes. Returns whether it held,
    /// or `None` when a termination signal arrived meanwhile.
    pub fn wait_until(&self, timeout: Duration, mut ready: impl FnMut() -> bool) -> Option<bool> {
        let deadline = std::time::Instant::now() + timeout;
        loop {
            if ready() {
                return Some(true);
            }
            if std::time::Instant::now() >= deadline {
                return Some(false);
            }
            if !self.sleep(Duration::from_millis(10)) {
                return None;
            }
        }
    }

    /// Publishers currently on the publish-subscribe service `service` of `[T]` messages (opened
    /// with this node's queue settings, without subscribing to it).
    pub fn publisher_count<T: Debug + ZeroCopySend + 'static>(
        &self,
        service: &str,
    ) -> Result<usize, IpcError> {
        let factory = self.pubsub::<T>(service, 0, self.channel.subscriber_buffer)?;
        Ok(factory.dynamic_config().number_of_publishers())
    }

    fn pubsub<T: Debug + ZeroCopySend + 'static>(
        &self,
        service: &str,
        history: usize,
        buffer: usize,
    ) -> Result<PubSubFactory<ipc::Service, [T], FrameHeader>, IpcError> {
        // The progress service has a publisher in every process (and briefly a dead one per
        // restarting worker): room for all.
        let max_publishers = if service == self.names.progress() {
            self.channel.max_publishers * 3 + 2
        } else {
            self.channel.max_publishers
        };
        self.node
            .service_builder(&service_name(service)?)
            .publish_subscribe::<[T]>()
            .user_header::<FrameHeader>()
            .max_publishers(max_publishers)
            .max_subscribers(self.channel.max_subscribers)
            .subscriber_max_buffer_size(buffer)
            .history_size(history)
            .enable_safe_overflow(false)
            .open_or_create()
            .map_err(setup(format!("publish-subscribe service {service}")))
    }

    fn event(
        &self,
        service: &str,
    ) -> Result<iceoryx2::service::port_factory::event::PortFactory<ipc::Service>, IpcError> {
        self.node
            .service_builder(&service_name(service)?)
            .event()
            .max_notifiers(self.channel.max_publishers * 2 + 4)
            .max_listeners(self.channel.max_subscribers * 2 + 4)
            .open_or_create()
            .map_err(setup(format!("event service {service}")))
    }

    /// The next-pick request-response service and the event service of the same name that a
    /// client notifies after each request (the server's listener sits in its WaitSet).
    #[allow(clippy::type_complexity)]
    pub fn next_pick_service(
        &self,
    ) -> Result<
        (
            iceoryx2::service::port_factory::request_response::PortFactory<
                ipc::Service,
                crate::NextPickRequest,
                (),
                crate::NextPickResponse,
                (),
            >,
            iceoryx2::service::port_factory::event::PortFactory<ipc::Service>,
        ),
        IpcError,
    > {
        let name = self.names.next_pick();
        let service = self
            .node
            .service_builder(&service_name(&name)?)
            .request_response::<crate::NextPickRequest, crate::NextPickResponse>()
            .max_clients(16)
            .open_or_create()
            .map_err(setup(format!("request-response service {name}")))?;
        Ok((service, self.event(&name)?))
    }

    /// A publisher of `[T]` slices on `service`, able to loan up to `max_len` elements
    /// (it grows on demand).
    pub fn publisher<T: Debug + ZeroCopySend + Default + Copy + 'static>(
        &self,
        service: &str,
        max_len: usize,
    ) -> Result<FramePublisher<T>, IpcError> {
        self.publisher_with_buffer(service, max_len, self.channel.subscriber_buffer)
    }

    /// Like [`Self::publisher`] with an explicit subscriber buffer (e.g. deep queues for tiny
    /// announcement messages).
    pub fn publisher_with_buffer<T: Debug + ZeroCopySend + Default + Copy + 'static>(
        &self,
        service: &str,
        max_len: usize,
        buffer: usize,
    ) -> Result<FramePublisher<T>, IpcError> {
        let factory = self.pubsub::<T>(service, 0, buffer)?;
        let dropped = Arc::new(AtomicU64::new(0));
        let counter = dropped.clone();
        let policy = self.channel.drop_policy;
        let timeout = Duration::from_millis(self.channel.block_timeout_ms);
        let handler = move |info: &BackpressureInfo| -> BackpressureAction {
            let give_up = match policy {
                DropPolicy::DropNewest => true,
                DropPolicy::Block => info.elapsed_time >= timeout,
            };
            if give_up {
                counter.fetch_add(1, Ordering::Relaxed);
                BackpressureAction::DiscardData
            } else {
                std::thread::sleep(Duration::from_micros(200));
                BackpressureAction::Retry
            }
        };
        let publisher = factory
            .publisher_builder()
            .initial_max_slice_len(max_len.max(1))
            .allocation_strategy(AllocationStrategy::PowerOfTwo)
            .backpressure_strategy(BackpressureStrategy::DiscardData)
            .set_backpressure_handler(handler)
            .create()
            .map_err(setup(format!("publisher on {service}")))?;
        let notifier = self
            .event(service)?
            .notifier_builder()
            .create()
            .map_err(setup(format!("notifier on {service}")))?;
        Ok(FramePublisher {
            service: service.to_string(),
            factory,
            publisher,
            notifier,
            dropped,
        })
    }

    /// A publisher of frame outcomes (picks or error records) on `picks`; its subscribers may
    /// queue [`OUTCOME_BUFFER`] outcomes.
    pub fn outcome_publisher(
        &self,
        max_picks: usize,
    ) -> Result<FramePublisher<PickRecord>, IpcError> {
        self.publisher_with_buffer(&self.names.picks(), max_picks.max(1), OUTCOME_BUFFER)
    }

    /// A subscriber of frame outcomes (picks or error records), [`OUTCOME_BUFFER`] deep.
    pub fn outcome_subscriber(&self) -> Result<FrameSubscriber<PickRecord>, IpcError> {
        self.subscriber_with_buffer(&self.names.picks(), OUTCOME_BUFFER)
    }

    /// A publisher of progress reports for the frame ledger.
    pub fn progress_publisher(&self) -> Result<FramePublisher<ProgressEvent>, IpcError> {
        self.publisher_with_buffer(&self.names.progress(), 1, PROGRESS_BUFFER)
    }

    /// A subscriber of progress reports, [`PROGRESS_BUFFER`] deep.
    pub fn progress_subscriber(&self) -> Result<FrameSubscriber<ProgressEvent>, IpcError> {
        self.subscriber_with_buffer(&self.names.progress(), PROGRESS_BUFFER)
    }

    /// A subscriber of `[T]` slices on `service`, connected immediately.
    pub fn subscriber<T: Debug + ZeroCopySend + 'static>(
        &self,
        service: &str,
    ) -> Result<FrameSubscriber<T>, IpcError> {
        self.subscriber_with_buffer(service, self.channel.subscriber_buffer)
    }

    /// Like [`Self::subscriber`] with an explicit buffer size.
    pub fn subscriber_with_buffer<T: Debug + ZeroCopySend + 'static>(
        &self,
        service: &str,
        buffer: usize,
    ) -> Result<FrameSubscriber<T>, IpcError> {
        let factory = self.pubsub::<T>(service, 0, buffer)?;
        let subscriber = factory
            .subscriber_builder()
            .buffer_size(buffer)
            .create()
            .map_err(setup(format!("subscriber on {service}")))?;
        // A subscriber attaches to the publishers present on its receive calls: do it now.
        let _ = subscriber.has_samples();
        let listener = self
            .event(service)?
            .listener_builder()
            .create()
            .map_err(setup(format!("listener on {service}")))?;
        Ok(FrameSubscriber {
            service: service.to_string(),
            factory,
            subscriber,
            listener,
        })
    }
}

/// Publishes header + slice messages and wakes the subscribers.
pub struct FramePublisher<T: Debug + ZeroCopySend + 'static> {
    service: String,
    factory: PubSubFactory<ipc::Service, [T], FrameHeader>,
    publisher: Publisher<ipc::Service, [T], FrameHeader>,
    notifier: Notifier<ipc::Service>,
    dropped: Arc<AtomicU64>,
}

impl<T: Debug + ZeroCopySend + Default + Copy + 'static> FramePublisher<T> {
    /// Loans `len` elements in shared memory, lets `fill` write them in place, sets the header
    /// (with `element_count = len`) and sends. Returns how many subscribers received it.
    /// If `fill` fails, nothing is sent and its error is returned.
    pub fn send_with<E>(
        &self,
        header: FrameHeader,
        len: usize,
        fill: impl FnOnce(&mut [T]) -> Result<(), E>,
    ) -> Result<Result<usize, E>, IpcError> {
        Ok(self
            .send_inner(header, len, fill, None, |_| {})?
            .map(|(delivered, _)| delivered))
    }

    /// Like [`Self::send_with`], recording `end_stamp` in the header once `fill` has finished
    /// (so the stage's processing time includes the work done inside the loan) and calling
    /// `before_send` with the final header just before the send. Returns the header as sent.
    pub fn send_with_stamp<E>(
        &self,
        header: FrameHeader,
        len: usize,
        fill: impl FnOnce(&mut [T]) -> Result<(), E>,
        end_stamp: Option<crate::Stamp>,
        before_send: impl FnOnce(&FrameHeader),
    ) -> Result<Result<FrameHeader, E>, IpcError> {
        Ok(self
            .send_inner(header, len, fill, end_stamp, before_send)?
            .map(|(_, header)| header))
    }

    fn send_inner<E>(
        &self,
        mut header: FrameHeader,
        len: usize,
        fill: impl FnOnce(&mut [T]) -> Result<(), E>,
        end_stamp: Option<crate::Stamp>,
        before_send: impl FnOnce(&FrameHeader),
    ) -> Result<Result<(usize, FrameHeader), E>, IpcError> {
        let mut sample = self.publisher.loan_slice(len).map_err(|e| IpcError::Send {
            service: self.service.clone(),
            detail: format!("loan of {len} elements: {e:?}"),
        })?;
        if let Err(e) = fill(sample.payload_mut()) {
            return Ok(Err(e));
        }
        header.element_count = len as u32;
        if let Some(stamp) = end_stamp {
            header.stamp(stamp);
        }
        *sample.user_header_mut() = header;
        before_send(&header);
        let subscribers = self.subscriber_count();
        let discarded_before = self.dropped.load(Ordering::Relaxed);
        let delivered = sample.send().map_err(|e| IpcError::Send {
            service: self.service.clone(),
            detail: format!("{e:?}"),
        })?;
        let _ = self.notifier.notify();
        // iceoryx2 discards a delivery without an error when the subscriber's queue is full and
        // the subscriber has not attached to this publisher yet (it does so on its next receive):
        // count and log it like any other drop. Discards by the drop policy were counted by the
        // back-pressure handler already.
        let by_policy = self.dropped.load(Ordering::Relaxed) - discarded_before;
        let missed = subscribers
            .saturating_sub(delivered)
            .saturating_sub(by_policy as usize);
        if missed > 0 {
            self.dropped.fetch_add(missed as u64, Ordering::Relaxed);
            tracing::warn!(
                "{}: frame {} reached {delivered} of {subscribers} subscribers (queue full before \
                 the subscriber attached); counted as dropped",
                self.service,
                header.frame_id
            );
        }
        Ok(Ok((delivered, header)))
    }

    /// Sends a copy of `items`.
    pub fn send_slice(&self, header: FrameHeader, items: &[T]) -> Result<usize, IpcError> {
        self.send_with::<()>(header, items.len(), |buf| {
            buf.copy_from_slice(items);
            Ok(())
        })
        .map(|r| r.unwrap_or(0))
    }

    /// Sends a header-only message (e.g. an error record).
    pub fn send_header(&self, header: FrameHeader) -> Result<usize, IpcError> {
        self.send_slice(header, &[])
    }

    /// Deliveries discarded under the drop policy so far.
    pub fn dropped(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }

    /// Subscribers currently connected to the service.
    pub fn subscriber_count(&self) -> usize {
        self.factory.dynamic_config().number_of_subscribers()
    }
}

/// Receives header + slice messages; its listener goes into a WaitSet.
pub struct FrameSubscriber<T: Debug + ZeroCopySend + 'static> {
    service: String,
    factory: PubSubFactory<ipc::Service, [T], FrameHeader>,
    subscriber: Subscriber<ipc::Service, [T], FrameHeader>,
    listener: Listener<ipc::Service>,
}

impl<T: Debug + ZeroCopySend + 'static> FrameSubscriber<T> {
    /// The next queued message, if any. The sample borrows shared memory: no copy.
    pub fn receive(&self) -> Result<Option<Sample<ipc::Service, [T], FrameHeader>>, IpcError> {
        self.subscriber.receive().map_err(|e| IpcError::Receive {
            service: self.service.clone(),
            detail: format!("{e:?}"),
        })
    }

    /// Publishers currently on the service.
    pub fn publisher_count(&self) -> usize {
        self.factory.dynamic_config().number_of_publishers()
    }

    /// Attaches to every publisher present now. iceoryx2 attaches a subscriber on its receive
    /// calls; until then a publisher that fills this subscriber's queue discards further
    /// deliveries, so stages attach before they announce themselves ready (see
    /// [`PipelineNode::wait_until`]).
    pub fn attach(&self) {
        let _ = self.subscriber.has_samples();
    }

    /// Clears pending wake-up events (call before draining with [`Self::receive`]).
    pub fn clear_events(&self) {
        let _ = self.listener.try_wait(|_| {});
    }

    /// Blocks up to `timeout` for a wake-up (for simple loops outside a WaitSet).
    pub fn wait(&self, timeout: Duration) {
        let _ = self.listener.timed_wait(|_| {}, timeout);
    }

    /// The listener to attach to a WaitSet.
    pub fn listener(&self) -> &Listener<ipc::Service> {
        &self.listener
    }
}

/// A subscriber seen only as an input that must attach to its publishers (see
/// [`FrameSubscriber::attach`]); lets a stage wait on inputs of different payload types.
pub trait InputPort {
    /// The service name.
    fn service(&self) -> &str;
    /// Publishers currently on the service.
    fn publisher_count(&self) -> usize;
    /// Attaches to every publisher present now.
    fn attach(&self);
}

impl<T: Debug + ZeroCopySend + 'static> InputPort for FrameSubscriber<T> {
    fn service(&self) -> &str {
        &self.service
    }
    fn publisher_count(&self) -> usize {
        FrameSubscriber::publisher_count(self)
    }
    fn attach(&self) {
        FrameSubscriber::attach(self)
    }
}

/// Removes shared-memory resources left behind by processes that died without cleaning up.
/// Returns how many dead nodes were cleaned.
pub fn cleanup_dead_nodes() -> usize {
    let mut cleaned = 0;
    let _ = Node::<ipc::Service>::list(Config::global_config(), |state| {
        if let NodeState::<ipc::Service>::Dead(view) = state {
            if view.try_remove_stale_resources().is_ok() {
                cleaned += 1;
            }
        }
        CallbackProgression::Continue
    });
    cleaned
}
