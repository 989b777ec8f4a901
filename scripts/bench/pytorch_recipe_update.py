#!/usr/bin/env python3
"""The update of a recurrent TD3-family recipe (configs/walker-rdpg.toml, memory-rdpg.toml) or
a recurrent SAC recipe (configs/memory-sac.toml, hardcore-sac-paper.toml: ``algo = "sac"``)
written in PyTorch, to compare with ``rdpg bench update --config FILE``. It reads the same TOML
file and builds the same networks and update, op for op as rdpg-agents runs it (SAC: as
``build_sac`` says; TD3 family:)

* networks: MLP trunk (ReLU after every layer) -> LSTM -> head (tanh for the actor); the critic
  reads observation ++ action at its trunk's input (``critic_action_fc = 0``); twin critics;
  target copies of all networks;
* 1. scan (no grad), ``s`` steps: actor and target actor from the acting-time state stored in
  the replay (random here, as rdpg's synthetic batch), critics and target critics from zeros;
* 2a. (no grad) the behaviour actor along the window one LSTM cell step at a time (its states
  before every step are kept), the target actor along the window for ``mu'(o_tail)``, clipped
  Gaussian smoothing noise, each target critic along the window with ``mu'(o_tail)`` at the
  tail slot, the minimum of the two;
* 2b. tail-step bootstrap targets, each critic along the window with gradient, the summed
  weighted squared TD loss, one backward, Adam;
* 3. on every ``policy_delay``-th update: critic 0's states along the window (cell steps) from
  its scan redone after its step (``actor_uses_updated_critic``, the default) or from its scan
  before the step, the actor loss from every step's detached previous state in
  one batched LSTM cell over ``N * l`` rows through the frozen critic (one cell step), Adam;
  soft update of the targets (``lerp_``).

Full windows, synthetic data. Prints one JSON line:
{"impl": "pytorch", ..., "updates_per_sec": X, "ms": {...phases...}}.

Usage: .venv/bin/python scripts/bench/pytorch_recipe_update.py --config configs/walker-rdpg.toml
       [--iters 200] [--threads 1] [--obs 24 --act 4]
"""

import argparse
import json
import math
import time
import tomllib

import torch
import torch.nn as nn
import torch.nn.functional as F


def mlp(sizes):
    layers = []
    for i, o in zip(sizes[:-1], sizes[1:]):
        layers += [nn.Linear(i, o), nn.ReLU()]
    return nn.Sequential(*layers)


class Net(nn.Module):
    """Trunk (MLP, ReLU) -> LSTM -> linear head."""

    def __init__(self, inp, trunk, hidden, out):
        super().__init__()
        self.trunk = mlp([inp] + trunk)
        self.lstm = nn.LSTM(trunk[-1], hidden, batch_first=True)
        self.head = nn.Linear(hidden, out)


def cell(lstm, x, h, c):
    """One LSTM step with torch.lstm_cell on the module's weights (rdpg's Lstm::cell)."""
    return torch.lstm_cell(x, (h, c), lstm.weight_ih_l0, lstm.weight_hh_l0, lstm.bias_ih_l0, lstm.bias_hh_l0)


def stepwise(lstm, x, h, c, final=False):
    """One cell step at a time; returns the states before every step (and with ``final`` the
    state after the last)."""
    hs, cs = [], []
    for t in range(x.shape[1]):
        hs.append(h)
        cs.append(c)
        h, c = cell(lstm, x[:, t], h, c)
    if final:
        return torch.stack(hs, 1), torch.stack(cs, 1), h
    return torch.stack(hs, 1), torch.stack(cs, 1)


# RdpgConfig's defaults for the fields a config may leave out.
DEFAULTS = dict(gamma=0.99, lr_actor=1e-3, lr_critic=1e-3, critic_l2=1e-5, batch_size=64, opt_len=8,
                scan_len=24, tau=0.0, policy_delay=1, actor_uses_updated_critic=True,
                actor_hidden=256, critic_hidden=320, critic_action_fc=64, recurrent=True)


def window_consts(n, l, gamma):
    """Full windows' tail one-hot ``[N, l+1]``, ``disc[k, i] = gamma^(k-i)`` for ``k >= i``,
    the bootstrap coefficients ``gamma^(l-i)`` and the actor's weights ``1/l`` (``[N, l]``)."""
    onehot = torch.zeros(n, l + 1)
    onehot[:, l] = 1
    k = torch.arange(l)
    disc = torch.where(k[:, None] >= k[None, :], gamma ** (k[:, None] - k[None, :]).float(), 0.0)
    boot_coef = (gamma ** (l - k).float()).expand(n, l)
    return onehot, disc, boot_coef, torch.full((n, l), 1.0 / l)


def q_seq(c, obs, act, state):
    """A critic's Q along a sequence, ``[N, T]``."""
    y, _ = c.lstm(c.trunk(torch.cat([obs, act], -1)), state)
    return c.head(y).squeeze(-1)


def stopwatch(phases, timed):
    """``tick(name)`` charges the time since the last tick to ``phases[name]`` (when timed)."""
    lap = [time.perf_counter()]

    def tick(name):
        if timed:
            now = time.perf_counter()
            phases[name] += now - lap[0]
            lap[0] = now

    return tick


def sample(out, act_dim, eps):
    """A squashed-Gaussian sample from the actor's head output ``[mean, log_std]`` and its
    log-probability with the tanh correction (rdpg's ``sac::squashed_sample``)."""
    m, log_s = out[:, :act_dim], out[:, act_dim:].clamp(-20.0, 2.0)
    u = m + log_s.exp() * eps
    log_normal = -0.5 * eps**2 - log_s - 0.5 * math.log(2 * math.pi)
    log_det = 2 * (math.log(2) - u - F.softplus(-2 * u))
    return torch.tanh(u), (log_normal - log_det).sum(-1)


def build_sac(ag, obs_dim, act_dim):
    """SAC's update as ``rdpg-agents/src/rdpg/sac.rs`` runs it: 1. scans of the actor (from the
    stored state), the critics and the target critics; 2. the actor along the window one cell
    step at a time (its states and its output at the tail), a sample at the tail, the target
    critics along the window with it at the tail slot, ``min Q' - alpha log pi``, tail-step
    targets, the critics' loss, Adam; 3. both critics rescanned and run along the window, the
    actor's loss from every step's detached state through the minimum of both critics, Adam;
    4. the temperature's Adam step; 5. soft update of the target critics."""
    trunk = ag["trunk"]["mlp"]["hidden"]
    n, s, l = ag["batch_size"], ag["scan_len"], ag["opt_len"]
    gamma, tau = ag["gamma"], ag["tau"]
    ha, hc = ag["actor_hidden"], ag["critic_hidden"]
    actor = Net(obs_dim, trunk, ha, 2 * act_dim)
    critics = [Net(obs_dim + act_dim, trunk, hc, 1) for _ in range(2)]
    t_critics = [Net(obs_dim + act_dim, trunk, hc, 1) for _ in range(2)]
    for t, m in zip(t_critics, critics):
        t.load_state_dict(m.state_dict())
        t.requires_grad_(False)
    log_alpha = torch.zeros(1, requires_grad=True)
    target_entropy = -float(act_dim)
    opt_a = torch.optim.Adam(actor.parameters(), lr=ag["lr_actor"])
    critic_params = [p for c in critics for p in c.parameters()]
    opt_c = torch.optim.Adam(critic_params, lr=ag["lr_critic"], weight_decay=ag["critic_l2"])
    opt_alpha = torch.optim.Adam([log_alpha], lr=ag.get("sac", {}).get("lr_alpha", 3e-4))
    pairs = [(tp, p) for t, m in zip(t_critics, critics) for tp, p in zip(t.parameters(), m.parameters())]
    onehot, disc, boot_coef, w = window_consts(n, l, gamma)
    phases = dict(scan=0.0, window_nograd=0.0, critic_step=0.0, critic_rescan=0.0, actor_step=0.0, other=0.0)

    def update(b, timed):
        obs, act, rew, stored = b
        tick = stopwatch(phases, timed)

        alpha = log_alpha.detach().exp().item()
        o_scan, a_scan = obs[:, :s], act[:, :s]
        o_win, a_win, r = obs[:, s:], act[:, s:], rew[:, s:]
        st = (stored[:, :ha].unsqueeze(0).contiguous(), stored[:, ha:].unsqueeze(0).contiguous())
        zc = (torch.zeros(1, n, hc), torch.zeros(1, n, hc))
        with torch.no_grad():
            h_a = actor.lstm(actor.trunk(o_scan), st)[1]
            h_c = [c.lstm(c.trunk(torch.cat([o_scan, a_scan], -1)), zc)[1] for c in critics]
            h_tc = [c.lstm(c.trunk(torch.cat([o_scan, a_scan], -1)), zc)[1] for c in t_critics]
        tick("scan")
        with torch.no_grad():
            # States before each of the l + 1 slots' steps, and the output at the tail slot l.
            hb, cb, y_tail = stepwise(actor.lstm, actor.trunk(o_win), h_a[0][0], h_a[1][0], final=True)
            a_tail, logp_tail = sample(actor.head(y_tail), act_dim, torch.randn(n, act_dim))
            hb, cb = hb[:, :l], cb[:, :l]
            ext = torch.cat([a_win, torch.zeros(n, 1, act_dim)], 1)
            oh = onehot.unsqueeze(-1)
            ext = ext * (1 - oh) + a_tail.unsqueeze(1) * oh
            q_tail = torch.minimum(*[(q_seq(c, o_win, ext, h) * onehot).sum(1) for c, h in zip(t_critics, h_tc)])
            y = (r @ disc) + boot_coef * (q_tail - alpha * logp_tail).unsqueeze(1)
        tick("window_nograd")
        closs = sum((w * (y - q_seq(c, o_win[:, :l], a_win, h)) ** 2).sum() / n for c, h in zip(critics, h_c))
        opt_c.zero_grad()
        closs.backward()
        opt_c.step()
        tick("critic_step")
        states = []
        with torch.no_grad():
            for c in critics:
                h0 = c.lstm(c.trunk(torch.cat([o_scan, a_scan], -1)), zc)[1]
                states.append(stepwise(c.lstm, c.trunk(torch.cat([o_win[:, :l], a_win], -1)), h0[0][0], h0[1][0]))
        tick("critic_rescan")
        for c in critics:
            c.requires_grad_(False)
        o = o_win[:, :l].reshape(n * l, -1)
        ya, _ = cell(actor.lstm, actor.trunk(o), hb.reshape(n * l, -1), cb.reshape(n * l, -1))
        a_new, logp = sample(actor.head(ya), act_dim, torch.randn(n * l, act_dim))
        qs = []
        for c, (hcb, ccb) in zip(critics, states):
            yc, _ = cell(c.lstm, c.trunk(torch.cat([o, a_new], -1)), hcb.reshape(n * l, -1), ccb.reshape(n * l, -1))
            qs.append(c.head(yc).squeeze(-1))
        aloss = ((alpha * logp - torch.minimum(*qs)).reshape(n, l) * w).sum() / n
        opt_a.zero_grad()
        aloss.backward()
        for c in critics:
            c.requires_grad_(True)
        opt_a.step()
        mean_logp = (logp.detach().reshape(n, l) * w).sum() / n
        opt_alpha.zero_grad()
        (-(log_alpha * (mean_logp + target_entropy)).sum()).backward()
        opt_alpha.step()
        tick("actor_step")
        with torch.no_grad():
            for tp, p in pairs:
                tp.lerp_(p, tau)
        tick("other")
        return closs.item(), aloss.item()

    return update, phases, (n, s, l, ha)


def build(cfg, obs_dim, act_dim):
    ag = {**DEFAULTS, **cfg["agent"]}
    if cfg.get("algo") == "sac":
        if not ag["recurrent"] or ag["critic_action_fc"] != 0 or not ag.get("twin_critic"):
            raise SystemExit("this script covers recurrent twin-critic SAC with critic_action_fc = 0")
        return build_sac(ag, obs_dim, act_dim)
    trunk = ag["trunk"]["mlp"]["hidden"]
    if not ag["recurrent"] or ag["critic_action_fc"] != 0:
        raise SystemExit("this script covers recurrent agents with critic_action_fc = 0")
    if not (ag.get("twin_critic") and ag["tau"] > 0):
        raise SystemExit("this script covers twin critics with target networks")
    n, s, l = ag["batch_size"], ag["scan_len"], ag["opt_len"]
    gamma, tau = ag["gamma"], ag["tau"]
    noise = ag.get("target_noise")
    delay = ag["policy_delay"]
    updated_critic = ag["actor_uses_updated_critic"]
    ha, hc = ag["actor_hidden"], ag["critic_hidden"]
    actor = Net(obs_dim, trunk, ha, act_dim)
    critics = [Net(obs_dim + act_dim, trunk, hc, 1) for _ in range(2)]
    t_actor = Net(obs_dim, trunk, ha, act_dim)
    t_critics = [Net(obs_dim + act_dim, trunk, hc, 1) for _ in range(2)]
    for t, m in zip([t_actor] + t_critics, [actor] + critics):
        t.load_state_dict(m.state_dict())
        t.requires_grad_(False)
    opt_a = torch.optim.Adam(actor.parameters(), lr=ag["lr_actor"])
    critic_params = [p for c in critics for p in c.parameters()]
    opt_c = torch.optim.Adam(critic_params, lr=ag["lr_critic"], weight_decay=ag["critic_l2"])
    pairs = [
        (tp, p)
        for t, m in zip([t_actor] + t_critics, [actor] + critics)
        for tp, p in zip(t.parameters(), m.parameters())
    ]
    onehot, disc, boot_coef, w = window_consts(n, l, gamma)
    phases = dict(scan=0.0, window_nograd=0.0, critic_step=0.0, critic_rescan=0.0, actor_step=0.0, other=0.0)
    updates = [0]

    def update(b, timed):
        obs, act, rew, stored = b
        tick = stopwatch(phases, timed)

        o_scan, a_scan = obs[:, :s], act[:, :s]
        o_win, a_win, r = obs[:, s:], act[:, s:], rew[:, s:]
        st = (stored[:, :ha].unsqueeze(0).contiguous(), stored[:, ha:].unsqueeze(0).contiguous())
        zc = (torch.zeros(1, n, hc), torch.zeros(1, n, hc))
        # 1. scan
        with torch.no_grad():
            h_a = actor.lstm(actor.trunk(o_scan), st)[1]
            h_c = [c.lstm(c.trunk(torch.cat([o_scan, a_scan], -1)), zc)[1] for c in critics]
            h_ta = t_actor.lstm(t_actor.trunk(o_scan), st)[1]
            h_tc = [c.lstm(c.trunk(torch.cat([o_scan, a_scan], -1)), zc)[1] for c in t_critics]
        tick("scan")
        # 2a. behaviour actor states along the window, target action and value at the tail
        with torch.no_grad():
            hb, cb = stepwise(actor.lstm, actor.trunk(o_win), h_a[0][0], h_a[1][0])
            hb, cb = hb[:, :l], cb[:, :l]
            y_ta, _ = t_actor.lstm(t_actor.trunk(o_win), h_ta)
            a_tail = (torch.tanh(t_actor.head(y_ta)) * onehot.unsqueeze(-1)).sum(1)
            if noise:
                eps = (torch.randn_like(a_tail) * noise["std"]).clamp(-noise["clip"], noise["clip"])
                a_tail = (a_tail + eps).clamp(-1.0, 1.0)
            ext = torch.cat([a_win, torch.zeros(n, 1, act_dim)], 1)
            oh = onehot.unsqueeze(-1)
            ext = ext * (1 - oh) + a_tail.unsqueeze(1) * oh
            q_tail = torch.minimum(*[(q_seq(c, o_win, ext, h) * onehot).sum(1) for c, h in zip(t_critics, h_tc)])
            y = (r @ disc) + boot_coef * q_tail.unsqueeze(1)
        tick("window_nograd")
        # 2b. the critics' TD loss
        closs = sum((w * (y - q_seq(c, o_win[:, :l], a_win, h)) ** 2).sum() / n for c, h in zip(critics, h_c))
        opt_c.zero_grad()
        closs.backward()
        updates[0] += 1
        actor_turn = updates[0] % delay == 0
        if updated_critic or not actor_turn:
            opt_c.step()
        tick("critic_step")
        aloss = None
        if actor_turn:
            c0 = critics[0]
            with torch.no_grad():
                # Algorithm 1's order rescans the stepped critic; otherwise its scan before the
                # step (whose Adam step then waits until after the actor's backward pass).
                h0 = c0.lstm(c0.trunk(torch.cat([o_scan, a_scan], -1)), zc)[1] if updated_critic else h_c[0]
                hcb, ccb = stepwise(c0.lstm, c0.trunk(torch.cat([o_win[:, :l], a_win], -1)), h0[0][0], h0[1][0])
            tick("critic_rescan")
            c0.requires_grad_(False)
            o = o_win[:, :l].reshape(n * l, -1)
            ya, _ = cell(actor.lstm, actor.trunk(o), hb.reshape(n * l, -1), cb.reshape(n * l, -1))
            a_new = torch.tanh(actor.head(ya))
            yc, _ = cell(c0.lstm, c0.trunk(torch.cat([o, a_new], -1)), hcb.reshape(n * l, -1), ccb.reshape(n * l, -1))
            aloss = -(c0.head(yc).reshape(n, l) * w).sum() / n
            opt_a.zero_grad()
            aloss.backward()
            c0.requires_grad_(True)
            if not updated_critic:
                opt_c.step()
            opt_a.step()
            tick("actor_step")
            with torch.no_grad():
                for tp, p in pairs:
                    tp.lerp_(p, tau)
        tick("other")
        return closs.item(), None if aloss is None else aloss.item()

    return update, phases, (n, s, l, ha)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--config", required=True)
    ap.add_argument("--iters", type=int, default=200)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--obs", type=int, default=24, help="observation size (24: BipedalWalker)")
    ap.add_argument("--act", type=int, default=4, help="action size")
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    torch.set_flush_denormal(True)
    torch.manual_seed(0)
    with open(a.config, "rb") as f:
        cfg = tomllib.load(f)
    update, phases, (n, s, l, ha) = build(cfg, a.obs, a.act)

    def batch():
        obs = torch.randn(n, s + l + 1, a.obs)
        act = torch.rand(n, s + l, a.act) * 2 - 1
        rew = torch.randn(n, s + l) * 0.1
        stored = torch.randn(n, 2 * ha) * 0.3
        return obs, act, rew, stored

    batches = [batch() for _ in range(4)]
    for i in range(3):
        update(batches[i % 4], False)
    t0 = time.perf_counter()
    for i in range(a.iters):
        update(batches[i % 4], True)
    secs = time.perf_counter() - t0
    print(
        json.dumps(
            {
                "impl": "pytorch",
                "torch": torch.__version__,
                "config": a.config,
                "threads": a.threads,
                "batch": n,
                "scan": s,
                "opt": l,
                "updates_per_sec": round(a.iters / secs, 2),
                "ms": {k_: round(v * 1000 / a.iters, 2) for k_, v in phases.items()},
            }
        )
    )


if __name__ == "__main__":
    main()
