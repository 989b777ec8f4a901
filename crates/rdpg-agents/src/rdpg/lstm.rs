//! The recurrent core and the scan it drives.
//!
//! * [`Lstm`]: a single-layer LSTM on libtorch's fused kernel for sequences ([`Lstm::seq`]),
//!   `lstm_cell` for single steps ([`Lstm::cell`]: acting, the per-step actor gradient),
//!   measured faster for one step and cheaper in backward, and a loop of cells with the input
//!   projection of all steps hoisted out for the no-gradient runs that need every step's
//!   state ([`Core::states_after`], [`Core::states_before`], [`Core::stepwise`]).
//! * [`Core`]: the part between embedding and head, an LSTM (RDPG) or FC + ReLU (DDPG, whose
//!   state is zero-width and passes through unchanged).
//! * [`scan_state`]: the no-gradient scan of Algorithm 1 (paper Eq. (scan)) over left-padded
//!   windows, with the padding never touching the state.
//!
//! Shapes: `B` batch (windows or environments), `T` time steps, `H` recurrent width.
//! Recurrent states are `[1, B, H]` (libtorch's `[layers, batch, hidden]`). Sequences are
//! batch-first.

use tch::nn::{self, Module};
use tch::{Device, Kind, Tensor};

use super::config::ScanMethod;

/// The state of an LSTM core: `h` and `c`, each `[1, B, H]` (zero-width `[1, B, 0]` for a
/// feed-forward core).
#[derive(Debug)]
pub struct RecState {
    /// Hidden state (also the LSTM output), `[1, B, H]`.
    pub h: Tensor,
    /// Cell state, `[1, B, H]`.
    pub c: Tensor,
}

impl RecState {
    /// All-zero state for `batch` sequences of width `hidden`.
    pub fn zeros(batch: i64, hidden: i64, kind: Kind, device: Device) -> Self {
        let z = Tensor::zeros([1, batch, hidden], (kind, device));
        Self { h: z.copy(), c: z }
    }

    /// A second handle to the same tensors.
    pub fn shallow_clone(&self) -> Self {
        Self {
            h: self.h.shallow_clone(),
            c: self.c.shallow_clone(),
        }
    }

    /// The same values, cut from the autograd graph.
    pub fn detach(&self) -> Self {
        Self {
            h: self.h.detach(),
            c: self.c.detach(),
        }
    }

    /// A deep copy.
    pub fn copy(&self) -> Self {
        Self {
            h: self.h.copy(),
            c: self.c.copy(),
        }
    }

    /// Batch size `B`.
    pub fn batch(&self) -> i64 {
        self.h.size()[1]
    }
}

/// A single-layer LSTM on libtorch's fused kernel (oneDNN on CPU, cuDNN on GPU).
///
/// Weights are named and initialised as PyTorch's `nn.LSTM` (`weight_ih_l0 [4H, in]`,
/// `weight_hh_l0 [4H, H]`, two biases `[4H]`, all uniform in `±1/sqrt(H)`; gate order i, f, g, o).
#[derive(Debug)]
pub struct Lstm {
    w_ih: Tensor,
    w_hh: Tensor,
    b_ih: Tensor,
    b_hh: Tensor,
    hidden: i64,
}

impl Lstm {
    /// A second handle on the same weights (no copy), for another thread.
    pub fn shallow_clone(&self) -> Self {
        Self {
            w_ih: self.w_ih.shallow_clone(),
            w_hh: self.w_hh.shallow_clone(),
            b_ih: self.b_ih.shallow_clone(),
            b_hh: self.b_hh.shallow_clone(),
            hidden: self.hidden,
        }
    }

    /// Creates the four weight tensors under `p`.
    pub fn new(p: &nn::Path, in_dim: i64, hidden: i64) -> Self {
        let k = 1.0 / (hidden as f64).sqrt();
        let init = nn::Init::Uniform { lo: -k, up: k };
        let w_ih = p.var("weight_ih_l0", &[4 * hidden, in_dim], init);
        let w_hh = p.var("weight_hh_l0", &[4 * hidden, hidden], init);
        let b_ih = p.var("bias_ih_l0", &[4 * hidden], init);
        let b_hh = p.var("bias_hh_l0", &[4 * hidden], init);
        let lstm = Self {
            w_ih,
            w_hh,
            b_ih,
            b_hh,
            hidden,
        };
        lstm.flatten_for_cudnn(in_dim);
        lstm
    }

    /// On CUDA, lays the weights out in one contiguous cuDNN buffer (what PyTorch's
    /// `flatten_parameters` does); a no-op on the CPU.
    fn flatten_for_cudnn(&self, in_dim: i64) {
        if self.w_ih.device().is_cuda() && tch::Cuda::cudnn_is_available() {
            let _ = Tensor::internal_cudnn_rnn_flatten_weight(
                &[&self.w_ih, &self.w_hh, &self.b_ih, &self.b_hh],
                4,
                in_dim,
                2, // LSTM
                self.hidden,
                0,
                1,
                true,
                false,
            );
        }
    }

    /// Hidden width `H`.
    pub fn hidden(&self) -> i64 {
        self.hidden
    }

    /// Runs the fused LSTM over `x [B, T, in]` from `s`; returns the outputs `h_t` for every
    /// step, `[B, T, H]`, and the final state.
    pub fn seq(&self, x: &Tensor, s: &RecState) -> (Tensor, RecState) {
        let (out, h, c) = x.lstm(
            &[&s.h, &s.c],
            &[&self.w_ih, &self.w_hh, &self.b_ih, &self.b_hh],
            true,
            1,
            0.0,
            true,
            false,
            true,
        );
        (out, RecState { h, c })
    }

    /// `steps` LSTM steps over `x [B, >= steps, in]` from `(h, c)` (`[B, H]` each), for runs
    /// without gradient that need the state at every step: the input projection
    /// `x W_ih^T + b_ih + b_hh` of all steps in one matrix product, then per step one
    /// `h W_hh^T` and the gate arithmetic (gate order i, f, g, o). Returns the states after
    /// each step, `(h_t, c_t)`. The same function as [`Lstm::cell`] step after step, with the
    /// sums in another order (equal to float rounding).
    fn cells(&self, x: &Tensor, h: &Tensor, c: &Tensor, steps: i64) -> Vec<(Tensor, Tensor)> {
        let hd = self.hidden;
        let (b, d) = (x.size()[0], x.size()[2]);
        let x = x.narrow(1, 0, steps);
        // [B * steps, in] @ [in, 4H] + (b_ih + b_hh) -> [B, steps, 4H]
        let xw = (&self.b_ih + &self.b_hh)
            .addmm(&x.reshape([b * steps, d]), &self.w_ih.tr())
            .view([b, steps, 4 * hd]);
        let w_hh = self.w_hh.tr(); // [H, 4H]
        let (mut h, mut c) = (h.shallow_clone(), c.shallow_clone());
        let mut out = Vec::with_capacity(steps as usize);
        for t in 0..steps {
            let g = xw.select(1, t).addmm(&h, &w_hh); // [B, 4H]
            let i_f = g.narrow(1, 0, 2 * hd).sigmoid();
            let (i, f) = (i_f.narrow(1, 0, hd), i_f.narrow(1, hd, hd));
            let gg = g.narrow(1, 2 * hd, hd).tanh();
            let o = g.narrow(1, 3 * hd, hd).sigmoid();
            c = (f * &c).addcmul(&i, &gg);
            h = o * c.tanh();
            out.push((h.shallow_clone(), c.shallow_clone()));
        }
        out
    }

    /// One step with libtorch's `lstm_cell` (composite matmuls + element-wise ops): `x [N, in]`,
    /// `h`, `c` `[N, H]` -> next `(h, c)`. For single steps this beats the fused sequence
    /// kernel, and autograd only computes the gradients actually needed (e.g. none for a
    /// detached state or frozen weights).
    pub fn cell(&self, x: &Tensor, h: &Tensor, c: &Tensor) -> (Tensor, Tensor) {
        x.lstm_cell(
            &[h, c],
            &self.w_ih,
            &self.w_hh,
            Some(&self.b_ih),
            Some(&self.b_hh),
        )
    }
}

/// The part between embedding and head: an LSTM (RDPG) or an FC layer + ReLU (DDPG).
#[derive(Debug)]
pub enum Core {
    /// Recurrent core.
    Lstm(Lstm),
    /// Feed-forward core (`width` outputs); carries no state.
    Ff(nn::Linear, i64),
}

impl Core {
    /// A second handle on the same parameters (no copy), for another thread.
    pub fn shallow_clone(&self) -> Self {
        match self {
            Core::Lstm(l) => Core::Lstm(l.shallow_clone()),
            Core::Ff(fc, w) => Core::Ff(crate::common::tensor::linear_handle(fc), *w),
        }
    }

    pub(super) fn new(p: &nn::Path, recurrent: bool, in_dim: i64, hidden: i64) -> Self {
        if recurrent {
            Core::Lstm(Lstm::new(&(p / "lstm"), in_dim, hidden))
        } else {
            Core::Ff(
                nn::linear(p / "fc", in_dim, hidden, Default::default()),
                hidden,
            )
        }
    }

    /// Whether this core carries a recurrent state.
    pub fn is_recurrent(&self) -> bool {
        matches!(self, Core::Lstm(_))
    }

    /// Width of the recurrent state (0 for a feed-forward core).
    pub fn state_width(&self) -> i64 {
        match self {
            Core::Lstm(l) => l.hidden(),
            Core::Ff(..) => 0,
        }
    }

    /// Width of the output `H`.
    pub fn out_width(&self) -> i64 {
        match self {
            Core::Lstm(l) => l.hidden(),
            Core::Ff(_, w) => *w,
        }
    }

    /// Zero state for `batch` sequences.
    pub fn zero_state(&self, batch: i64, kind: Kind, device: Device) -> RecState {
        RecState::zeros(batch, self.state_width(), kind, device)
    }

    /// `x [B, T, in]` from state `s` -> (`[B, T, H]`, final state). Feed-forward: per step,
    /// the state passes through.
    pub fn seq(&self, x: &Tensor, s: &RecState) -> (Tensor, RecState) {
        match self {
            Core::Lstm(l) => l.seq(x, s),
            Core::Ff(fc, _) => (fc.forward(x).relu(), s.shallow_clone()),
        }
    }

    /// One step for a batch: `x [N, in]` from `s` (`[1, N, Hs]`) -> (`[N, H]`, next state).
    /// Recurrent cores use [`Lstm::cell`].
    pub fn step(&self, x: &Tensor, s: &RecState) -> (Tensor, RecState) {
        match self {
            Core::Lstm(l) => {
                let (h, c) = l.cell(x, &s.h.squeeze_dim(0), &s.c.squeeze_dim(0));
                (
                    h.shallow_clone(),
                    RecState {
                        h: h.unsqueeze(0),
                        c: c.unsqueeze(0),
                    },
                )
            }
            Core::Ff(fc, _) => (fc.forward(x).relu(), s.shallow_clone()),
        }
    }

    /// Like [`Core::seq`], one step at a time, also returning the state *before* each step:
    /// `(out [B, T, H], h_before [B, T, Hs], c_before [B, T, Hs], final state)`, for runs
    /// without gradient that need both the outputs and the carried states.
    pub fn stepwise(&self, x: &Tensor, s: &RecState) -> (Tensor, Tensor, Tensor, RecState) {
        let t_len = x.size()[1];
        let (ha, ca) = self.states_after(x, s);
        let before = |first: &Tensor, after: &Tensor| {
            Tensor::cat(&[first.transpose(0, 1), after.narrow(1, 0, t_len - 1)], 1)
        };
        let out = match self {
            Core::Lstm(_) => ha.shallow_clone(), // an LSTM's output is its hidden state
            Core::Ff(fc, _) => fc.forward(x).relu(),
        };
        let fin = RecState {
            h: ha.select(1, t_len - 1).unsqueeze(0),
            c: ca.select(1, t_len - 1).unsqueeze(0),
        };
        (out, before(&s.h, &ha), before(&s.c, &ca), fin)
    }

    /// The states after each of the `T` steps of `x [B, T, in]` from `s`, `(h, c)` each
    /// `[B, T, Hs]` (no gradient). Feed-forward cores: zero-width.
    pub fn states_after(&self, x: &Tensor, s: &RecState) -> (Tensor, Tensor) {
        self.states_from(x, s, x.size()[1], false)
    }

    /// The states before each of the `T` steps of `x [B, T, in]` from `s`, `(h, c)` each
    /// `[B, T, Hs]` (no gradient; `T - 1` steps computed). Feed-forward cores: zero-width.
    pub fn states_before(&self, x: &Tensor, s: &RecState) -> (Tensor, Tensor) {
        self.states_from(x, s, x.size()[1] - 1, true)
    }

    /// The states after `steps` steps of `x` from `s`, stacked on dim 1, preceded by `s` itself
    /// with `with_first`; zero-width of the same length for a feed-forward core.
    fn states_from(
        &self,
        x: &Tensor,
        s: &RecState,
        steps: i64,
        with_first: bool,
    ) -> (Tensor, Tensor) {
        let (h0, c0) = (s.h.squeeze_dim(0), s.c.squeeze_dim(0)); // [B, Hs]
        match self {
            Core::Lstm(l) => {
                let after = l.cells(x, &h0, &c0, steps);
                let first = with_first.then_some((&h0, &c0));
                let all = || first.into_iter().chain(after.iter().map(|(h, c)| (h, c)));
                let hs: Vec<&Tensor> = all().map(|(h, _)| h).collect();
                let cs: Vec<&Tensor> = all().map(|(_, c)| c).collect();
                (Tensor::stack(&hs, 1), Tensor::stack(&cs, 1))
            }
            Core::Ff(..) => {
                let t_len = steps + i64::from(with_first);
                let z = h0.unsqueeze(1).expand([-1, t_len, -1], false).copy();
                (z.shallow_clone(), z)
            }
        }
    }
}

/// The state after exactly `scan_len[n]` real steps of window `n` from `init`: the scan
/// inputs `x [N, s, in]` are left-padded (the last `scan_len[n]` steps are real) and the
/// padding never enters the state. `method` chooses how (see [`ScanMethod`]). Feed-forward
/// cores and `s = 0` return `init`.
pub fn scan_state(
    core: &Core,
    x: &Tensor,
    scan_len: &[usize],
    init: &RecState,
    method: ScanMethod,
) -> RecState {
    let s = x.size()[1] as usize;
    if !core.is_recurrent() || s == 0 {
        return init.shallow_clone();
    }
    match method {
        ScanMethod::Grouped => {
            if scan_len.iter().all(|&k| k == s) {
                return core.seq(x, init).1; // the common case: one fused call
            }
            // Windows grouped by their scan length k: one fused call per group over its last k
            // (real) steps. Windows with no real scan step keep `init`.
            let (mut h, mut c) = (init.h.copy(), init.c.copy());
            let mut lengths: Vec<usize> = scan_len.iter().copied().filter(|&k| k > 0).collect();
            lengths.sort_unstable();
            lengths.dedup();
            for k in lengths {
                let group: Vec<i64> = (0..scan_len.len())
                    .filter(|&i| scan_len[i] == k)
                    .map(|i| i as i64)
                    .collect();
                let it = Tensor::from_slice(&group).to_device(x.device());
                let st0 = RecState {
                    h: init.h.index_select(1, &it),
                    c: init.c.index_select(1, &it),
                };
                let xk = x.index_select(0, &it).narrow(1, (s - k) as i64, k as i64);
                let (_, st) = core.seq(&xk, &st0);
                h = h.index_copy(1, &it, &st.h);
                c = c.index_copy(1, &it, &st.c);
            }
            RecState { h, c }
        }
        ScanMethod::MaskedLoop => masked_cell_loop(core, x, scan_len, init),
    }
}

/// The scan as a loop of LSTM cell steps over `x [m, s, in]`, keeping each window's state
/// unchanged (`where`) while it is still in its left padding. Steps before the longest real
/// scan are skipped.
fn masked_cell_loop(core: &Core, x: &Tensor, scan_len: &[usize], init: &RecState) -> RecState {
    let (m, s) = (x.size()[0], x.size()[1] as usize);
    let longest = scan_len.iter().copied().max().unwrap_or(0);
    let real: Vec<u8> = scan_len
        .iter()
        .flat_map(|&k| (0..s).map(move |t| u8::from(t >= s - k)))
        .collect();
    let real = Tensor::from_slice(&real)
        .view([m, s as i64])
        .to_device(x.device())
        .to_kind(Kind::Bool);
    let mut st = init.shallow_clone();
    for t in (s - longest) as i64..s as i64 {
        let (_, next) = core.step(&x.select(1, t), &st);
        let keep = real.select(1, t).view([1, m, 1]);
        st = RecState {
            h: next.h.where_self(&keep, &st.h),
            c: next.c.where_self(&keep, &st.c),
        };
    }
    st
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stepwise_matches_fused() {
        tch::manual_seed(1);
        let vs = nn::VarStore::new(Device::Cpu);
        let l = Lstm::new(&vs.root(), 5, 6);
        let x = Tensor::randn([2, 4, 5], (Kind::Float, Device::Cpu));
        let h0 = RecState {
            h: Tensor::randn([1, 2, 6], (Kind::Float, Device::Cpu)),
            c: Tensor::randn([1, 2, 6], (Kind::Float, Device::Cpu)),
        };
        let (out, fin) = l.seq(&x, &h0);
        let core = Core::Lstm(l);
        let (out2, hb, cb, fin2) = core.stepwise(&x, &h0);
        assert!(out.allclose(&out2, 1e-5, 1e-6, false));
        assert!(fin.c.allclose(&fin2.c, 1e-5, 1e-6, false));
        // The state before step t+1 is the output of step t.
        assert!(hb
            .narrow(1, 1, 3)
            .allclose(&out.narrow(1, 0, 3), 1e-5, 1e-6, false));
        assert!(cb
            .select(1, 0)
            .allclose(&h0.c.squeeze_dim(0), 0.0, 0.0, false));
    }

    /// The no-gradient runs (`stepwise`, `states_before`: input projection hoisted out of the
    /// loop, gate arithmetic by hand) equal libtorch's `lstm_cell` step after step to rounding
    /// (f64: 1e-12), and so does `states_before` (`stepwise`'s states before each step).
    #[test]
    fn hoisted_cells_equal_lstm_cell_steps() {
        tch::manual_seed(2);
        let mut vs = nn::VarStore::new(Device::Cpu);
        let l = Lstm::new(&vs.root(), 5, 6);
        vs.double();
        let opts = (Kind::Double, Device::Cpu);
        let x = Tensor::randn([3, 7, 5], opts);
        let s = RecState {
            h: Tensor::randn([1, 3, 6], opts),
            c: Tensor::randn([1, 3, 6], opts),
        };
        let (mut h, mut c) = (s.h.squeeze_dim(0), s.c.squeeze_dim(0));
        let (mut outs, mut hs, mut cs) = (vec![], vec![], vec![]);
        for t in 0..7 {
            hs.push(h.shallow_clone());
            cs.push(c.shallow_clone());
            (h, c) = l.cell(&x.select(1, t), &h, &c);
            outs.push(h.shallow_clone());
        }
        let core = Core::Lstm(l);
        let (out, hb, cb, fin) = tch::no_grad(|| core.stepwise(&x, &s));
        let close = |a: &Tensor, b: &Tensor| a.allclose(b, 1e-12, 1e-12, false);
        assert!(close(&out, &Tensor::stack(&outs, 1)));
        assert!(close(&hb, &Tensor::stack(&hs, 1)));
        assert!(close(&cb, &Tensor::stack(&cs, 1)));
        assert!(close(&fin.c.squeeze_dim(0), &c));
        let (hb2, cb2) = tch::no_grad(|| core.states_before(&x, &s));
        assert!(close(&hb2, &hb) && close(&cb2, &cb));
    }
}
