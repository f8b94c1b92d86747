//! The next-pick server (in grasp-selection worker 0): hands out the picks of the latest
//! successful frame one by one to a cell controller.
use anyhow::Result;
use iceoryx2::port::listener::Listener;
use iceoryx2::prelude::*;
use psgrasp_ipc::{
    FrameSubscriber, NextPickMode, NextPickRequest, NextPickResponse, NextPickStatus, PickRecord,
    PipelineNode,
};

type Server =
    iceoryx2::port::server::Server<ipc::Service, NextPickRequest, (), NextPickResponse, ()>;

/// The ports the server needs: the request-response server, the listener that wakes it on a
/// request, and a subscriber to the picks of every grasp-selection worker.
pub struct NextPickPorts {
    server: Server,
    requests: Listener<ipc::Service>,
    picks: FrameSubscriber<PickRecord>,
}

impl NextPickPorts {
    /// What wakes the server: a request, or new picks.
    pub fn listeners(&self) -> [&Listener<ipc::Service>; 2] {
        [&self.requests, self.picks.listener()]
    }
}

/// Serves `next-pick` requests from the latest successful pick list.
pub struct NextPickServer<'p> {
    ports: &'p NextPickPorts,
    latest: Option<(u64, Vec<PickRecord>)>,
    cursor: usize,
}

impl<'p> NextPickServer<'p> {
    /// Opens the server's ports on `node`.
    pub fn ports(node: &PipelineNode) -> Result<NextPickPorts> {
        let (service, event) = node.next_pick_service()?;
        let server = service
            .server_builder()
            .create()
            .map_err(|e| anyhow::anyhow!("next-pick server: {e:?}"))?;
        let requests = event
            .listener_builder()
            .create()
            .map_err(|e| anyhow::anyhow!("next-pick listener: {e:?}"))?;
        let picks = node.subscriber::<PickRecord>(&node.names.picks())?;
        Ok(NextPickPorts {
            server,
            requests,
            picks,
        })
    }

    /// A server on `ports` that has seen no picks yet.
    pub fn new(ports: &'p NextPickPorts) -> Self {
        Self {
            ports,
            latest: None,
            cursor: 0,
        }
    }

    /// Takes in new pick lists, then answers every pending request.
    pub fn serve(&mut self) -> Result<()> {
        while let Some(s) = self.ports.picks.receive()? {
            let h = s.user_header();
            if h.is_ok() && self.latest.as_ref().is_none_or(|(id, _)| h.frame_id > *id) {
                self.latest = Some((h.frame_id, s.payload().to_vec()));
                self.cursor = 0;
            }
        }
        while let Some(active) = self
            .ports
            .server
            .receive()
            .map_err(|e| anyhow::anyhow!("next-pick receive: {e:?}"))?
        {
            let response = self.answer(active.payload().mode());
            active
                .send_copy(response)
                .map_err(|e| anyhow::anyhow!("next-pick respond: {e:?}"))?;
        }
        Ok(())
    }

    fn answer(&mut self, mode: Option<NextPickMode>) -> NextPickResponse {
        let Some((frame_id, picks)) = &self.latest else {
            return NextPickResponse::without_pick(NextPickStatus::NoFrameYet, 0);
        };
        match mode {
            None => return NextPickResponse::without_pick(NextPickStatus::BadRequest, *frame_id),
            Some(NextPickMode::AfterFailure) => self.cursor += 1,
            Some(NextPickMode::Current) => {}
        }
        match picks.get(self.cursor) {
            Some(p) => NextPickResponse::with_pick(*frame_id, *p),
            None => NextPickResponse::without_pick(NextPickStatus::Exhausted, *frame_id),
        }
    }
}
