//! The `mode360 node` binary as a child process on its own domain: started with a params
//! file, up once it logs [`UP_MARKER`], its stderr lines collected, its own resident memory
//! readable apart from the test's, stopped by SIGINT with its exit summary, killed if a test
//! fails first.

use mode360::memory::resident_mib_of;
use std::collections::BTreeMap;
use std::io::{BufRead, BufReader, Read};
use std::path::Path;
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::mpsc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

const MANIFEST_DIR: &str = env!("CARGO_MANIFEST_DIR");
/// What the node logs once its endpoints exist.
pub const UP_MARKER: &str = " up on domain";
const POLL: Duration = Duration::from_millis(20);
/// How the node's exit summary line on stdout begins.
pub const SUMMARY_PREFIX: &str = "mode360 node stopped by SIGINT:";

/// A running node process (killed on drop unless [`NodeProcess::interrupt`] stopped it).
pub struct NodeProcess {
    child: Option<Child>,
    pid: u32,
    lines: mpsc::Receiver<String>,
    stderr_reader: Option<JoinHandle<()>>,
    stdout_reader: Option<JoinHandle<String>>,
    /// The stderr lines read so far.
    pub log: Vec<String>,
}

/// How a node process ended after SIGINT.
pub struct NodeExit {
    pub status: ExitStatus,
    /// Seconds from SIGINT to exit.
    pub exit_s: f64,
    pub stdout: String,
    /// Every stderr line.
    pub log: Vec<String>,
}

impl NodeExit {
    /// The counters of the exit summary line (`key=value` pairs after [`SUMMARY_PREFIX`]).
    pub fn summary(&self) -> Result<Summary, String> {
        let line = self
            .stdout
            .lines()
            .find(|l| l.starts_with(SUMMARY_PREFIX))
            .ok_or_else(|| format!("no summary line in {:?}", self.stdout))?;
        let counts = line
            .split_whitespace()
            .filter_map(|kv| kv.split_once('='))
            .filter_map(|(k, v)| Some((k.to_string(), v.parse().ok()?)))
            .collect();
        Ok(Summary {
            line: line.to_string(),
            counts,
        })
    }
}

/// The node's exit summary: the line and its counters.
pub struct Summary {
    pub line: String,
    pub counts: BTreeMap<String, u64>,
}

impl Summary {
    /// The counter `key`.
    pub fn get(&self, key: &str) -> Result<u64, String> {
        self.counts
            .get(key)
            .copied()
            .ok_or_else(|| format!("no {key} in '{}'", self.line))
    }
}

impl NodeProcess {
    /// Starts `mode360 node --ros-args --params-file PARAMS` in `domain_id` and waits up to
    /// `up_timeout` for [`UP_MARKER`].
    pub fn spawn(params: &Path, domain_id: u16, up_timeout: Duration) -> Result<Self, String> {
        let mut child = Command::new(env!("CARGO_BIN_EXE_mode360"))
            .args(["node", "--ros-args", "--params-file"])
            .arg(params)
            .current_dir(MANIFEST_DIR)
            .env("ROS_DOMAIN_ID", domain_id.to_string())
            .env("RUST_LOG", "info,rustdds=off")
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .map_err(|e| format!("starting the node binary: {e}"))?;
        let pid = child.id();
        let stderr = child.stderr.take().ok_or("no stderr")?;
        let stdout = child.stdout.take().ok_or("no stdout")?;
        let (line_tx, lines) = mpsc::channel::<String>();
        let stderr_reader = std::thread::spawn(move || {
            for line in BufReader::new(stderr).lines().map_while(Result::ok) {
                let _ = line_tx.send(line);
            }
        });
        let stdout_reader = std::thread::spawn(move || {
            let mut text = String::new();
            let _ = BufReader::new(stdout).read_to_string(&mut text);
            text
        });
        let mut node = Self {
            child: Some(child),
            pid,
            lines,
            stderr_reader: Some(stderr_reader),
            stdout_reader: Some(stdout_reader),
            log: Vec::new(),
        };
        let t0 = Instant::now();
        while !node.log.iter().any(|l| l.contains(UP_MARKER)) {
            let left = up_timeout.checked_sub(t0.elapsed()).ok_or_else(|| {
                format!("node not up after {up_timeout:?}; its log: {:#?}", node.log)
            })?;
            match node.lines.recv_timeout(left) {
                Ok(line) => node.log.push(line),
                Err(_) => return Err(format!("node not up; its log: {:#?}", node.log)),
            }
        }
        Ok(node)
    }

    /// The node's own resident memory (`VmRSS`), MiB.
    pub fn resident_mib(&self) -> Option<f64> {
        resident_mib_of(self.pid)
    }

    /// Sends SIGINT and waits up to `limit` for the process to exit.
    pub fn interrupt(mut self, limit: Duration) -> Result<NodeExit, String> {
        let mut child = self.child.take().ok_or("node already stopped")?;
        // SAFETY: kill(2) on the pid of our own child process.
        let rc = unsafe { libc::kill(self.pid as libc::pid_t, libc::SIGINT) };
        if rc != 0 {
            let _ = child.kill();
            return Err("kill(SIGINT) failed".into());
        }
        let t_sig = Instant::now();
        let status = loop {
            if let Some(status) = child.try_wait().map_err(|e| e.to_string())? {
                break status;
            }
            if t_sig.elapsed() > limit {
                let _ = child.kill();
                let _ = child.wait();
                return Err(format!("still running {limit:?} after SIGINT"));
            }
            std::thread::sleep(POLL);
        };
        let exit_s = t_sig.elapsed().as_secs_f64();
        let stdout = match self.stdout_reader.take() {
            Some(reader) => reader.join().map_err(|_| "stdout reader panicked")?,
            None => String::new(),
        };
        if let Some(reader) = self.stderr_reader.take() {
            let _ = reader.join();
        }
        let mut log = std::mem::take(&mut self.log);
        log.extend(self.lines.try_iter());
        Ok(NodeExit {
            status,
            exit_s,
            stdout,
            log,
        })
    }
}

impl Drop for NodeProcess {
    fn drop(&mut self) {
        if let Some(mut c) = self.child.take() {
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}
