//! TQC's truncated quantile critics (Kuznetsov et al. 2020, "Controlling Overestimation Bias
//! with Truncated Mixture of Continuous Distributional Quantile Critics"), the critic option
//! of soft actor-critic (`sac.tqc`), on RDPG's windows and tail-step bootstrap. `sac.rs` calls
//! these in its steps 2 and 3; the update still reads top to bottom there.
//!
//! Each of the `C` critics (one, or two with `twin_critic`) outputs `M` atoms
//! `z_1..z_M` of the return's distribution at quantile levels `tau_m = (2m - 1) / 2M`; its value
//! is their mean. With `K = C (M - d)`:
//!
//! * **Target** (the paper's Eq. (10), with the soft value and RDPG's tail-step bootstrap):
//!   pool the `C M` atoms of the target critics at `(o_tail, a_tail)`, sort them, keep the
//!   `K` smallest (drop `d` per critic from the top), subtract `alpha log pi(a_tail | o_tail)`;
//!   window step `i` gets the `K` atoms
//!   `y_{i,k} = sum_{j=i}^{len-1} gamma^{j-i} r_j + gamma^{len-i} (1 - term) z_(k)`.
//! * **Critic loss** (Eq. (11)): for each critic and step, the quantile Huber loss
//!   `1/(K M) sum_m sum_k |tau_m - 1{y_k < z_m}| L_1(y_k - z_m)` (`L_1` the Huber loss with
//!   threshold 1), weighted over the window as RDPG's squared error and summed over critics.
//! * **Actor** (Eq. (12)): `alpha log pi(a~ | o) - 1/(C M) sum_c sum_m z^c_m(o, a~)`, the mean
//!   of every atom of every critic in place of SAC's min over two.

use tch::Tensor;

use super::lstm::RecState;
use super::nets::Critic;
use super::prepared::Prepared;
use super::update::weighted_window_sum;

/// The atoms of `critic` on the steps the loss trains, the first `u` of the window
/// (`[N, u, M]`), from its scanned state.
pub(super) fn trained_atoms(critic: &Critic, p: &Prepared, h: &RecState) -> Tensor {
    let (obs, act) = (p.obs_win.narrow(1, 0, p.u), p.act_win.narrow(1, 0, p.u));
    critic.atoms_seq(&obs, &act, h).0
}

/// The truncated soft targets `[N, l, K]` from each target critic's atoms at the tail
/// (`[N, M]` each), `log pi(a_tail | o_tail)` `[N]` and `alpha`; zero on padding steps.
pub(super) fn truncated_targets(
    p: &Prepared,
    atoms: &[Tensor],
    logp_tail: &Tensor,
    alpha: f64,
    drop_per_critic: usize,
) -> Tensor {
    let pooled = Tensor::cat(atoms, 1); // [N, C*M]
    let kept = pooled.size()[1] - (drop_per_critic * atoms.len()) as i64;
    let (sorted, _) = pooled.sort(1, false);
    let z = sorted.narrow(1, 0, kept) - (logp_tail * alpha).unsqueeze(1); // [N, K]
    let z = z * p.not_term.unsqueeze(1);
    let returns = (&p.rew * &p.mask).matmul(&p.disc); // [N, l]
    returns.unsqueeze(2) + p.boot_coef.unsqueeze(2) * z.unsqueeze(1) // [N, l, K]
}

/// One critic's quantile Huber loss on its trained steps' atoms `z [N, u, M]` towards the
/// targets `y [N, l, K]`, weighted over the window as the squared error is
/// ([`weighted_window_sum`]).
pub(super) fn quantile_huber_loss(p: &Prepared, z: &Tensor, y: &Tensor) -> Tensor {
    let u = z.size()[1];
    weighted_window_sum(p, quantile_huber(z, &y.narrow(1, 0, u)))
}

/// The quantile Huber loss of atoms `z [.., M]` towards target atoms `y [.., K]`:
/// `1/(K M) sum_m sum_k |tau_m - 1{y_k < z_m}| L_1(y_k - z_m)`, `[..]`. Minimised over `z`,
/// atom `m` is the `tau_m` quantile of `y` (`tau_m = (2m - 1) / 2M`).
pub(super) fn quantile_huber(z: &Tensor, y: &Tensor) -> Tensor {
    let m = z.size()[z.dim() - 1];
    let delta = y.unsqueeze(-2) - z.unsqueeze(-1); // [.., M, K]
    let abs = delta.abs();
    let huber = (delta.square() * 0.5).where_self(&abs.le(1.0), &(&abs - 0.5));
    let tau = (Tensor::arange(m, (z.kind(), z.device())) * 2.0 + 1.0) / (2 * m) as f64;
    let below = delta.lt(0.0).to_kind(z.kind()); // 1{y_k < z_m}
    let weight = (tau.unsqueeze(-1) - below).abs(); // [M, 1] against [.., M, K]
    (weight * huber).mean_dim(&[-2i64, -1][..], false, z.kind())
}

/// The actor's critic term: the mean over critics (TQC) or their minimum (SAC) of each
/// critic's value `[B]`.
pub(super) fn combine_critics(values: &[Tensor], tqc: bool) -> Tensor {
    if !tqc {
        return super::update::min_all(values);
    }
    let stacked = Tensor::stack(values, 0); // [C, B]
    stacked.mean_dim(0, false, stacked.kind())
}

#[cfg(test)]
mod tests {
    use super::*;
    use tch::{nn, nn::OptimizerConfig, Kind};

    /// Minimising the loss over the atoms puts atom `m` at the `(2m - 1) / 2M` quantile of
    /// the targets: on 1000 evenly spread targets in [0, 100], the five atoms go to 10, 30,
    /// 50, 70 and 90 (a flipped indicator or level would order or place them otherwise).
    #[test]
    fn the_atoms_converge_to_the_targets_quantiles() {
        let y = Tensor::linspace(0.0, 100.0, 1000, (Kind::Double, tch::Device::Cpu));
        let vs = nn::VarStore::new(tch::Device::Cpu);
        let z = vs.root().zeros("z", &[5]).to_kind(Kind::Double);
        let z = vs.root().var_copy("atoms", &z);
        let mut opt = nn::Adam::default().build(&vs, 0.5).unwrap();
        for _ in 0..3000 {
            let loss = quantile_huber(&z, &y);
            opt.zero_grad();
            loss.backward();
            opt.step();
        }
        let got: Vec<f64> = Vec::<f64>::try_from(&z.to_kind(Kind::Double)).unwrap();
        for (g, want) in got.iter().zip([10.0, 30.0, 50.0, 70.0, 90.0]) {
            assert!((g - want).abs() < 0.5, "atoms {got:?}");
        }
    }
}
