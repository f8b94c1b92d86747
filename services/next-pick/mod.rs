//! The next-pick request-response service: the server in grasp-selection and the client a cell
//! controller uses, side by side.
mod client;
mod server;

pub use client::PickClient;
pub use server::{state_path, NextPickPorts, NextPickServer, PickCursor};
