//! The depth service (`semdepth serve`): HTTP and WebSocket API over
//! sessions and calibrations, with durable SQLite storage. Everything async
//! lives under this module; the vision code it calls is pure.

pub mod storage;
