//! The next-pick client: a cell controller asks grasp-selection for its next pick.
use anyhow::Result;
use iceoryx2::prelude::*;
use psgrasp_ipc::{NextPickMode, NextPickRequest, NextPickResponse, PipelineNode};
use std::time::{Duration, Instant};

type Service = iceoryx2::service::port_factory::request_response::PortFactory<
    ipc::Service,
    NextPickRequest,
    (),
    NextPickResponse,
    (),
>;

/// Asks grasp-selection for picks (request-response).
pub struct PickClient {
    service: Service,
    client: iceoryx2::port::client::Client<ipc::Service, NextPickRequest, (), NextPickResponse, ()>,
    notifier: iceoryx2::port::notifier::Notifier<ipc::Service>,
}

/// How often a waiting client looks for a response or a (restarted) server.
const POLL: Duration = Duration::from_millis(1);

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
        Ok(Self {
            service,
            client,
            notifier,
        })
    }

    fn servers(&self) -> usize {
        self.service.dynamic_config().number_of_servers()
    }

    /// Requests a pick in `mode` (what became of the previous one). Waits up to `timeout`,
    /// also for a grasp-selection that is restarting: the request is sent (again) once a server
    /// is there. `None` if no answer came in time.
    pub fn next_pick(
        &self,
        mode: NextPickMode,
        timeout: Duration,
    ) -> Result<Option<NextPickResponse>> {
        let deadline = Instant::now() + timeout;
        while Instant::now() < deadline {
            if self.servers() == 0 {
                std::thread::sleep(POLL * 10);
                continue;
            }
            let pending = self
                .client
                .send_copy(NextPickRequest::new(mode))
                .map_err(|e| anyhow::anyhow!("next-pick request: {e:?}"))?;
            let _ = self.notifier.notify();
            // Until answered, or the server went away (then ask its successor).
            while Instant::now() < deadline && self.servers() > 0 {
                if let Some(r) = pending
                    .receive()
                    .map_err(|e| anyhow::anyhow!("next-pick response: {e:?}"))?
                {
                    return Ok(Some(*r.payload()));
                }
                std::thread::sleep(POLL);
            }
        }
        Ok(None)
    }
}
