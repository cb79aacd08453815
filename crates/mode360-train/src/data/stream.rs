//! The training stream: samples rendered in a background thread ahead of the trainer.

use super::{training_sample, DataConfig, DataError, TrainSample};
use std::sync::mpsc::{sync_channel, Receiver};
use std::thread::JoinHandle;

/// A sample and its index in the stream.
pub struct IndexedSample {
    pub index: u64,
    pub sample: Result<TrainSample, DataError>,
}

/// Samples `start, start + 1, ...` rendered in a background thread, at most `capacity` ahead
/// of the consumer (a bounded channel), so rendering overlaps training.
pub struct SampleStream {
    rx: Option<Receiver<IndexedSample>>,
    handle: Option<JoinHandle<()>>,
}

impl SampleStream {
    pub fn start(cfg: DataConfig, start: u64, capacity: usize) -> Result<Self, DataError> {
        cfg.validate()?;
        let (tx, rx) = sync_channel(capacity.max(1));
        let handle = std::thread::Builder::new()
            .name("mode360-train-data".into())
            .spawn(move || {
                for index in start.. {
                    let sample = training_sample(&cfg, index);
                    if tx.send(IndexedSample { index, sample }).is_err() {
                        break;
                    }
                }
            })
            .map_err(|e| DataError::Config(format!("cannot start data thread: {e}")))?;
        Ok(Self {
            rx: Some(rx),
            handle: Some(handle),
        })
    }

    /// The next sample (blocks until rendered).
    pub fn next_sample(&mut self) -> Result<IndexedSample, DataError> {
        self.rx
            .as_ref()
            .and_then(|rx| rx.recv().ok())
            .ok_or_else(|| DataError::Config("data thread stopped".into()))
    }
}

impl Drop for SampleStream {
    fn drop(&mut self) {
        // Closing the receiver makes the producer's next send fail, ending its loop.
        self.rx = None;
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
    }
}
