//! Connections that hold the server without sending a request (issue #21,
//! item 1): a header deadline closes them, and a cap on open connections
//! keeps their number below the file-descriptor limit, so `/healthz` keeps
//! answering once they are gone. Real sockets on 127.0.0.1.

use crate::server;

use std::time::{Duration, Instant};

use crate::server::{get_text, test_config, TestServer};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

/// Reads until the server closes the connection (or it resets it); how long
/// that took, or `None` within `limit`.
async fn closed_within(tcp: &mut TcpStream, limit: Duration) -> Option<Duration> {
    let start = Instant::now();
    let mut buf = [0u8; 1024];
    loop {
        match tokio::time::timeout(limit.saturating_sub(start.elapsed()), tcp.read(&mut buf)).await {
            Ok(Ok(0)) | Ok(Err(_)) => return Some(start.elapsed()),
            Ok(Ok(_)) => continue,
            Err(_) => return None,
        }
    }
}

/// Sends `GET path` (`Connection: close`) on a new connection and reads
/// until the server closes it: what it answered, and whether it closed
/// within 3 s (a busy CI machine took more than 0.8 s to accept and close a
/// connection beyond the cap).
async fn request_beyond_the_cap(server: &TestServer, path: &str) -> (Vec<u8>, bool) {
    let mut tcp = TcpStream::connect(server.addr).await.unwrap();
    let request = format!("GET {path} HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n");
    let _ = tcp.write_all(request.as_bytes()).await;
    let mut answer = Vec::new();
    let closed = tokio::time::timeout(Duration::from_secs(3), async {
        let mut buf = [0u8; 1024];
        loop {
            match tcp.read(&mut buf).await {
                Ok(0) | Err(_) => return,
                Ok(n) => answer.extend_from_slice(&buf[..n]),
            }
        }
    })
    .await;
    (answer, closed.is_ok())
}

/// A client that sends its headers one byte every 300 ms is cut off after
/// the 1-s header deadline, not held for good (before: 4 of 4 such
/// connections were open after 100 s); a prompt client on a fresh
/// connection is served meanwhile.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn slow_headers_are_cut_off_at_the_deadline() {
    let dir = tempfile::tempdir().unwrap();
    let mut config = test_config(&dir.path().join("db.sqlite3"));
    config.header_timeout = Duration::from_secs(1);
    let server = TestServer::start(config).await;
    let mut slow = TcpStream::connect(server.addr).await.unwrap();
    let request =
        b"GET /healthz HTTP/1.1\r\nHost: x\r\nX-Slow: aaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaa\r\n\r\n";
    let started = Instant::now();
    let mut cut_off = None;
    for &byte in request.iter() {
        if slow.write_all(&[byte]).await.is_err() {
            cut_off = Some(started.elapsed());
            break;
        }
        if let Some(after) = closed_within(&mut slow, Duration::from_millis(300)).await {
            cut_off = Some(started.elapsed().max(after));
            break;
        }
    }
    let cut_off = cut_off.expect("the slow client was never cut off");
    assert!(
        cut_off >= Duration::from_millis(900) && cut_off < Duration::from_secs(5),
        "cut off after {cut_off:?} (deadline 1 s)"
    );
    assert!(get_text(&format!("{}/healthz", server.base)).await.contains("ok"));
}

/// Open WebSockets count against the cap: with a cap of 3 and three
/// streams open, a new connection is closed unread; once a stream closes,
/// the server answers again.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn open_websockets_count_against_the_cap() {
    let dir = tempfile::tempdir().unwrap();
    let mut config = test_config(&dir.path().join("db.sqlite3"));
    config.max_connections = 3;
    let server = TestServer::start(config).await;
    let sid = server::new_session(&server.base).await;
    let mut streams = Vec::new();
    for _ in 0..3 {
        // The HTTP clients that waited for readiness and created the
        // session close their pooled connections on their own time; until
        // the server has seen that, they hold slots, and a stream beyond the
        // cap is refused (in CI one was, with HandshakeIncomplete).
        let mut tries = 0;
        let ws = loop {
            match tokio_tungstenite::connect_async(server.stream_url(&sid, "all")).await {
                Ok((ws, _)) => break ws,
                Err(e) if tries < 50 => {
                    tries += 1;
                    eprintln!("stream refused ({e}); retrying");
                    tokio::time::sleep(Duration::from_millis(100)).await;
                }
                Err(e) => panic!("no stream within 5 s: {e}"),
            }
        };
        streams.push(ws);
    }
    // Beyond the cap, the probes are answered and the rest refused (issue
    // #66): a slot of the few kept for them.
    let (answer, closed) = request_beyond_the_cap(&server, "/healthz").await;
    let answer = String::from_utf8_lossy(&answer);
    assert!(answer.starts_with("HTTP/1.1 200") && closed, "{answer:?}");
    let (answer, closed) = request_beyond_the_cap(&server, "/v1/sessions").await;
    let answer = String::from_utf8_lossy(&answer);
    assert!(
        answer.starts_with("HTTP/1.1 503")
            && answer.contains("\"busy\"")
            && answer.contains("--max-connections")
            && closed,
        "a request beyond three open streams: {answer:?}"
    );
    let mut first = streams.remove(0);
    first.close(None).await.unwrap();
    // The server sees the close and lets the stream's slot go.
    let mut served = false;
    for _ in 0..50 {
        if let Ok(Ok(r)) = tokio::time::timeout(
            Duration::from_secs(1),
            reqwest::get(format!("{}/healthz", server.base)),
        )
        .await
        {
            served = r.status() == 200;
            if served {
                break;
            }
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    assert!(served, "the server did not answer after a stream closed");
}

/// With a cap of 4 connections, 4 idle connections fill it and 8 more the
/// slots kept for the probes: a thirteenth is closed at once, unread. Once
/// the header deadline (6 s: a busy machine must not free a slot before the
/// thirteenth arrives) has closed the idle ones, `/healthz` answers again.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn connections_beyond_the_cap_are_closed_and_the_server_recovers() {
    let dir = tempfile::tempdir().unwrap();
    let mut config = test_config(&dir.path().join("db.sqlite3"));
    config.header_timeout = Duration::from_secs(6);
    config.max_connections = 4;
    let server = TestServer::start(config).await;
    let full = 4 + semdepth::service::listener::OPS_RESERVED;
    // Fill the cap and the probes' slots with idle connections the server
    // holds. One refused because an earlier client's connection (the
    // readiness check's) had not closed yet is replaced: on a loaded
    // machine that connection closed later and freed the slot the next was
    // then served in.
    let mut idle: Vec<TcpStream> = Vec::new();
    for _ in 0..20 {
        while idle.len() < full {
            idle.push(TcpStream::connect(server.addr).await.unwrap());
        }
        tokio::time::sleep(Duration::from_millis(300)).await;
        let mut buf = [0u8; 1];
        idle.retain(
            |tcp| matches!(tcp.try_read(&mut buf), Err(e) if e.kind() == std::io::ErrorKind::WouldBlock),
        );
        if idle.len() == full {
            break;
        }
    }
    assert_eq!(
        idle.len(),
        full,
        "the server did not hold {full} idle connections"
    );
    // Closed unread: no answer, and closed well before the idle ones' 6-s
    // deadline could free a slot.
    let (answer, closed) = request_beyond_the_cap(&server, "/healthz").await;
    assert!(
        answer.is_empty(),
        "a connection beyond the cap and the probes' slots was served: {:?}",
        String::from_utf8_lossy(&answer)
    );
    assert!(closed, "a connection beyond the cap was left open for 3 s");
    // The idle ones are cut off at the header deadline; then the server
    // answers again.
    for tcp in &mut idle {
        assert!(
            closed_within(tcp, Duration::from_secs(10)).await.is_some(),
            "an idle connection outlived the header deadline"
        );
    }
    assert!(get_text(&format!("{}/healthz", server.base)).await.contains("ok"));
}

/// Raises this process's soft limit on open files to its hard limit: the
/// test below holds 600 client sockets and the in-process server its own.
fn raise_open_files_limit() {
    let mut limit = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: getrlimit and setrlimit only read and write `limit`.
    unsafe {
        if libc::getrlimit(libc::RLIMIT_NOFILE, &mut limit) == 0 && limit.rlim_cur < limit.rlim_max {
            limit.rlim_cur = limit.rlim_max;
            libc::setrlimit(libc::RLIMIT_NOFILE, &limit);
        }
    }
}

/// Opens `GET path` on a new connection and reads its status line (None:
/// closed without an answer); the connection stays open with the caller.
async fn open_get(server: &TestServer, path: &str) -> (TcpStream, Option<u16>) {
    let mut tcp = TcpStream::connect(server.addr).await.unwrap();
    let request = format!("GET {path} HTTP/1.1\r\nHost: x\r\n\r\n");
    let _ = tcp.write_all(request.as_bytes()).await;
    let mut head = Vec::new();
    let mut buf = [0u8; 512];
    let read = tokio::time::timeout(Duration::from_secs(5), async {
        while !head.windows(2).any(|w| w == b"\r\n") {
            match tcp.read(&mut buf).await {
                Ok(0) | Err(_) => return,
                Ok(n) => head.extend_from_slice(&buf[..n]),
            }
        }
    })
    .await;
    assert!(read.is_ok(), "no status line within 5 s for {path}");
    let status = String::from_utf8_lossy(&head)
        .split(' ')
        .nth(1)
        .and_then(|s| s.parse().ok());
    (tcp, status)
}

/// Issue #66: 600 event streams opened at once, on the default limits. The
/// first `--max-event-streams` (64) are served and stay open; the rest are
/// answered 503 `busy` (or, once the connections beyond them fill the cap,
/// closed unread); and all the while `/healthz` and `/readyz` answer 200
/// within a second, on the slots kept for the probes.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn event_streams_are_capped_and_probes_keep_answering() {
    raise_open_files_limit();
    let dir = tempfile::tempdir().unwrap();
    let config = test_config(&dir.path().join("db.sqlite3"));
    let (cap, streams) = (config.max_event_streams, 600);
    let server = TestServer::start(config).await;
    let sid = server::new_session(&server.base).await;
    let path = format!("/v1/sessions/{sid}/events");
    let mut held = Vec::new();
    let (mut served, mut busy, mut unanswered) = (0, 0, 0);
    for k in 0..streams {
        let (tcp, status) = open_get(&server, &path).await;
        match status {
            Some(200) => served += 1,
            Some(503) => busy += 1,
            None => unanswered += 1,
            Some(other) => panic!("event stream {k}: status {other}"),
        }
        held.push(tcp);
        if k % 100 == 99 {
            for probe in ["/healthz", "/readyz"] {
                let start = Instant::now();
                let (answer, _) = request_beyond_the_cap(&server, probe).await;
                let status = String::from_utf8_lossy(&answer).to_string();
                assert!(
                    status.starts_with("HTTP/1.1 200") && start.elapsed() < Duration::from_secs(1),
                    "{probe} with {} event streams opened: {status:?} after {:?}",
                    k + 1,
                    start.elapsed()
                );
            }
        }
    }
    assert_eq!(
        served, cap,
        "streams served (busy {busy}, unanswered {unanswered})"
    );
    assert_eq!(served + busy + unanswered, streams);
    assert!(busy > 0, "the streams beyond the cap were answered busy");
    drop(held);
}
