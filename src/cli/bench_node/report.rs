//! What `mode360 bench-node` reports: latency percentiles, rates, node counters and the
//! resident-memory trace with its least-squares slope, as a table and as JSON.

use serde::Serialize;

/// Seconds per minute, for the RSS slope.
const SECONDS_PER_MINUTE: f64 = 60.0;

/// Latency distribution, milliseconds.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct LatencyStats {
    pub count: usize,
    pub min_ms: f64,
    pub median_ms: f64,
    pub p95_ms: f64,
    pub max_ms: f64,
}

impl LatencyStats {
    /// Of `samples_ms` (any order); `None` when empty.
    pub fn from_samples(samples_ms: &[f64]) -> Option<Self> {
        let mut v: Vec<f64> = samples_ms
            .iter()
            .copied()
            .filter(|x| x.is_finite())
            .collect();
        if v.is_empty() {
            return None;
        }
        v.sort_by(f64::total_cmp);
        Some(Self {
            count: v.len(),
            min_ms: v[0],
            median_ms: percentile(&v, 50.0),
            p95_ms: percentile(&v, 95.0),
            max_ms: v[v.len() - 1],
        })
    }
}

/// Percentile `p` (0..=100) of sorted, non-empty `v`, interpolating linearly between ranks
/// (numpy's default).
pub fn percentile(v: &[f64], p: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let pos = (p.clamp(0.0, 100.0) / 100.0) * (v.len() - 1) as f64;
    let lo = pos.floor() as usize;
    let hi = pos.ceil() as usize;
    v[lo] + (v[hi] - v[lo]) * (pos - lo as f64)
}

/// Least-squares slope of `(seconds, MiB)` samples, in MiB per minute (`None` for fewer
/// than two distinct times).
pub fn slope_mib_per_min(samples: &[(f64, f64)]) -> Option<f64> {
    let n = samples.len() as f64;
    if samples.len() < 2 {
        return None;
    }
    let mt = samples.iter().map(|s| s.0).sum::<f64>() / n;
    let mm = samples.iter().map(|s| s.1).sum::<f64>() / n;
    let stt: f64 = samples.iter().map(|s| (s.0 - mt).powi(2)).sum();
    if stt <= 0.0 {
        return None;
    }
    let stm: f64 = samples.iter().map(|s| (s.0 - mt) * (s.1 - mm)).sum();
    Some(stm / stt * SECONDS_PER_MINUTE)
}

/// 1-minute load average, if readable.
pub(super) fn load_average_1m() -> Option<f64> {
    std::fs::read_to_string("/proc/loadavg")
        .ok()?
        .split_whitespace()
        .next()?
        .parse()
        .ok()
}

/// Resident memory over the run, MiB.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct RssStats {
    pub start_mib: f64,
    pub max_mib: f64,
    pub end_mib: f64,
    /// Over the steady state: the second half of the time after the first depth.
    pub slope_mib_per_min: Option<f64>,
    /// Start of the steady state, seconds since the start.
    pub steady_from_s: Option<f64>,
    /// Band of the steady-state samples (RSS rises and falls with each inference).
    pub steady_min_mib: Option<f64>,
    pub steady_max_mib: Option<f64>,
    /// `(seconds since the start, MiB)`, one a second.
    pub samples: Vec<(f64, f64)>,
}

/// Everything measured.
#[derive(Clone, Debug, Serialize)]
pub struct BenchReport {
    pub estimator: String,
    /// Where the estimator ran: `cpu` or `cuda:N`.
    pub device: String,
    pub bag: String,
    pub input_width: usize,
    pub output_width: usize,
    pub cameras: usize,
    pub play_rate: f64,
    /// Playing window, seconds.
    pub window_s: f64,
    /// Complete groups (all cameras) published.
    pub groups_published: u64,
    pub input_rate_hz: f64,
    pub depth_received: u64,
    pub output_rate_hz: f64,
    /// Groups the node synchronized / ran through the pipeline / dropped in its mailbox.
    pub groups_synced: u64,
    pub groups_processed: u64,
    pub groups_dropped: u64,
    /// Published but never synchronized (lost on best-effort DDS, or unmatched).
    pub groups_lost: u64,
    pub pipeline_errors: u64,
    /// The node's own pipeline time (estimator + messages), mean, milliseconds.
    pub mean_inference_ms: Option<f64>,
    /// How long a group waited in the node's mailbox for the worker, mean, milliseconds.
    pub mean_mailbox_wait_ms: Option<f64>,
    pub latency: Option<LatencyStats>,
    pub rss: Option<RssStats>,
    pub cpus: usize,
    pub load_average_1m_start: Option<f64>,
    pub load_average_1m_end: Option<f64>,
}

impl BenchReport {
    /// A Markdown table.
    pub fn to_table(&self) -> String {
        let opt = |v: Option<f64>, prec: usize| {
            v.map_or_else(|| "n/a".to_string(), |x| format!("{x:.prec$}"))
        };
        let mut rows: Vec<(String, String)> = vec![
            ("estimator".into(), self.estimator.clone()),
            ("device".into(), self.device.clone()),
            ("bag".into(), self.bag.clone()),
            (
                "input / output width".into(),
                format!("{} / {} px", self.input_width, self.output_width),
            ),
            ("cameras".into(), self.cameras.to_string()),
            ("play rate".into(), format!("{}", self.play_rate)),
            ("window".into(), format!("{:.1} s", self.window_s)),
            (
                "input".into(),
                format!(
                    "{} groups, {:.2} groups/s",
                    self.groups_published, self.input_rate_hz
                ),
            ),
            (
                "output".into(),
                format!(
                    "{} depth, {:.3} depth/s",
                    self.depth_received, self.output_rate_hz
                ),
            ),
            (
                "node groups".into(),
                format!(
                    "synced {}, processed {}, dropped (mailbox) {}, lost before sync {}, errors {}",
                    self.groups_synced,
                    self.groups_processed,
                    self.groups_dropped,
                    self.groups_lost,
                    self.pipeline_errors
                ),
            ),
            (
                "inference (node, mean)".into(),
                format!("{} ms", opt(self.mean_inference_ms, 0)),
            ),
            (
                "mailbox wait (node, mean)".into(),
                format!("{} ms", opt(self.mean_mailbox_wait_ms, 0)),
            ),
        ];
        match &self.latency {
            Some(l) => rows.push((
                "latency min / median / p95 / max".into(),
                format!(
                    "{:.0} / {:.0} / {:.0} / {:.0} ms (n = {})",
                    l.min_ms, l.median_ms, l.p95_ms, l.max_ms, l.count
                ),
            )),
            None => rows.push(("latency".into(), "no depth received".into())),
        }
        if let Some(r) = &self.rss {
            rows.push((
                "RSS start / max / end".into(),
                format!(
                    "{:.0} / {:.0} / {:.0} MiB",
                    r.start_mib, r.max_mib, r.end_mib
                ),
            ));
            rows.push((
                "RSS slope (steady state)".into(),
                format!(
                    "{} MiB/min (from {} s on, band {} to {} MiB)",
                    opt(r.slope_mib_per_min, 2),
                    opt(r.steady_from_s, 0),
                    opt(r.steady_min_mib, 0),
                    opt(r.steady_max_mib, 0)
                ),
            ));
        }
        rows.push((
            "machine".into(),
            format!(
                "{} CPUs, load average {} -> {}",
                self.cpus,
                opt(self.load_average_1m_start, 2),
                opt(self.load_average_1m_end, 2)
            ),
        ));
        let mut out = String::from("| measure | value |\n|---|---|\n");
        for (k, v) in rows {
            out.push_str(&format!("| {k} | {v} |\n"));
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn latency_stats_interpolate_percentiles() {
        let samples: Vec<f64> = (1..=100).rev().map(f64::from).collect();
        let s = LatencyStats::from_samples(&samples).unwrap();
        assert_eq!(s.count, 100);
        assert_eq!(s.min_ms, 1.0);
        assert_eq!(s.max_ms, 100.0);
        assert!((s.median_ms - 50.5).abs() < 1e-12, "{s:?}");
        assert!((s.p95_ms - 95.05).abs() < 1e-9, "{s:?}");
        let one = LatencyStats::from_samples(&[42.0]).unwrap();
        assert_eq!(
            (one.min_ms, one.median_ms, one.p95_ms, one.max_ms),
            (42.0, 42.0, 42.0, 42.0)
        );
        assert_eq!(LatencyStats::from_samples(&[]), None);
        assert_eq!(LatencyStats::from_samples(&[f64::NAN]), None);
    }

    #[test]
    fn rss_slope_is_least_squares_mib_per_minute() {
        // 100 MiB + 2 MiB/min, sampled every second for a minute.
        let flat_growth: Vec<(f64, f64)> = (0..=60)
            .map(|s| (s as f64, 100.0 + 2.0 * s as f64 / 60.0))
            .collect();
        let slope = slope_mib_per_min(&flat_growth).unwrap();
        assert!((slope - 2.0).abs() < 1e-9, "{slope}");
        // +-1 MiB of alternating noise on a flat line for a minute: sum (t - mean) x = -30
        // and sum (t - mean)^2 = 60 (60^2 - 1) / 12 = 17995, i.e. only -0.1 MiB/min.
        let flat: Vec<(f64, f64)> = (0..60)
            .map(|s| (s as f64, 300.0 + if s % 2 == 0 { 1.0 } else { -1.0 }))
            .collect();
        let noisy = slope_mib_per_min(&flat).unwrap();
        assert!((noisy - (-30.0 / 17995.0 * 60.0)).abs() < 1e-9, "{noisy}");
        assert_eq!(slope_mib_per_min(&[(1.0, 5.0)]), None);
        assert_eq!(slope_mib_per_min(&[(1.0, 5.0), (1.0, 6.0)]), None);
    }
}
