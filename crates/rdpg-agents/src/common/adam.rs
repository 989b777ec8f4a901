//! Adam on plain tensors, so that its moments can be checkpointed (tch's `nn::Optimizer` wraps
//! the C++ optimiser and cannot export its state).
//!
//! The arithmetic follows `torch.optim.Adam` (non-amsgrad, coupled L2 weight decay):
//! `g += wd * p; m = b1 m + (1 - b1) g; v = b2 v + (1 - b2) g^2;
//! p -= lr / (1 - b1^t) * m / (sqrt(v) / sqrt(1 - b2^t) + eps)`.

use tch::{Kind, Tensor};

use crate::error::{AgentError, Result};

/// Hyper-parameters of one Adam instance.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AdamConfig {
    /// Learning rate.
    pub lr: f64,
    /// First-moment decay.
    pub beta1: f64,
    /// Second-moment decay.
    pub beta2: f64,
    /// Denominator epsilon.
    pub eps: f64,
    /// Coupled L2 coefficient added to the gradient (`g += wd * p`).
    pub weight_decay: f64,
}

/// Adam over a fixed, named list of parameters.
#[derive(Debug)]
pub struct Adam {
    cfg: AdamConfig,
    names: Vec<String>,
    params: Vec<Tensor>,
    m: Vec<Tensor>,
    v: Vec<Tensor>,
    step: i64,
}

impl Adam {
    /// Adam over `params` (name, variable), with zero moments.
    pub fn new(cfg: AdamConfig, params: Vec<(String, Tensor)>) -> Self {
        let (names, params): (Vec<_>, Vec<_>) = params.into_iter().unzip();
        let m = params.iter().map(Tensor::zeros_like).collect();
        let v = params.iter().map(Tensor::zeros_like).collect();
        Self {
            cfg,
            names,
            params,
            m,
            v,
            step: 0,
        }
    }

    /// Number of steps taken.
    pub fn steps(&self) -> i64 {
        self.step
    }

    /// The parameters this optimiser updates.
    pub fn params(&self) -> &[Tensor] {
        &self.params
    }

    /// Clears the gradients of all parameters.
    pub fn zero_grad(&mut self) {
        for p in &mut self.params {
            p.zero_grad();
        }
    }

    /// Scales the gradients so that their global L2 norm is at most `max_norm` (no host sync:
    /// the factor `min(1, max_norm / (norm + 1e-6))` stays a tensor). Returns the norm before
    /// clipping as a tensor.
    pub fn clip_grad_norm(&mut self, max_norm: f64) -> Tensor {
        let grads: Vec<Tensor> = self
            .params
            .iter()
            .map(Tensor::grad)
            .filter(Tensor::defined)
            .collect();
        if grads.is_empty() {
            return Tensor::from(0.0);
        }
        let sq: Vec<Tensor> = grads.iter().map(|g| g.square().sum(Kind::Float)).collect();
        let norm = Tensor::stack(&sq, 0).sum(Kind::Float).sqrt();
        let coef = (max_norm / (&norm + 1e-6)).clamp_max(1.0);
        tch::no_grad(|| {
            for mut g in grads {
                let c = coef.to_kind(g.kind());
                let _ = g.g_mul_(&c);
            }
        });
        norm
    }

    /// One Adam step on the current gradients (parameters without a gradient are skipped).
    pub fn step(&mut self) {
        let s = self.begin_step();
        self.apply(&s, 0..self.params.len());
    }

    /// Counts a step and returns its coefficients, for a step taken in parts:
    /// [`Adam::apply`] on ranges of the parameters here, [`AdamPart::apply`] on others on
    /// another thread. Every parameter must get the same `AdamStep` exactly once; the result
    /// is then identical to [`Adam::step`].
    pub fn begin_step(&mut self) -> AdamStep {
        self.step += 1;
        let c = self.cfg;
        let t = self.step as i32;
        AdamStep {
            cfg: c,
            step_size: c.lr / (1.0 - c.beta1.powi(t)),
            bc2_sqrt: (1.0 - c.beta2.powi(t)).sqrt(),
        }
    }

    /// Applies `s` to the parameters in `range` (in the order given to [`Adam::new`]).
    pub fn apply(&mut self, s: &AdamStep, range: std::ops::Range<usize>) {
        let (p, m, v) = (
            &mut self.params[range.clone()],
            &mut self.m[range.clone()],
            &mut self.v[range],
        );
        tch::no_grad(|| {
            for ((p, m), v) in p.iter_mut().zip(m).zip(v) {
                s.apply_one(p, m, v);
            }
        });
    }

    /// Second handles to the parameters in `range` and their moments, to step them on another
    /// thread.
    pub fn part(&self, range: std::ops::Range<usize>) -> AdamPart {
        let h = |ts: &[Tensor]| {
            ts[range.clone()]
                .iter()
                .map(Tensor::shallow_clone)
                .collect()
        };
        AdamPart {
            params: h(&self.params),
            m: h(&self.m),
            v: h(&self.v),
        }
    }

    /// The optimiser state as named tensors (`{prefix}step`, `{prefix}m.{name}`,
    /// `{prefix}v.{name}`), for a checkpoint.
    pub fn state(&self, prefix: &str) -> Vec<(String, Tensor)> {
        let mut out = vec![(format!("{prefix}step"), Tensor::from_slice(&[self.step]))];
        for ((n, m), v) in self.names.iter().zip(&self.m).zip(&self.v) {
            out.push((format!("{prefix}m.{n}"), m.shallow_clone()));
            out.push((format!("{prefix}v.{n}"), v.shallow_clone()));
        }
        out
    }

    /// Restores the state written by [`Adam::state`] from `tensors` (looked up by name).
    pub fn load_state(
        &mut self,
        prefix: &str,
        tensors: &std::collections::HashMap<String, Tensor>,
    ) -> Result<()> {
        let get = |k: String| {
            tensors
                .get(&k)
                .ok_or_else(|| AgentError::Checkpoint(format!("missing optimiser tensor `{k}`")))
        };
        let step = get(format!("{prefix}step"))?;
        let step = match step.numel() {
            1 => step.f_int64_value(&[0]).ok(),
            _ => None,
        }
        .filter(|s| (0..=crate::common::checkpoint::MAX_UPDATES as i64).contains(s))
        .ok_or_else(|| {
            AgentError::Checkpoint(format!(
                "optimiser tensor `{prefix}step` is not one step count from 0 to {}",
                crate::common::checkpoint::MAX_UPDATES
            ))
        })?;
        self.step = step;
        for ((n, m), v) in self.names.iter().zip(&mut self.m).zip(&mut self.v) {
            let src_m = get(format!("{prefix}m.{n}"))?;
            let src_v = get(format!("{prefix}v.{n}"))?;
            if src_m.size() != m.size() || src_v.size() != v.size() {
                return Err(AgentError::Checkpoint(format!(
                    "optimiser tensor `{n}` has the wrong shape"
                )));
            }
            tch::no_grad(|| {
                m.copy_(&src_m.to_kind(m.kind()).to_device(m.device()));
                v.copy_(&src_v.to_kind(v.kind()).to_device(v.device()));
            });
        }
        Ok(())
    }
}

/// The coefficients of one Adam step ([`Adam::begin_step`]).
#[derive(Debug, Clone, Copy)]
pub struct AdamStep {
    cfg: AdamConfig,
    step_size: f64,
    bc2_sqrt: f64,
}

impl AdamStep {
    fn apply_one(&self, p: &mut Tensor, m: &mut Tensor, v: &mut Tensor) {
        let c = self.cfg;
        let g = p.grad();
        if !g.defined() {
            return;
        }
        let g = if c.weight_decay != 0.0 {
            &g + &*p * c.weight_decay
        } else {
            g
        };
        let _ = m.lerp_(&g, 1.0 - c.beta1);
        let _ = v
            .g_mul_scalar_(c.beta2)
            .addcmul_(&g, &g.g_mul_scalar(1.0 - c.beta2));
        let denom = (v.sqrt() / self.bc2_sqrt) + c.eps;
        let _ = p.addcdiv_(&(&*m * -self.step_size), &denom);
    }
}

/// Some of an [`Adam`]'s parameters and moments as second handles ([`Adam::part`]): `Send`,
/// so that a step can be applied to them on another thread.
#[derive(Debug)]
pub struct AdamPart {
    params: Vec<Tensor>,
    m: Vec<Tensor>,
    v: Vec<Tensor>,
}

impl AdamPart {
    /// Applies `s` to these parameters.
    pub fn apply(&mut self, s: &AdamStep) {
        tch::no_grad(|| {
            for ((p, m), v) in self.params.iter_mut().zip(&mut self.m).zip(&mut self.v) {
                s.apply_one(p, m, v);
            }
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tch::Device;

    /// Matches a hand-computed Adam trajectory on `f(p) = sum(p^2) / 2` (gradient = p).
    #[test]
    fn matches_reference_arithmetic() {
        let p = Tensor::from_slice(&[1.0f64, -2.0]).set_requires_grad(true);
        let cfg = AdamConfig {
            lr: 0.1,
            beta1: 0.9,
            beta2: 0.999,
            eps: 1e-8,
            weight_decay: 0.01,
        };
        let mut adam = Adam::new(cfg, vec![("p".into(), p.shallow_clone())]);
        let (mut rp, mut rm, mut rv) = ([1.0f64, -2.0], [0.0f64; 2], [0.0f64; 2]);
        for t in 1..=5 {
            adam.zero_grad();
            let loss = p.square().sum(Kind::Double) * 0.5;
            loss.backward();
            adam.step();
            for i in 0..2 {
                let g = rp[i] + 0.01 * rp[i];
                rm[i] = 0.9 * rm[i] + 0.1 * g;
                rv[i] = 0.999 * rv[i] + 0.001 * g * g;
                let mh = rm[i] / (1.0 - 0.9f64.powi(t));
                let vh = rv[i] / (1.0 - 0.999f64.powi(t));
                rp[i] -= 0.1 * mh / (vh.sqrt() + 1e-8);
            }
        }
        let got: Vec<f64> = Vec::try_from(&p.detach()).unwrap();
        for i in 0..2 {
            assert!((got[i] - rp[i]).abs() < 1e-12, "{got:?} vs {rp:?}");
        }
        let _ = Device::Cpu;
    }

    #[test]
    fn clipping_bounds_the_norm() {
        let p = Tensor::from_slice(&[3.0f32, 4.0]).set_requires_grad(true);
        let cfg = AdamConfig {
            lr: 0.1,
            beta1: 0.9,
            beta2: 0.999,
            eps: 1e-8,
            weight_decay: 0.0,
        };
        let mut adam = Adam::new(cfg, vec![("p".into(), p.shallow_clone())]);
        (p.square().sum(Kind::Float) * 0.5).backward();
        let n = adam.clip_grad_norm(1.0);
        assert!((n.double_value(&[]) - 5.0).abs() < 1e-5);
        let g: Vec<f32> = Vec::try_from(&p.grad()).unwrap();
        assert!(
            (g[0] - 0.6).abs() < 1e-5 && (g[1] - 0.8).abs() < 1e-5,
            "{g:?}"
        );
    }

    /// A step taken in parts, one of them on another thread, equals one step bit for bit.
    #[test]
    fn a_step_in_parts_equals_one_step() {
        let cfg = AdamConfig {
            lr: 0.05,
            beta1: 0.9,
            beta2: 0.999,
            eps: 1e-8,
            weight_decay: 0.01,
        };
        let make = || {
            let ps: Vec<Tensor> = (0..3)
                .map(|i| {
                    Tensor::from_slice(&[1.0f32 + i as f32, -0.5, 0.25]).set_requires_grad(true)
                })
                .collect();
            let named = ps
                .iter()
                .enumerate()
                .map(|(i, p)| (format!("p{i}"), p.shallow_clone()));
            (Adam::new(cfg, named.collect()), ps)
        };
        let (mut whole, pw) = make();
        let (mut parts, pp) = make();
        for _ in 0..4 {
            for (adam, ps) in [(&mut whole, &pw), (&mut parts, &pp)] {
                adam.zero_grad();
                let loss = ps
                    .iter()
                    .map(|p| p.pow_tensor_scalar(3).sum(Kind::Float))
                    .reduce(|a, b| a + b)
                    .unwrap();
                loss.backward();
            }
            whole.step();
            let s = parts.begin_step();
            let mut side = parts.part(1..3);
            std::thread::spawn(move || side.apply(&s)).join().unwrap();
            parts.apply(&s, 0..1);
        }
        for (a, b) in pw.iter().zip(&pp) {
            assert!(a.equal(b), "{a:?} vs {b:?}");
        }
        assert_eq!(whole.steps(), parts.steps());
    }
}
