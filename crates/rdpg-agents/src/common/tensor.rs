//! Tensor plumbing shared by every learner: devices, variables in a stable order, copies to
//! plain vectors, seed-only weight initialisation, the MLP builder and the denormal switch.

use tch::nn::{self, Module, VarStore};
use tch::{Device, Kind, Tensor};

use rdpg_core::rng::NpRng;
use serde::{Deserialize, Serialize};

use crate::error::{AgentError, Result};

/// Where the tensors live.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DeviceSpec {
    /// Always the CPU.
    Cpu,
    /// The first CUDA device; an error if libtorch sees none.
    Cuda,
    /// CUDA when available, else the CPU.
    Auto,
}

impl DeviceSpec {
    /// The name used in configs and on the command line (`cpu`, `cuda`, `auto`).
    pub fn as_str(self) -> &'static str {
        match self {
            DeviceSpec::Cpu => "cpu",
            DeviceSpec::Cuda => "cuda",
            DeviceSpec::Auto => "auto",
        }
    }
}

/// The tch device of a [`DeviceSpec`]; `cuda` without a CUDA device is an error.
pub fn resolve_device(spec: DeviceSpec) -> Result<Device> {
    match spec {
        DeviceSpec::Cpu => Ok(Device::Cpu),
        DeviceSpec::Cuda => {
            if tch::Cuda::is_available() {
                Ok(Device::Cuda(0))
            } else {
                Err(AgentError::Device(
                    "device \"cuda\" requested but libtorch sees no CUDA device (is the binary \
                     linked with libtorch_cuda?)"
                        .into(),
                ))
            }
        }
        DeviceSpec::Auto => Ok(Device::cuda_if_available()),
    }
}

/// Variables of a var store as (name, tensor), sorted by name (a stable order).
pub fn sorted_vars(vs: &VarStore) -> Vec<(String, Tensor)> {
    let mut v: Vec<_> = vs.variables().into_iter().collect();
    v.sort_by(|a, b| a.0.cmp(&b.0));
    v
}

/// Variables whose name starts with `prefix`, sorted by name.
pub fn vars_with_prefix(vs: &VarStore, prefix: &str) -> Vec<(String, Tensor)> {
    sorted_vars(vs)
        .into_iter()
        .filter(|(n, _)| n.starts_with(prefix))
        .collect()
}

/// A tensor's values as `f32`, flattened row-major (copied to the CPU).
#[allow(
    clippy::expect_used,
    reason = "called on 1-D float tensors this crate built"
)]
pub fn tensor_to_vec(t: &Tensor) -> Vec<f32> {
    let t = t
        .detach()
        .to_kind(Kind::Float)
        .to_device(Device::Cpu)
        .contiguous()
        .view([-1]);
    Vec::<f32>::try_from(&t).expect("tensor to Vec<f32>")
}

/// A tensor's values as `f64`, flattened row-major (copied to the CPU).
#[allow(
    clippy::expect_used,
    reason = "called on 1-D double tensors this crate built"
)]
pub fn tensor_to_vec64(t: &Tensor) -> Vec<f64> {
    let t = t
        .detach()
        .to_kind(Kind::Double)
        .to_device(Device::Cpu)
        .contiguous()
        .view([-1]);
    Vec::<f64>::try_from(&t).expect("tensor to Vec<f64>")
}

/// Output layers start small (uniform in `±3e-3`), as in DDPG, so that initial actions and
/// Q-values are near zero.
pub const HEAD_INIT: f64 = 3e-3;

/// Re-initialises every variable of `vs` from `rng` (uniform, PyTorch's default bounds), so
/// that initial weights depend only on the seed: not on libtorch's process-wide generator,
/// other threads, or the libtorch version.
///
/// Bounds: output layers (`*.head.*`) `±3e-3`; LSTM weights and biases `±1/sqrt(H)`; other
/// weights and biases (linear, convolution) `±1/sqrt(fan_in)` with `fan_in` the product of the
/// weight's dimensions after the first. Variables are visited in name order, each filled
/// row-major.
pub fn init_from_rng(vs: &VarStore, rng: &mut NpRng) {
    let vars = vs.variables();
    let mut names: Vec<&String> = vars.keys().collect();
    names.sort();
    for name in names {
        let var = &vars[name];
        let (stem, leaf) = name.rsplit_once('.').unwrap_or(("", name.as_str()));
        let bound = if stem.ends_with("head") {
            HEAD_INIT
        } else if stem.ends_with("lstm") {
            let h = var.size()[0] / 4;
            1.0 / (h as f64).sqrt()
        } else {
            let weight = if leaf == "bias" {
                &vars[&format!("{stem}.weight")]
            } else {
                var
            };
            let fan_in: i64 = weight.size()[1..].iter().product();
            1.0 / (fan_in.max(1) as f64).sqrt()
        };
        let vals: Vec<f64> = (0..var.numel())
            .map(|_| rng.uniform(-bound, bound))
            .collect();
        let t = Tensor::from_slice(&vals)
            .view(var.size().as_slice())
            .to_kind(var.kind())
            .to_device(var.device());
        let mut v = var.shallow_clone();
        tch::no_grad(|| v.copy_(&t));
    }
}

/// The non-linearity after each hidden layer of an [`Mlp`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Activation {
    /// `max(0, x)`.
    Relu,
    /// `tanh(x)`.
    Tanh,
}

/// A multi-layer perceptron: hidden layers `{prefix}{i}` (each followed by the activation),
/// then optionally a linear output layer `head` (no activation). Without a head the output is
/// the last hidden layer's activation.
#[derive(Debug)]
pub struct Mlp {
    layers: Vec<nn::Linear>,
    head: Option<nn::Linear>,
    act: Activation,
}

/// A second handle on a linear layer's parameters (no copy).
pub fn linear_handle(l: &nn::Linear) -> nn::Linear {
    nn::Linear {
        ws: l.ws.shallow_clone(),
        bs: l.bs.as_ref().map(Tensor::shallow_clone),
    }
}

impl Mlp {
    /// A second handle on the same parameters (no copy), for another thread.
    pub fn shallow_clone(&self) -> Self {
        Self {
            layers: self.layers.iter().map(linear_handle).collect(),
            head: self.head.as_ref().map(linear_handle),
            act: self.act,
        }
    }

    /// Builds the layers under `p`: `input -> hidden[0] -> ... -> hidden[k-1] (-> head)`,
    /// hidden layers named `{prefix}0`, `{prefix}1`, ... and the output layer `head`.
    pub fn new(
        p: &nn::Path,
        input: usize,
        hidden: &[usize],
        prefix: &str,
        head: Option<usize>,
        act: Activation,
    ) -> Self {
        let mut layers = Vec::with_capacity(hidden.len());
        let mut width = input as i64;
        for (i, &h) in hidden.iter().enumerate() {
            layers.push(nn::linear(
                p / format!("{prefix}{i}"),
                width,
                h as i64,
                Default::default(),
            ));
            width = h as i64;
        }
        let head = head.map(|out| nn::linear(p / "head", width, out as i64, Default::default()));
        Self { layers, head, act }
    }

    /// `x [B, in] -> [B, out]`.
    pub fn forward(&self, x: &Tensor) -> Tensor {
        let mut h = x.shallow_clone();
        for l in &self.layers {
            h = l.forward(&h);
            h = match self.act {
                Activation::Relu => h.relu(),
                Activation::Tanh => h.tanh(),
            };
        }
        match &self.head {
            Some(head) => head.forward(&h),
            None => h,
        }
    }
}

pub use rdpg_core::fpmode::set_flush_denormal;

/// Sets the number of intra-op CPU threads libtorch uses (process-wide); `n` is capped at
/// [`MAX_THREADS`].
pub fn set_num_threads(n: usize) {
    tch::set_num_threads(n.clamp(1, MAX_THREADS) as i32);
}

/// The most intra-op threads a config may ask for (`num_threads`).
pub const MAX_THREADS: usize = 1024;
