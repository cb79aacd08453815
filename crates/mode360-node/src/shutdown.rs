//! Shutdown on SIGINT (Ctrl-C) or SIGTERM: [`ShutdownSignals`] for async loops such as
//! [`super::run_node`]'s, [`stop_flag_on_signals`] for blocking ones.

use super::dds::runtime;
use super::NodeError;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

/// SIGINT (Ctrl-C) and SIGTERM as one stream; install it before announcing that the
/// process is up so that no signal can hit the default handler (which kills the process).
pub struct ShutdownSignals {
    #[cfg(unix)]
    interrupt: tokio::signal::unix::Signal,
    #[cfg(unix)]
    terminate: tokio::signal::unix::Signal,
}

impl ShutdownSignals {
    /// Installs the handlers; must be called inside a tokio runtime (`Runtime::enter`).
    pub fn install() -> Result<Self, NodeError> {
        #[cfg(unix)]
        {
            use tokio::signal::unix::{signal, SignalKind};
            let err = |e: std::io::Error| NodeError::Runtime {
                what: "installing signal handlers".into(),
                problem: e.to_string(),
            };
            Ok(Self {
                interrupt: signal(SignalKind::interrupt()).map_err(err)?,
                terminate: signal(SignalKind::terminate()).map_err(err)?,
            })
        }
        #[cfg(not(unix))]
        Ok(Self {})
    }

    /// Waits for the next signal and returns its name (`SIGINT` or `SIGTERM`).
    pub async fn recv(&mut self) -> &'static str {
        #[cfg(unix)]
        {
            tokio::select! {
                _ = self.interrupt.recv() => "SIGINT",
                _ = self.terminate.recv() => "SIGTERM",
            }
        }
        #[cfg(not(unix))]
        {
            match tokio::signal::ctrl_c().await {
                Ok(()) => "Ctrl-C",
                Err(_) => std::future::pending().await,
            }
        }
    }
}

/// A flag that turns true on SIGINT or SIGTERM (a background thread waits for them), for
/// blocking loops such as [`super::player::play_bag_until`].
pub fn stop_flag_on_signals() -> Result<Arc<AtomicBool>, NodeError> {
    let rt = runtime()?;
    let mut signals = {
        let _guard = rt.enter();
        ShutdownSignals::install()?
    };
    let stop = Arc::new(AtomicBool::new(false));
    let flag = stop.clone();
    std::thread::Builder::new()
        .name("mode360-signals".into())
        .spawn(move || {
            let name = rt.block_on(signals.recv());
            tracing::info!("{name}: stopping");
            flag.store(true, Ordering::SeqCst);
        })
        .map_err(|e| NodeError::Runtime {
            what: "starting the signal thread".into(),
            problem: e.to_string(),
        })?;
    Ok(stop)
}
