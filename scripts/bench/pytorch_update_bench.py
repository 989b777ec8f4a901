#!/usr/bin/env python3
"""The RDPG update of crates/rdpg-agents (src/rdpg.rs) written in PyTorch, to compare update
throughput with the tch implementation (`cargo run --release -p rdpg-agents --example
bench_update`). Same networks (lidar conv trunk, LSTM 256 actor, LSTM 320 critic with a 64-wide
action branch), same scans, same losses, same order of operations:

1. scan (no grad): actor and critic LSTMs over the s scan steps from zero;
2. actor along the window without grad, one LSTM cell step at a time (states before every
   step kept),
   tail action mu(o_tail); critic forward with grad over l + 1 steps (the tail slot holds
   mu(o_tail)), tail-step bootstrap targets, weighted squared TD loss, Adam (L2 1e-5);
3. critic rescan after its step (no grad) + its states along the replayed actions; actor loss
   from every step's detached previous state in one batched LSTM cell call over N * l,
   through the frozen critic (also one cell step); Adam.

Full windows (scan_len = s, opt_len = l), synthetic data. Prints one JSON line:
{"impl": "pytorch", ..., "updates_per_sec": X, "ms": {...phases...}}.

Usage: python scripts/bench/pytorch_update_bench.py [--scan 24] [--batch 64] [--opt 8] [--iters 30]
       [--threads 2] [--old-critic] [--device cpu|cuda]
"""

import argparse
import json
import time

import torch
import torch.nn as nn
import torch.nn.functional as F

OBS, ACT, LIDAR = 24, 4, 10


class Trunk(nn.Module):
    """Lidar: conv1d(1->64, k3) + ReLU + maxpool(2) + FC 64 + ReLU; body: FC 14->192 + ReLU."""

    def __init__(self, ch=64, k=3, lidar_fc=64, body_fc=192):
        super().__init__()
        self.conv = nn.Conv1d(1, ch, k)
        self.lidar_fc = nn.Linear(ch * ((LIDAR - k + 1) // 2), lidar_fc)
        self.body_fc = nn.Linear(OBS - LIDAR, body_fc)

    def forward(self, obs):  # [..., D] -> [..., 256]
        lead = obs.shape[:-1]
        o = obs.reshape(-1, OBS)
        lidar = o[:, OBS - LIDAR:].unsqueeze(1)
        l_ = F.max_pool1d(F.relu(self.conv(lidar)), 2).flatten(1)
        l_ = F.relu(self.lidar_fc(l_))
        b = F.relu(self.body_fc(o[:, : OBS - LIDAR]))
        return torch.cat([l_, b], 1).reshape(*lead, -1)


def head(in_dim, out_dim):
    h = nn.Linear(in_dim, out_dim)
    nn.init.uniform_(h.weight, -3e-3, 3e-3)
    nn.init.uniform_(h.bias, -3e-3, 3e-3)
    return h


class Actor(nn.Module):
    def __init__(self, hidden=256):
        super().__init__()
        self.trunk = Trunk()
        self.lstm = nn.LSTM(256, hidden, batch_first=True)
        self.head = head(hidden, ACT)

    def act(self, y):
        return torch.tanh(self.head(y))


class Critic(nn.Module):
    def __init__(self, hidden=320, act_fc=64):
        super().__init__()
        self.trunk = Trunk()
        self.act_fc = nn.Linear(ACT, act_fc)
        self.lstm = nn.LSTM(256 + act_fc, hidden, batch_first=True)
        self.head = head(hidden, 1)

    def inp(self, obs, act):
        return torch.cat([self.trunk(obs), F.relu(self.act_fc(act))], -1)

    def q(self, y):
        return self.head(y).squeeze(-1)


def cell(lstm, x, h, c):
    """One LSTM step with torch.lstm_cell on the module's weights (as Lstm::cell in nets.rs)."""
    return torch.lstm_cell(x, (h, c), lstm.weight_ih_l0, lstm.weight_hh_l0, lstm.bias_ih_l0, lstm.bias_hh_l0)


def stepwise(lstm, x, h0):
    """One cell step at a time; returns outputs and the states before every step."""
    h, c = h0[0][0], h0[1][0]
    outs, hs, cs = [], [], []
    for t in range(x.shape[1]):
        hs.append(h)
        cs.append(c)
        h, c = cell(lstm, x[:, t], h, c)
        outs.append(h)
    return torch.stack(outs, 1), torch.stack(hs, 1), torch.stack(cs, 1)


def sync(dev):
    if dev.type == "cuda":
        torch.cuda.synchronize()


def build(n, s, l, dev, old_critic=False, gamma=0.99):
    """Networks, optimisers and the update of full windows of s + l steps (batch of n).

    Returns (actor, update, phases): update((obs [n,s+l+1,OBS], act [n,s+l,ACT], rew [n,s+l]),
    timed) runs one update and returns the losses; phases accumulates per-phase seconds."""
    actor, critic = Actor().to(dev), Critic().to(dev)
    opt_a = torch.optim.Adam(actor.parameters(), lr=1e-3)
    opt_c = torch.optim.Adam(critic.parameters(), lr=1e-3, weight_decay=1e-5)
    # Full windows: tail at slot l, weights uniform over l steps, not terminated.
    onehot = torch.zeros(n, l + 1, device=dev)
    onehot[:, l] = 1
    mask = torch.ones(n, l, device=dev)
    k = torch.arange(l, device=dev)
    disc = torch.where(k[:, None] >= k[None, :], gamma ** (k[:, None] - k[None, :]).float(), 0.0)
    boot_coef = gamma ** (l - k).float().expand(n, l)
    critic_w = torch.full((n, l), 1.0 / l, device=dev)
    actor_w = torch.full((n, l), 1.0 / l, device=dev)
    phases = dict(scan=0.0, window_nograd=0.0, critic_step=0.0, critic_rescan=0.0, actor_step=0.0)

    def update(b, timed):
        obs, act, rew = b
        t0 = time.perf_counter()
        lap = [t0]

        def tick(name):
            if timed:
                sync(dev)
                now = time.perf_counter()
                phases[name] += now - lap[0]
                lap[0] = now

        obs_scan, act_scan = obs[:, :s], act[:, :s]
        obs_win, act_win, r = obs[:, s:], act[:, s:], rew[:, s:]
        za = (torch.zeros(1, n, 256, device=dev), torch.zeros(1, n, 256, device=dev))
        zc = (torch.zeros(1, n, 320, device=dev), torch.zeros(1, n, 320, device=dev))
        # 1. scan
        with torch.no_grad():
            ha = actor.lstm(actor.trunk(obs_scan), za)[1] if s > 0 else za
            hc = critic.lstm(critic.inp(obs_scan, act_scan), zc)[1] if s > 0 else zc
        tick("scan")
        # 2a. actor along the window, step by step, no grad
        with torch.no_grad():
            ya, hb, cb = stepwise(actor.lstm, actor.trunk(obs_win), ha)
            a_tail = (actor.act(ya) * onehot.unsqueeze(-1)).sum(1)
            hb, cb = hb[:, :l], cb[:, :l]
        tick("window_nograd")
        # 2b. critic with grad over l + 1 (tail slot = mu(o_tail))
        ext = torch.cat([act_win, torch.zeros(n, 1, ACT, device=dev)], 1)
        oh = onehot.unsqueeze(-1)
        ext = ext * (1 - oh) + a_tail.unsqueeze(1) * oh
        q = critic.q(critic.lstm(critic.inp(obs_win, ext), hc)[0])
        q_tail = (q * onehot).sum(1).detach()
        with torch.no_grad():
            y = (r * mask) @ disc + boot_coef * q_tail.unsqueeze(1)
        q_sa = q[:, :l]
        closs = (critic_w * (y - q_sa) ** 2).sum() / n
        opt_c.zero_grad()
        closs.backward()
        if old_critic:
            with torch.no_grad():
                _, hcb, ccb = stepwise(critic.lstm, critic.inp(obs_win[:, :l], act_win), hc)
        else:
            opt_c.step()
        tick("critic_step")
        if not old_critic:
            with torch.no_grad():
                hc2 = critic.lstm(critic.inp(obs_scan, act_scan), zc)[1] if s > 0 else zc
                _, hcb, ccb = stepwise(critic.lstm, critic.inp(obs_win[:, :l], act_win), hc2)
        tick("critic_rescan")
        # 3. actor, per-step from detached states, through the frozen critic
        for p_ in critic.parameters():
            p_.requires_grad_(False)
        o = obs_win[:, :l].reshape(n * l, OBS)
        ya2, _ = cell(actor.lstm, actor.trunk(o), hb.reshape(n * l, -1), cb.reshape(n * l, -1))
        act_new = actor.act(ya2)
        yc, _ = cell(critic.lstm, critic.inp(o, act_new), hcb.reshape(n * l, -1), ccb.reshape(n * l, -1))
        qa = critic.q(yc).reshape(n, l)
        aloss = -(qa * actor_w).sum() / n
        opt_a.zero_grad()
        aloss.backward()
        for p_ in critic.parameters():
            p_.requires_grad_(True)
        if old_critic:
            opt_c.step()
        opt_a.step()
        tick("actor_step")
        return closs.item(), aloss.item()

    return actor, update, phases


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--scan", type=int, default=24)
    ap.add_argument("--batch", type=int, default=64)
    ap.add_argument("--opt", type=int, default=8)
    ap.add_argument("--iters", type=int, default=30)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--old-critic", action="store_true")
    ap.add_argument("--device", default="cpu")
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    torch.manual_seed(0)
    dev = torch.device(a.device)
    n, s, l = a.batch, a.scan, a.opt
    _, update, phases = build(n, s, l, dev, a.old_critic)

    def batch():
        obs = torch.randn(n, s + l + 1, OBS, device=dev)
        obs[..., OBS - LIDAR:] = torch.rand(n, s + l + 1, LIDAR, device=dev)
        act = torch.rand(n, s + l, ACT, device=dev) * 2 - 1
        rew = torch.randn(n, s + l, device=dev) * 0.1
        return obs, act, rew

    batches = [batch() for _ in range(4)]

    for i in range(3):
        update(batches[i % 4], False)
    sync(dev)
    t0 = time.perf_counter()
    for i in range(a.iters):
        update(batches[i % 4], True)
    sync(dev)
    secs = time.perf_counter() - t0
    print(
        json.dumps(
            {
                "impl": "pytorch",
                "torch": torch.__version__,
                "device": a.device,
                "threads": a.threads,
                "batch": n,
                "scan": s,
                "opt": l,
                "updated_critic": not a.old_critic,
                "updates_per_sec": round(a.iters / secs, 2),
                "ms": {k_: round(v * 1000 / a.iters, 1) for k_, v in phases.items()},
            }
        )
    )


if __name__ == "__main__":
    main()
