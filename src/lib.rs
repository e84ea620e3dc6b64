//! semdepth: the height (z) of a tracked object from SEM stereo pairs, as a
//! service and a command line. The algorithms are the crate
//! [`semdepth_core`]; this crate is what runs them for people and scripts.
//!
//! - [`cli`]: the command-line front end used by `main.rs`.
//! - [`service`]: `semdepth serve`, the HTTP/WebSocket API, sessions and
//!   durable storage (async: tokio, axum, SQLite).

pub mod cli;
pub mod service;
