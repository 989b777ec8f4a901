"""One soft actor-critic update written out in PyTorch: the golden reference of `sac.rs`.

Writes ``tests/fixtures/sac_update.json``: for a feed-forward agent, a recurrent (LSTM) one and
a recurrent one with BPTT in the actor loss, and the feed-forward and LSTM agents with TQC's
truncated quantile critics, the agent's config, its weights before the update,
a batch of windows (scan part, short windows, a terminated tail), the seed of the standard
normal draws, and the weights, losses, temperature and entropy after one update. The Rust test
(`crates/rdpg-agents/src/rdpg/tests/sac.rs`) loads the same weights and batch into an
`RdpgAgent`, draws its noise from the same seed (`NpRng` is numpy's generator, bit for bit) and
must reproduce every number.

This is written per window, step by step, from Haarnoja et al. (2018), "Soft Actor-Critic
Algorithms and Applications", Kuznetsov et al. (2020), "Controlling Overestimation Bias with
Truncated Mixture of Continuous Distributional Quantile Critics" (TQC), and the tail-step
bootstrap of Song et al. (2018): no code is shared with the Rust side.

    .venv/bin/python scripts/reference/sac_update.py
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import torch

torch.set_default_dtype(torch.float64)
OUT = Path(__file__).resolve().parents[2] / "tests" / "fixtures" / "sac_update.json"

OBS, ACT = 3, 2
TRUNK, HID = 5, 4
GAMMA, TAU, L2 = 0.9, 0.1, 0.01
LR_A, LR_C, LR_ALPHA = 0.003, 0.002, 0.01
INIT_ALPHA, TARGET_ENTROPY = 0.5, -1.5
NOISE_SEED = 77
LOG_STD = (-20.0, 2.0)


def make_weights(rng: np.random.Generator, recurrent: bool, atoms: int) -> dict[str, torch.Tensor]:
    """Random weights under the Rust agent's variable names (larger than its init)."""

    def u(*shape):
        return torch.tensor(rng.uniform(-0.6, 0.6, size=shape))

    w: dict[str, torch.Tensor] = {}

    def core(prefix: str, e: int):
        if recurrent:
            w[f"{prefix}.core.lstm.weight_ih_l0"] = u(4 * HID, e)
            w[f"{prefix}.core.lstm.weight_hh_l0"] = u(4 * HID, HID)
            w[f"{prefix}.core.lstm.bias_ih_l0"] = u(4 * HID)
            w[f"{prefix}.core.lstm.bias_hh_l0"] = u(4 * HID)
        else:
            w[f"{prefix}.core.fc.weight"] = u(HID, e)
            w[f"{prefix}.core.fc.bias"] = u(HID)

    w["actor.trunk.fc0.weight"] = u(TRUNK, OBS)
    w["actor.trunk.fc0.bias"] = u(TRUNK)
    core("actor", TRUNK)
    w["actor.head.weight"] = u(2 * ACT, HID)
    w["actor.head.bias"] = u(2 * ACT)
    for c in ("critic", "critic2"):
        w[f"{c}.trunk.fc0.weight"] = u(TRUNK, OBS + ACT)
        w[f"{c}.trunk.fc0.bias"] = u(TRUNK)
        core(c, TRUNK)
        w[f"{c}.head.weight"] = u(atoms, HID)
        w[f"{c}.head.bias"] = u(atoms)
    for name in [n for n in w if n.startswith("critic")]:
        w[f"target.{name}"] = w[name] + u(*w[name].shape) * 0.1
    w["log_alpha"] = torch.tensor([math.log(INIT_ALPHA)])
    return w


class Net:
    """A trunk (FC + ReLU), an LSTM cell or FC + ReLU core, a linear head, by weight names."""

    def __init__(self, w, prefix: str, recurrent: bool):
        self.w, self.p, self.recurrent = w, prefix, recurrent

    def g(self, name):
        return self.w[f"{self.p}.{name}"]

    def trunk(self, x):
        return torch.relu(x @ self.g("trunk.fc0.weight").T + self.g("trunk.fc0.bias"))

    def zero(self):
        return (torch.zeros(HID), torch.zeros(HID))

    def cell(self, x, hc):
        """Core output and next state from the trunk's output `x` and state `hc`."""
        if not self.recurrent:
            return torch.relu(x @ self.g("core.fc.weight").T + self.g("core.fc.bias")), hc
        h, c = hc
        gates = (
            x @ self.g("core.lstm.weight_ih_l0").T
            + self.g("core.lstm.bias_ih_l0")
            + h @ self.g("core.lstm.weight_hh_l0").T
            + self.g("core.lstm.bias_hh_l0")
        )
        i, f, gg, o = gates.chunk(4)
        c = torch.sigmoid(f) * c + torch.sigmoid(i) * torch.tanh(gg)
        h = torch.sigmoid(o) * torch.tanh(c)
        return h, (h, c)

    def head(self, y):
        return y @ self.g("head.weight").T + self.g("head.bias")


class Actor(Net):
    def step(self, o, hc):
        y, hc = self.cell(self.trunk(o), hc)
        out = self.head(y)
        return out[:ACT], out[ACT:].clamp(*LOG_STD), hc


class Critic(Net):
    def atoms(self, o, a, hc):
        """The head's values (one, or TQC's atoms) and the next state."""
        y, hc = self.cell(self.trunk(torch.cat([o, a])), hc)
        return self.head(y), hc

    def step(self, o, a, hc):
        """The value (the atoms' mean) and the next state."""
        z, hc = self.atoms(o, a, hc)
        return z.mean(), hc


def quantile_huber(y, z):
    """TQC's Eq. (11) for one critic at one step: atoms `z` [M] towards targets `y` [K]."""
    m = z.shape[0]
    total = torch.zeros(())
    for j in range(m):
        tau = (2 * j + 1) / (2 * m)
        for yk in y:
            d = yk - z[j]
            huber = 0.5 * d**2 if d.abs() <= 1 else d.abs() - 0.5
            total = total + abs(tau - float(d < 0)) * huber
    return total / (m * y.shape[0])


def sample(m, log_s, eps):
    """a = tanh(m + s eps) and log pi(a) with the tanh correction (Haarnoja et al., Eq. (21))."""
    u = m + log_s.exp() * eps
    log_normal = -0.5 * eps**2 - log_s - 0.5 * math.log(2 * math.pi)
    log_det = torch.log(1 - torch.tanh(u) ** 2)
    return torch.tanh(u), (log_normal - log_det).sum()


def make_batch(rng, n, s, l, scan_len, opt_len, term):
    t = s + l
    obs = np.zeros((n, t + 1, OBS), np.float32)
    act = np.zeros((n, t, ACT), np.float32)
    rew = np.zeros((n, t), np.float32)
    mask = np.zeros((n, t), np.float32)
    for k in range(n):
        real = list(range(s - scan_len[k], s + opt_len[k]))
        for j in real:
            obs[k, j] = rng.normal(size=OBS)
            act[k, j] = rng.uniform(-1, 1, size=ACT)
            rew[k, j] = rng.normal()
            mask[k, j] = 1
        obs[k, s + opt_len[k]] = rng.normal(size=OBS)  # the tail observation
    return {
        "n": n, "scan": s, "opt": l, "obs_dim": OBS, "act_dim": ACT,
        "obs": obs.ravel().tolist(), "actions": act.ravel().tolist(),
        "rewards": rew.ravel().tolist(), "mask": mask.ravel().tolist(),
        "scan_len": scan_len, "opt_len": opt_len,
        "tail_terminated": [float(x) for x in term], "injected": [0.0] * n,
        "stored_state": None, "state_dim": 0,
    }


def adam_step(params, lr, wd):
    opt = torch.optim.Adam(params, lr=lr, betas=(0.9, 0.999), eps=1e-8, weight_decay=wd)
    opt.step()


def update(w, b, cfg, recurrent: bool, bptt: bool):
    """One SAC update on batch `b`, in place on `w`; returns the logged numbers."""
    n, s, l, u_len, lam = b["n"], b["scan"], b["opt"], cfg["update_len"], cfg["lambda"]
    obs = torch.tensor(b["obs"]).view(n, s + l + 1, OBS)
    act = torch.tensor(b["actions"]).view(n, s + l, ACT)
    rew = torch.tensor(b["rewards"]).view(n, s + l)
    noise = np.random.default_rng(NOISE_SEED)
    eps_tail = torch.tensor(noise.standard_normal(size=(n, ACT)))
    eps_actor = torch.tensor(noise.standard_normal(size=(n * l, ACT)))
    alpha = w["log_alpha"].exp().item()
    for t in w.values():
        t.requires_grad_(False)
    actor = Actor(w, "actor", recurrent)
    critics = [Critic(w, c, recurrent) for c in ("critic", "critic2")]
    targets = [Critic(w, f"target.{c}", recurrent) for c in ("critic", "critic2")]
    weights = [lam**i for i in range(u_len)]
    weights = [x / sum(weights) for x in weights]
    tqc = cfg["sac"].get("tqc")

    def scanned_actor(k):
        hc = actor.zero()
        for j in range(s - b["scan_len"][k], s):
            _, _, hc = actor.step(obs[k, j], hc)
        return hc

    def scanned_critic(c, k):
        hc = c.zero()
        for j in range(s - b["scan_len"][k], s):
            _, hc = c.step(obs[k, j], act[k, j], hc)
        return hc

    # Step 2: the soft tail-step bootstrap and the critics' loss.
    ys, actor_states = [], []
    with torch.no_grad():
        for k in range(n):
            ln = b["opt_len"][k]
            hc = scanned_actor(k)
            states = []
            for i in range(ln):
                states.append(hc)
                _, _, hc = actor.step(obs[k, s + i], hc)
            actor_states.append(states)
            m, log_s, _ = actor.step(obs[k, s + ln], hc)
            a_tail, logp_tail = sample(m, log_s, eps_tail[k])
            zs = []
            for t in targets:
                hc = scanned_critic(t, k)
                for i in range(ln):
                    _, hc = t.step(obs[k, s + i], act[k, s + i], hc)
                zs.append(t.atoms(obs[k, s + ln], a_tail, hc)[0])
            if tqc is None:
                v = torch.minimum(zs[0].mean(), zs[1].mean()) - alpha * logp_tail
            else:  # the pooled atoms, sorted, the largest drop_per_critic per critic dropped
                pooled = torch.sort(torch.cat(zs)).values
                v = pooled[: len(pooled) - 2 * tqc["drop_per_critic"]] - alpha * logp_tail
            v = v * (1 - b["tail_terminated"][k])
            y = [sum(GAMMA ** (j - i) * rew[k, s + j] for j in range(i, ln)) + GAMMA ** (ln - i) * v
                 for i in range(ln)]
            ys.append(y)
    critic_params = [w[x] for x in w if x.startswith("critic")]
    for p in critic_params:
        p.requires_grad_(True)
    loss = torch.zeros(())
    for c in critics:
        for k in range(n):
            with torch.no_grad():
                hc = scanned_critic(c, k)  # the scan has no gradient
            for i in range(min(u_len, b["opt_len"][k])):
                if tqc is None:
                    q, hc = c.step(obs[k, s + i], act[k, s + i], hc)
                    loss = loss + weights[i] * (ys[k][i] - q) ** 2
                else:
                    z, hc = c.atoms(obs[k, s + i], act[k, s + i], hc)
                    loss = loss + weights[i] * quantile_huber(ys[k][i], z)
    critic_loss = loss / n
    critic_loss.backward()
    adam_step(critic_params, LR_C, L2)
    for p in critic_params:
        p.requires_grad_(False)

    # Step 3: the actor, through the updated critics' min, from fresh samples.
    actor_params = [w[x] for x in w if x.startswith("actor")]
    for p in actor_params:
        p.requires_grad_(True)
    actor_loss, logps = torch.zeros(()), []
    for k in range(n):
        ln = b["opt_len"][k]
        with torch.no_grad():
            hcs = []
            for c in critics:
                hc, per = scanned_critic(c, k), []
                for i in range(ln):
                    per.append(hc)
                    _, hc = c.step(obs[k, s + i], act[k, s + i], hc)
                hcs.append(per)
        with torch.no_grad():
            hc = scanned_actor(k)  # BPTT: the run along the window (not the scan) has gradient
        for i in range(ln):
            start = hc if bptt else actor_states[k][i]
            m, log_s, hc = actor.step(obs[k, s + i], start)
            a, logp = sample(m, log_s, eps_actor[k * l + i])
            q2 = [critics[j].step(obs[k, s + i], a, hcs[j][i])[0] for j in range(2)]
            q = torch.minimum(*q2) if tqc is None else (q2[0] + q2[1]) / 2
            actor_loss = actor_loss + (alpha * logp - q) / ln
            logps.append(logp.detach() / ln)
    actor_loss = actor_loss / n
    actor_loss.backward()
    adam_step(actor_params, LR_A, 0.0)

    # Step 4: the temperature, in log alpha (Eq. (18) as softlearning steps it).
    mean_logp = sum(logps) / n
    la = w["log_alpha"]
    la.requires_grad_(True)
    (-(la * (mean_logp + TARGET_ENTROPY)).sum()).backward()
    adam_step([la], LR_ALPHA, 0.0)

    # Step 5: the target critics.
    with torch.no_grad():
        for name in [x for x in w if x.startswith("critic")]:
            w[f"target.{name}"] += TAU * (w[name] - w[f"target.{name}"])
    return {
        "critic_loss": critic_loss.item(),
        "actor_loss": actor_loss.item(),
        "alpha": alpha,
        "entropy": -mean_logp.item(),
    }


def case(name, recurrent, bptt, seed, tqc=None):
    rng = np.random.default_rng(seed)
    if recurrent:
        s, l, u = 2, 3, 2
        batch = make_batch(rng, 4, s, l, [2, 1, 0, 2], [3, 2, 1, 3], [0, 1, 0, 0])
    else:
        s, l, u = 0, 2, 2
        batch = make_batch(rng, 3, s, l, [0, 0, 0], [2, 1, 2], [0, 0, 1])
    cfg = {
        "trunk": {"mlp": {"hidden": [TRUNK]}}, "recurrent": recurrent,
        "actor_hidden": HID, "critic_hidden": HID, "critic_action_fc": 0,
        "gamma": GAMMA, "lr_actor": LR_A, "lr_critic": LR_C, "critic_l2": L2,
        "batch_size": batch["n"], "opt_len": l, "update_len": u, "scan_len": s,
        "lambda": 0.8, "tau": TAU, "twin_critic": True, "actor_bptt": bptt,
        "device": "cpu", "num_threads": 1, "flush_denormal": False,
        "sac": {"init_alpha": INIT_ALPHA, "learn_alpha": True,
                "target_entropy": TARGET_ENTROPY, "lr_alpha": LR_ALPHA, "tqc": tqc},
    }
    w = make_weights(rng, recurrent, 1 if tqc is None else tqc["quantiles"])
    before = {k: v.clone().ravel().tolist() for k, v in w.items()}
    logged = update(w, batch, cfg, recurrent, bptt)
    after = {k: v.detach().ravel().tolist() for k, v in w.items()}
    return {"name": name, "config": cfg, "obs_dim": OBS, "act_dim": ACT, "noise_seed": NOISE_SEED,
            "batch": batch, "before": before, "after": after, **logged}


def main():
    tqc = {"quantiles": 3, "drop_per_critic": 1}
    cases = [case("feed-forward", False, False, 1), case("lstm", True, False, 2),
             case("lstm-bptt", True, True, 3), case("tqc-feed-forward", False, False, 4, tqc),
             case("tqc-lstm", True, False, 5, tqc)]
    OUT.write_text(json.dumps({"cases": cases}, indent=None) + "\n")
    print(f"wrote {OUT} ({OUT.stat().st_size} bytes)")


if __name__ == "__main__":
    main()
