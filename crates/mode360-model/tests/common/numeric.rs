//! Numeric references for tests of tensor code: reproducible values, tensors from f64, and
//! reproducible network weights. Used by `mode360-model`'s tests and the root package's.

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
