//! The next-pick client: a cell controller asks grasp-selection for its next pick.
use anyhow::Result;
use iceoryx2::prelude::*;
use psgrasp_ipc::{NextPickMode, NextPickRequest, NextPickResponse, PipelineNode};
use std::time::{Duration, Instant};

/// Asks grasp-selection for picks (request-response).
pub struct PickClient {
    client: iceoryx2::port::client::Client<ipc::Service, NextPickRequest, (), NextPickResponse, ()>,
    notifier: iceoryx2::port::notifier::Notifier<ipc::Service>,
}

impl PickClient {
    /// Connects through an existing node.
    pub fn connect(node: &PipelineNode) -> Result<Self> {
        let (service, event) = node.next_pick_service()?;
        let client = service
            .client_builder()
            .create()
            .map_err(|e| anyhow::anyhow!("next-pick client: {e:?}"))?;
        let notifier = event
            .notifier_builder()
            .create()
            .map_err(|e| anyhow::anyhow!("next-pick notifier: {e:?}"))?;
        Ok(Self { client, notifier })
    }

    /// Requests a pick (`failed_previous` = the last pick failed, advance). Waits up to `timeout`.
    pub fn next_pick(
        &self,
        failed_previous: bool,
        timeout: Duration,
    ) -> Result<Option<NextPickResponse>> {
        let pending = self
            .client
            .send_copy(NextPickRequest::new(if failed_previous {
                NextPickMode::AfterFailure
            } else {
                NextPickMode::Current
            }))
            .map_err(|e| anyhow::anyhow!("next-pick request: {e:?}"))?;
        let _ = self.notifier.notify();
        let deadline = Instant::now() + timeout;
        while Instant::now() < deadline {
            if let Some(r) = pending
                .receive()
                .map_err(|e| anyhow::anyhow!("next-pick response: {e:?}"))?
            {
                return Ok(Some(*r.payload()));
            }
            std::thread::sleep(Duration::from_millis(1));
        }
        Ok(None)
    }
}
