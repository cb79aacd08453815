//! AdamW with inspectable moments (candle_nn's keeps them private, so they could not be
//! checkpointed), plus the learning-rate schedule.
//!
//! Update per parameter `theta` with gradient `g` at step `t` (1-based), as in
//! `candle_nn::AdamW` and Loshchilov & Hutter:
//! `m = b1 m + (1 - b1) g`, `v = b2 v + (1 - b2) g^2`,
//! `theta = theta (1 - lr wd) - lr (m / (1 - b1^t)) / (sqrt(v / (1 - b2^t)) + eps)`.
//!
//! With `max_grad_norm` set, the gradients are first scaled by
//! `min(1, max_grad_norm / ||g||)`, `||g||` the L2 norm over all parameters together.

use candle_core::{backprop::GradStore, DType, Device, Tensor, Var};
use std::collections::HashMap;
use std::f64::consts::PI;

/// Adam's default first-moment decay.
pub const DEFAULT_BETA1: f64 = 0.9;
/// Adam's default second-moment decay.
pub const DEFAULT_BETA2: f64 = 0.999;
/// Adam's default denominator epsilon.
pub const DEFAULT_EPS: f64 = 1e-8;
/// Prefixes of the moment tensors in an optimizer checkpoint.
const FIRST_MOMENT_PREFIX: &str = "m.";
const SECOND_MOMENT_PREFIX: &str = "v.";

/// AdamW hyper-parameters (the learning rate is set per step by the schedule).
#[derive(Clone, Debug, PartialEq)]
pub struct AdamWParams {
    pub beta1: f64,
    pub beta2: f64,
    pub eps: f64,
    pub weight_decay: f64,
    /// Clip the global gradient norm to this (`None`: no clipping).
    pub max_grad_norm: Option<f64>,
}

impl Default for AdamWParams {
    fn default() -> Self {
        Self {
            beta1: DEFAULT_BETA1,
            beta2: DEFAULT_BETA2,
            eps: DEFAULT_EPS,
            weight_decay: 0.0,
            max_grad_norm: None,
        }
    }
}

struct Slot {
    name: String,
    /// Multiplier of the step's learning rate for this variable.
    lr_scale: f64,
    var: Var,
    m: Tensor,
    v: Tensor,
}

/// AdamW over named variables.
pub struct AdamW {
    params: AdamWParams,
    slots: Vec<Slot>,
    /// Updates applied so far.
    pub step_t: usize,
}

impl AdamW {
    /// One slot per variable, in name order (so checkpoints are deterministic).
    pub fn new(mut vars: Vec<(String, Var)>, params: AdamWParams) -> candle_core::Result<Self> {
        vars.sort_by(|a, b| a.0.cmp(&b.0));
        let slots = vars
            .into_iter()
            .map(|(name, var)| {
                let m = var.zeros_like()?;
                let v = var.zeros_like()?;
                Ok(Slot {
                    name,
                    lr_scale: 1.0,
                    var,
                    m,
                    v,
                })
            })
            .collect::<candle_core::Result<Vec<_>>>()?;
        Ok(Self {
            params,
            slots,
            step_t: 0,
        })
    }

    /// Sets the learning-rate multiplier of the variables whose name starts with `prefix`;
    /// returns how many there are.
    pub fn scale_lr_of(&mut self, prefix: &str, scale: f64) -> usize {
        let mut n = 0;
        for s in self.slots.iter_mut().filter(|s| s.name.starts_with(prefix)) {
            s.lr_scale = scale;
            n += 1;
        }
        n
    }

    /// The L2 norm of all gradients of the optimizer's variables together.
    pub fn grad_norm(&self, grads: &GradStore) -> candle_core::Result<f64> {
        let mut sum_sq = 0f64;
        for s in &self.slots {
            if let Some(g) = grads.get(s.var.as_tensor()) {
                let sq: f32 = g.to_dtype(DType::F32)?.sqr()?.sum_all()?.to_scalar()?;
                sum_sq += f64::from(sq);
            }
        }
        Ok(sum_sq.sqrt())
    }

    /// Applies one update with learning rate `lr`; variables without a gradient are skipped
    /// (their moments stay). Returns the global gradient norm before clipping.
    pub fn step(&mut self, grads: &GradStore, lr: f64) -> candle_core::Result<f64> {
        let norm = self.grad_norm(grads)?;
        let clip = match self.params.max_grad_norm {
            Some(max) if norm > max && norm.is_finite() => max / norm,
            _ => 1.0,
        };
        self.step_t += 1;
        let p = &self.params;
        let t = self.step_t as i32;
        let scale_m = 1.0 / (1.0 - p.beta1.powi(t));
        let scale_v = 1.0 / (1.0 - p.beta2.powi(t));
        for s in &mut self.slots {
            let Some(g) = grads.get(s.var.as_tensor()) else {
                continue;
            };
            // Detached: gradients carry autograd history (they are built from variables), and
            // moments computed from them would otherwise chain every step's graph (a leak).
            let g = (g.detach().to_dtype(DType::F32)? * clip)?;
            let lr = lr * s.lr_scale;
            let m = ((&s.m * p.beta1)? + (&g * (1.0 - p.beta1))?)?;
            let v = ((&s.v * p.beta2)? + (g.sqr()? * (1.0 - p.beta2))?)?;
            let m_hat = (&m * scale_m)?;
            let v_hat = (&v * scale_v)?;
            let decayed = (s.var.as_tensor() * (1.0 - lr * p.weight_decay))?;
            let update = ((m_hat / (v_hat.sqrt()? + p.eps)?)? * lr)?;
            s.var.set(&(decayed - update)?)?;
            s.m = m.detach();
            s.v = v.detach();
        }
        Ok(norm)
    }

    /// The moments as named tensors (`m.<var>` and `v.<var>`).
    pub fn state_tensors(&self) -> HashMap<String, Tensor> {
        let mut out = HashMap::with_capacity(self.slots.len() * 2);
        for s in &self.slots {
            out.insert(format!("{FIRST_MOMENT_PREFIX}{}", s.name), s.m.clone());
            out.insert(format!("{SECOND_MOMENT_PREFIX}{}", s.name), s.v.clone());
        }
        out
    }

    /// Restores moments saved by [`Self::state_tensors`]; names a missing or mis-shaped one.
    pub fn load_state_tensors(
        &mut self,
        mut state: HashMap<String, Tensor>,
        step_t: usize,
        device: &Device,
    ) -> Result<(), String> {
        for s in &mut self.slots {
            for (prefix, dst) in [
                (FIRST_MOMENT_PREFIX, &mut s.m),
                (SECOND_MOMENT_PREFIX, &mut s.v),
            ] {
                let key = format!("{prefix}{}", s.name);
                let t = state
                    .remove(&key)
                    .ok_or_else(|| format!("optimizer state has no tensor '{key}'"))?;
                if t.dims() != s.var.dims() {
                    return Err(format!(
                        "optimizer tensor '{key}' has shape {:?}, the model {:?}",
                        t.dims(),
                        s.var.dims()
                    ));
                }
                *dst = t.to_device(device).map_err(|e| e.to_string())?;
            }
        }
        self.step_t = step_t;
        Ok(())
    }
}

/// Linear warmup then cosine decay to `min_lr_fraction * base_lr`:
/// `lr(s) = base (s + 1) / warmup` for `s < warmup`, else
/// `lr(s) = base (f + (1 - f) (1 + cos(pi p)) / 2)` with `p = (s - warmup) / (total - warmup)`.
#[derive(Clone, Debug, PartialEq)]
pub struct LrSchedule {
    pub base_lr: f64,
    pub warmup_steps: usize,
    pub total_steps: usize,
    pub min_lr_fraction: f64,
}

impl LrSchedule {
    /// Learning rate of step `step` (0-based).
    pub fn lr(&self, step: usize) -> f64 {
        if step < self.warmup_steps {
            return self.base_lr * (step + 1) as f64 / self.warmup_steps as f64;
        }
        let span = self.total_steps.saturating_sub(self.warmup_steps).max(1);
        let progress = ((step - self.warmup_steps) as f64 / span as f64).min(1.0);
        let f = self.min_lr_fraction;
        self.base_lr * (f + (1.0 - f) * 0.5 * (1.0 + (PI * progress).cos()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn schedule_warms_up_then_decays() {
        let s = LrSchedule {
            base_lr: 1e-3,
            warmup_steps: 4,
            total_steps: 104,
            min_lr_fraction: 0.1,
        };
        assert!((s.lr(0) - 2.5e-4).abs() < 1e-12);
        assert!((s.lr(3) - 1e-3).abs() < 1e-12);
        assert!((s.lr(4) - 1e-3).abs() < 1e-12);
        assert!((s.lr(54) - 0.55e-3).abs() < 1e-12);
        assert!((s.lr(104) - 1e-4).abs() < 1e-12);
    }

    #[test]
    fn adamw_first_step_moves_by_lr() {
        // With zero moments, the bias-corrected first step is lr * g / (|g| + eps) = lr sign(g).
        let var = Var::from_vec(vec![1.0f32, -2.0], 2, &Device::Cpu).unwrap();
        let mut opt = AdamW::new(vec![("w".into(), var.clone())], AdamWParams::default()).unwrap();
        let loss = (var.as_tensor() * 3.0).unwrap().sum_all().unwrap();
        let grads = loss.backward().unwrap();
        opt.step(&grads, 0.1).unwrap();
        let w: Vec<f32> = var.as_tensor().to_vec1().unwrap();
        assert!(
            (w[0] - 0.9).abs() < 1e-6 && (w[1] + 2.1).abs() < 1e-6,
            "{w:?}"
        );
        let m: Vec<f32> = opt.state_tensors()["m.w"].to_vec1().unwrap();
        assert!((m[0] - 0.3).abs() < 1e-6);
    }

    #[test]
    fn a_scaled_prefix_moves_by_its_own_rate() {
        // The first step moves every weight by its rate times sign(g): 0.1 for `a.w`, 5 x 0.1
        // for the two `head.*` variables.
        let dev = Device::Cpu;
        let vars: Vec<(String, Var)> = ["a.w", "head.x", "head.y"]
            .iter()
            .map(|n| {
                (
                    (*n).to_string(),
                    Var::from_vec(vec![1.0f32], 1, &dev).unwrap(),
                )
            })
            .collect();
        let mut opt = AdamW::new(vars.clone(), AdamWParams::default()).unwrap();
        assert_eq!(opt.scale_lr_of("head.", 5.0), 2);
        let loss = vars
            .iter()
            .map(|(_, v)| v.as_tensor().sum_all().unwrap())
            .reduce(|a, b| (a + b).unwrap())
            .unwrap();
        opt.step(&loss.backward().unwrap(), 0.1).unwrap();
        let w: Vec<f32> = vars
            .iter()
            .map(|(_, v)| v.as_tensor().to_vec1::<f32>().unwrap()[0])
            .collect();
        assert!((w[0] - 0.9).abs() < 1e-6, "{w:?}");
        assert!(
            (w[1] - 0.5).abs() < 1e-6 && (w[2] - 0.5).abs() < 1e-6,
            "{w:?}"
        );
    }
}
