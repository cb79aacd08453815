//! Helpers shared by the integration test binaries (`tests/core`, `tests/model`,
//! `tests/bags`, `tests/node`): paths in the repository, the bundled rig, third-party tools
//! from the environment, numeric references, and a lock for the live-node tests.
#![allow(dead_code)] // each binary uses its own subset

use mode360::geometry::Rig;
use std::path::PathBuf;
use std::sync::{Mutex, MutexGuard};

/// The Python with the interop packages (`tests/interop/setup.sh DIR` makes one).
pub const PYTHON_ENV: &str = "MODE360_PYTHON";
/// A folder holding `node_modules` with Foxglove's decoders (`tests/interop/setup.sh`).
pub const NODE_DIR_ENV: &str = "MODE360_NODE_DIR";
/// The bundled Deep360 rig, relative to the repository root.
pub const DEEP360_RIG: &str = "launch_configs/rig_deep360.yaml";

/// The bundled Deep360 rig, as an absolute path.
pub const RIG_PATH: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/launch_configs/rig_deep360.yaml"
);

/// What the tests that use `?` return.
pub type TestResult = Result<(), Box<dyn std::error::Error>>;

/// `rel` inside the repository.
pub fn repo_path(rel: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(rel)
}

/// The bundled Deep360 rig (`launch_configs/rig_deep360.yaml`).
pub fn deep360_rig() -> Rig {
    Rig::from_file(repo_path(DEEP360_RIG)).expect("launch_configs/rig_deep360.yaml")
}

/// The value of `var`, or `None` after printing `skipped {what}: {hint}`. Under CI (`CI` set)
/// a missing tool fails the test instead: CI installs every peer.
pub fn tool_from_env(var: &str, what: &str, hint: &str) -> Option<String> {
    match std::env::var(var) {
        Ok(value) if !value.is_empty() => Some(value),
        _ => {
            let message = format!("skipped {what}: {hint}");
            assert!(std::env::var_os("CI").is_none(), "CI is set: {message}");
            println!("{message}");
            None
        }
    }
}

/// The Python with numpy (`MODE360_PYTHON`), or `None` after saying why `what` is skipped.
pub fn python_with_numpy(what: &str) -> Option<String> {
    tool_from_env(
        PYTHON_ENV,
        what,
        &format!("set {PYTHON_ENV} to a Python with numpy (tests/interop/setup.sh)"),
    )
}

/// Serializes the tests that run a live node over DDS: each binary used to run alone, and two
/// nodes doing inference at once on a small CI machine would stretch their timeouts.
pub fn live_node_lock() -> MutexGuard<'static, ()> {
    static LOCK: Mutex<()> = Mutex::new(());
    LOCK.lock().unwrap_or_else(|e| e.into_inner())
}

/// Reliable QoS keeping the last 10 samples, for test publishers and listeners.
pub fn reliable_qos() -> ros2_client::QosProfile {
    ros2_client::QosProfile::publisher_default()
        .history(ros2_client::qos::History::KeepLast { depth: 10 })
}

/// Deterministic values in [-1, 1) from a linear congruential generator.
pub fn pseudo_random(n: usize, seed: u64) -> Vec<f64> {
    let mut s = seed
        .wrapping_mul(6364136223846793005)
        .wrapping_add(1442695040888963407);
    (0..n)
        .map(|_| {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((s >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
        })
        .collect()
}

/// An f32 CPU tensor of `v`.
pub fn tensor(v: &[f64], dims: &[usize]) -> candle_core::Tensor {
    let f: Vec<f32> = v.iter().map(|&x| x as f32).collect();
    candle_core::Tensor::from_vec(f, dims, &candle_core::Device::Cpu).unwrap()
}

/// All values of `t` (f32) as f64.
pub fn values(t: &candle_core::Tensor) -> Vec<f64> {
    t.flatten_all()
        .unwrap()
        .to_vec1::<f32>()
        .unwrap()
        .into_iter()
        .map(f64::from)
        .collect()
}

/// Largest absolute difference of two equally long slices.
pub fn max_abs_diff(a: &[f64], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}

/// Dot product.
pub fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// Replaces every variable's random initialisation by a reproducible one: uniform in
/// `±1/sqrt(fan_in)` (`fan_in`: the elements per output channel, the last axis) from
/// [`pseudo_random`], for every variable that candle initialises at random (non-constant);
/// constant ones (a zero bias, a unit scale) stay. Tests whose numbers depend on the weights
/// use it: candle's own initialisation differs from run to run.
pub fn seed_weights(varmap: &candle_nn::VarMap, seed: u64) {
    let data = varmap.data().lock().unwrap();
    let mut names: Vec<&String> = data.keys().collect();
    names.sort();
    for (i, name) in names.into_iter().enumerate() {
        let var = &data[name];
        let v = values(var.as_tensor());
        if v.iter().all(|x| *x == v[0]) {
            continue;
        }
        let dims = var.as_tensor().dims();
        let fan_in = v.len() / dims.last().copied().unwrap_or(1).max(1);
        let bound = 1.0 / (fan_in as f64).sqrt();
        let r = pseudo_random(v.len(), seed.wrapping_mul(1000).wrapping_add(i as u64));
        let w: Vec<f64> = r.iter().map(|x| bound * x).collect();
        var.set(&tensor(&w, dims)).expect("set weights");
    }
}
