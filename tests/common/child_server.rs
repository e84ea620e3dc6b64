//! `semdepth serve` as a child process on a temporary database and a port
//! the OS picks, for measurements whose memory and CPU must be the
//! server's own (`tests/app/memory.rs`, `benches/service_load.rs`).

#![allow(dead_code)] // each user takes what it needs

use std::io::{BufRead, BufReader};
use std::net::SocketAddr;
use std::process::{Child, Command, Stdio};
use std::sync::{mpsc, Arc, Mutex};
use std::time::{Duration, Instant};

/// A running `semdepth serve`; killed when dropped.
pub struct ChildServer {
    child: Child,
    /// The address it listens on.
    pub addr: SocketAddr,
    log: Arc<Mutex<String>>,
    _dir: tempfile::TempDir,
}

impl ChildServer {
    /// Starts `semdepth serve` with `args` beyond the listen address and the
    /// database; waits until it announces its address.
    pub fn start(args: &[&str]) -> ChildServer {
        let dir = tempfile::tempdir().expect("temporary directory");
        let mut cmd = Command::new(env!("CARGO_BIN_EXE_semdepth"));
        for (key, _) in std::env::vars_os() {
            if key.to_string_lossy().starts_with("SEMDEPTH_") {
                cmd.env_remove(key);
            }
        }
        cmd.arg("serve")
            .args(["--listen", "127.0.0.1:0", "--db"])
            .arg(dir.path().join("db.sqlite3"))
            .args(args)
            // Only warnings, and the line announcing the address.
            .env("SEMDEPTH_LOG", "warn,semdepth=info")
            .env("NO_COLOR", "1")
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::piped());
        let mut child = cmd.spawn().expect("start semdepth serve");
        let stderr = child.stderr.take().expect("piped stderr");
        let log = Arc::new(Mutex::new(String::new()));
        let (addr_tx, addr_rx) = mpsc::channel();
        {
            let log = log.clone();
            // Drains stderr for the whole life of the server (a full pipe
            // would block its logging).
            std::thread::spawn(move || {
                for line in BufReader::new(stderr).lines() {
                    let Ok(line) = line else { break };
                    let line = strip_ansi(&line);
                    if line.contains("semdepth listening") {
                        let addr = line
                            .split_whitespace()
                            .find_map(|w| w.strip_prefix("address="))
                            .and_then(|a| a.parse::<SocketAddr>().ok());
                        let _ = addr_tx.send(addr);
                    }
                    if let Ok(mut log) = log.lock() {
                        log.push_str(&line);
                        log.push('\n');
                    }
                }
            });
        }
        let addr = match addr_rx.recv_timeout(Duration::from_secs(60)) {
            Ok(Some(addr)) => addr,
            other => {
                let _ = child.kill();
                let _ = child.wait();
                std::thread::sleep(Duration::from_millis(100));
                panic!(
                    "semdepth serve did not announce its address ({other:?}); its log:\n{}",
                    log.lock().map(|l| l.clone()).unwrap_or_default()
                );
            }
        };
        ChildServer {
            child,
            addr,
            log,
            _dir: dir,
        }
    }

    /// Its process id.
    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    /// `http://ADDR{path}`.
    pub fn url(&self, path: &str) -> String {
        format!("http://{}{path}", self.addr)
    }

    /// Resident memory now, KiB.
    pub fn rss_kib(&self) -> u64 {
        proc_status_kib(self.pid(), "VmRSS:")
    }

    /// Peak resident memory so far, KiB.
    pub fn peak_rss_kib(&self) -> u64 {
        proc_status_kib(self.pid(), "VmHWM:")
    }

    /// Warnings the server logged (they would skew the figures).
    pub fn warnings(&self) -> Vec<String> {
        self.log
            .lock()
            .map(|l| {
                l.lines()
                    .filter(|l| l.contains("WARN") || l.contains("ERROR"))
                    .map(str::to_string)
                    .collect()
            })
            .unwrap_or_default()
    }

    /// SIGTERM, then up to 10 s for a clean shutdown, then SIGKILL.
    pub fn stop(mut self) {
        let _ = Command::new("kill")
            .args(["-TERM", &self.pid().to_string()])
            .status();
        let deadline = Instant::now() + Duration::from_secs(10);
        while Instant::now() < deadline {
            if let Ok(Some(_)) = self.child.try_wait() {
                return;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        eprintln!("server did not stop within 10 s of SIGTERM; killing it");
    }
}

impl Drop for ChildServer {
    fn drop(&mut self) {
        if let Ok(None) = self.child.try_wait() {
            let _ = self.child.kill();
        }
        let _ = self.child.wait();
    }
}

/// Removes ANSI escape sequences (`ESC [ ... letter`).
fn strip_ansi(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    let mut chars = s.chars();
    while let Some(c) = chars.next() {
        if c == '\u{1b}' {
            if chars.next() == Some('[') {
                for c in chars.by_ref() {
                    if ('@'..='~').contains(&c) {
                        break;
                    }
                }
            }
        } else {
            out.push(c);
        }
    }
    out
}

/// A `VmRSS:`-style field of /proc/<pid>/status, KiB.
pub fn proc_status_kib(pid: u32, field: &str) -> u64 {
    let text = std::fs::read_to_string(format!("/proc/{pid}/status")).expect("read /proc/<pid>/status");
    text.lines()
        .find_map(|l| l.strip_prefix(field))
        .and_then(|rest| rest.split_whitespace().next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("{field} missing in /proc/{pid}/status"))
}
