//! Set-up shared by the live-node tests: a loopback domain, a rendered frame, a client that
//! plays the cameras, a third-party peer process with its line protocol ([`Peer`]), and small
//! helpers (waiting for a condition, FNV-1a hashes, fields of a JSON result). The flows of the
//! third-party DDS tests (`cyclone`, `fastdds`) are in `dds_peer`.

use mode360::frame::RigFrame;
use mode360::geometry::Rig;
use mode360::msgs::image::image_msg_from_rgb;
use mode360::msgs::{Header, Image};
use mode360::node::{create_publisher, sensor_qos, DdsOptions, SpunNode};
use mode360::synth::record::{record_synthetic_bag, RecordOptions};
use mode360::synth::{SynthConfig, SynthRenderer};
use ros2_client::Publisher;
use serde_json::Value;
use std::io::{BufRead, BufReader, Read, Write};
use std::process::{Child, ChildStdin, Command, Stdio};
use std::sync::mpsc::{Receiver, RecvTimeoutError};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// How long to wait for the node to subscribe to the cameras.
const DISCOVERY_TIMEOUT: Duration = Duration::from_secs(10);
const POLL: Duration = Duration::from_millis(20);

/// DDS on loopback only, in `domain_id`.
pub fn loopback(domain_id: u16) -> DdsOptions {
    DdsOptions {
        domain_id,
        loopback_only: true,
    }
}

/// Frame 0 of a street rendered with `seed` at `width` on `rig`.
pub fn render(rig: &Rig, seed: u64, width: usize) -> Result<RigFrame, Box<dyn std::error::Error>> {
    Ok(SynthRenderer::new(SynthConfig {
        seed,
        width,
        ..Default::default()
    })?
    .render_frame(rig, 0))
}

/// A rig bag of `frames` street frames rendered with `seed` at `width` on `rig`, written to
/// `out` (the renderer's defaults otherwise).
pub fn record_street_bag(
    rig: &Rig,
    seed: u64,
    width: usize,
    frames: usize,
    out: &std::path::Path,
) -> Result<(), Box<dyn std::error::Error>> {
    record_synthetic_bag(&RecordOptions {
        rig: rig.clone(),
        config: SynthConfig {
            seed,
            width,
            ..Default::default()
        },
        frames,
        first_frame: 0,
        out: out.to_path_buf(),
        show_progress: false,
    })?;
    Ok(())
}

/// One best-effort image publisher per rig camera on a client node, sending one frame's
/// images again and again under increasing stamps.
pub struct Cameras {
    pubs: Vec<Publisher<Image>>,
    rig: Rig,
    frame: RigFrame,
    stamp_ns: u64,
    step_ns: u64,
}

impl Cameras {
    /// Creates the publishers on `client` and waits (up to 10 s) until the node subscribed
    /// to every one.
    pub fn new(
        client: &mut SpunNode,
        rig: &Rig,
        frame: RigFrame,
        step_ns: u64,
    ) -> Result<Self, Box<dyn std::error::Error>> {
        let pubs = rig
            .cameras
            .iter()
            .map(|c| create_publisher::<Image>(&mut client.node, &c.topic, sensor_qos()))
            .collect::<Result<Vec<_>, _>>()?;
        let t0 = Instant::now();
        while pubs
            .iter()
            .any(|p| p.get_subscription_count(&client.node) == 0)
            && t0.elapsed() < DISCOVERY_TIMEOUT
        {
            std::thread::sleep(POLL);
        }
        Ok(Self {
            pubs,
            rig: rig.clone(),
            stamp_ns: frame.stamp_ns,
            frame,
            step_ns,
        })
    }

    /// Sends the images of cameras `cams` under the next stamp; returns the stamp.
    pub fn send(&mut self, cams: &[usize]) -> Result<u64, String> {
        self.stamp_ns += self.step_ns;
        for &i in cams {
            let msg = image_msg_from_rgb(
                Header::new(self.stamp_ns, &self.rig.cameras[i].frame_id),
                &self.frame.images[i],
            );
            self.pubs[i].publish(msg).map_err(|e| format!("{e:?}"))?;
        }
        Ok(self.stamp_ns)
    }

    /// Sends every camera's image under the next stamp.
    pub fn send_all(&mut self) -> Result<u64, String> {
        let all: Vec<usize> = (0..self.pubs.len()).collect();
        self.send(&all)
    }
}

/// A third-party DDS peer program (`tests/interop/cyclone_peer.py`, the Fast DDS
/// `fastdds_peer`) speaking a line protocol: its stdout lines arrive on a channel, stderr is
/// kept for error messages, and dropping it kills the process.
pub struct Peer {
    name: String,
    child: Child,
    stdin: Option<ChildStdin>,
    lines: Receiver<String>,
    stderr: Arc<Mutex<String>>,
}

impl Peer {
    /// Starts `program` with `args`; `name` is how messages call it.
    pub fn start(
        name: &str,
        program: &str,
        args: &[String],
    ) -> Result<Self, Box<dyn std::error::Error>> {
        let mut child = Command::new(program)
            .args(args)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .map_err(|e| format!("starting {name} ({program}): {e}"))?;
        let stdout = child.stdout.take().ok_or("peer has no stdout")?;
        let mut stderr_pipe = child.stderr.take().ok_or("peer has no stderr")?;
        let (tx, lines) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            for line in BufReader::new(stdout).lines().map_while(Result::ok) {
                if tx.send(line).is_err() {
                    break;
                }
            }
        });
        let stderr = Arc::new(Mutex::new(String::new()));
        let sink = stderr.clone();
        std::thread::spawn(move || {
            let mut text = String::new();
            let _ = stderr_pipe.read_to_string(&mut text);
            if let Ok(mut s) = sink.lock() {
                s.push_str(&text);
            }
        });
        Ok(Self {
            name: name.to_string(),
            stdin: child.stdin.take(),
            child,
            lines,
            stderr,
        })
    }

    fn stderr_text(&self) -> String {
        self.stderr.lock().map(|s| s.clone()).unwrap_or_default()
    }

    /// The next stdout line, waiting at most `timeout`.
    fn next_line(&self, timeout: Duration) -> Result<Option<String>, String> {
        match self.lines.recv_timeout(timeout) {
            Ok(line) => Ok(Some(line)),
            Err(RecvTimeoutError::Timeout) => Ok(None),
            Err(RecvTimeoutError::Disconnected) => {
                // Give the stderr reader a moment to collect the reason.
                let t0 = Instant::now();
                while self.stderr_text().is_empty() && t0.elapsed() < Duration::from_secs(2) {
                    std::thread::sleep(POLL);
                }
                Err(format!(
                    "{} ended early; stderr:\n{}",
                    self.name,
                    self.stderr_text()
                ))
            }
        }
    }

    /// The rest (trimmed) of the next stdout line, which must start with `prefix` (other lines
    /// are errors), or `None` when the peer said nothing within `timeout`.
    pub fn next_with(&self, prefix: &str, timeout: Duration) -> Result<Option<String>, String> {
        match self.next_line(timeout)? {
            Some(line) => match line.strip_prefix(prefix) {
                Some(rest) => Ok(Some(rest.trim().to_string())),
                None => Err(format!("{} said '{line}', expected '{prefix}'", self.name)),
            },
            None => Ok(None),
        }
    }

    /// Waits for a line starting with `prefix`; other lines are errors.
    pub fn expect_line(&self, prefix: &str, timeout: Duration) -> Result<String, String> {
        self.next_with(prefix, timeout)?.ok_or_else(|| {
            format!(
                "{} did not say '{prefix}' within {timeout:?}; stderr:\n{}",
                self.name,
                self.stderr_text()
            )
        })
    }

    /// Writes one line to the peer's stdin.
    pub fn send(&mut self, command: &str) -> Result<(), String> {
        let stdin = self.stdin.as_mut().ok_or("peer stdin closed")?;
        writeln!(stdin, "{command}")
            .and_then(|_| stdin.flush())
            .map_err(|e| format!("writing '{command}' to {}: {e}", self.name))
    }

    /// Closes stdin and waits for a successful exit.
    pub fn finish(mut self, timeout: Duration) -> Result<(), String> {
        drop(self.stdin.take());
        let t0 = Instant::now();
        loop {
            match self.child.try_wait() {
                Ok(Some(status)) if status.success() => return Ok(()),
                Ok(Some(status)) => {
                    return Err(format!(
                        "{} exited with {status}; stderr:\n{}",
                        self.name,
                        self.stderr_text()
                    ))
                }
                Ok(None) if t0.elapsed() < timeout => std::thread::sleep(POLL),
                Ok(None) => return Err(format!("{} still running after {timeout:?}", self.name)),
                Err(e) => return Err(format!("waiting for {}: {e}", self.name)),
            }
        }
    }
}

impl Drop for Peer {
    fn drop(&mut self) {
        if matches!(self.child.try_wait(), Ok(None)) {
            let _ = self.child.kill();
        }
        let _ = self.child.wait();
    }
}

/// FNV-1a (64 bit) of `data`, as the peers compute it.
pub fn fnv1a64(data: &[u8]) -> String {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for &b in data {
        h = (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3);
    }
    format!("{h:016x}")
}

/// Waits until `done()` or `timeout`; false on timeout.
pub fn wait_for(timeout: Duration, mut done: impl FnMut() -> bool) -> bool {
    let t0 = Instant::now();
    while !done() {
        if t0.elapsed() > timeout {
            return false;
        }
        std::thread::sleep(POLL);
    }
    true
}

/// The value at JSON pointer `path` of `v`.
pub fn json_at<'a>(v: &'a Value, path: &str) -> Result<&'a Value, String> {
    v.pointer(path).ok_or(format!("result has no {path}: {v}"))
}

/// The unsigned integer (or decimal string) at JSON pointer `path` of `v`.
pub fn json_u64(v: &Value, path: &str) -> Result<u64, String> {
    let field = json_at(v, path)?;
    field
        .as_u64()
        .or_else(|| field.as_str().and_then(|s| s.parse().ok()))
        .ok_or(format!("{path} is not an unsigned integer: {field}"))
}

/// The string at JSON pointer `path` of `v`.
pub fn json_str<'a>(v: &'a Value, path: &str) -> Result<&'a str, String> {
    v.pointer(path)
        .and_then(Value::as_str)
        .ok_or(format!("result has no string {path}: {v}"))
}
