//! The application end to end: a real server on 127.0.0.1 port 0 with a
//! SQLite file in a temporary folder, driven by real HTTP and WebSocket
//! clients; the `semdepth` binary run as a user would; bad input of every
//! kind. One binary, so that the suite links once.

#[path = "../common/child_server.rs"]
mod child_server;
#[path = "../common/mod.rs"]
mod common;
#[path = "../common/discs.rs"]
mod discs;
#[path = "../common/fuzz_seeds.rs"]
mod fuzz_seeds;
#[path = "../common/server.rs"]
mod server;

mod api;
mod cli;
mod connections;
mod errors;
mod fuzz_corpus;
mod image_input_errors;
mod live;
mod memory;
mod meta;
mod migration;
mod objects;
mod openapi_sync;
mod process;
mod registry;
mod restart;
mod rust_version;
mod storage_full;
mod ws;
mod ws_fairness;
