"""Trained rdpg agents as PyTorch modules: :func:`to_torch`.

The module acts exactly as the Rust policy (``rdpg.Policy``): the same libtorch operations in
the same order on the same float32 weights, so its actions equal the Rust ones (tested to
1e-6; in practice bit for bit). It takes *full* observations of the agent's environment and
does inside what ``Policy.act`` does around the agent: drops the run's hidden observation
components (``train.hide_obs``), puts the previous action in front of the observation when the
run trained with ``train.prev_action_obs``, stacks the last views with ``train.frame_stack``,
and maps the agent's ``[-1, 1]`` action to the
environment's bounds (clipping first).

The recurrent state is explicit::

    policy = to_torch(agent_dir, config, obs_low, obs_high, act_low, act_high)
    state = policy.initial_state(n)          # n environments at an episode start
    action, state = policy(obs, state)       # obs [n, obs_dim] -> action [n, act_dim]

State layouts (float32 tensors, first dimension the ``n`` environments; ``D`` is the size of
the agent's view: the kept observation components, after the previous action if the run
trained with it). Every layout starts with the previous action:

* feed-forward agents (DDPG, TD3, TD3-FORK, PPO), :class:`FeedForwardPolicy`:
  ``(prev_action [n, act_dim],)``;
* feed-forward agents trained with a frame stack (``train.frame_stack = k``),
  :class:`StackedFeedForwardPolicy`: ``(prev_action, history [n, k - 1, D])``, the agent's
  last ``k - 1`` views, oldest first, zeros before the episode's first;
* recurrent RDPG agents, :class:`LstmPolicy`: ``(prev_action, h [n, H], c [n, H])``, the
  actor LSTM's hidden and cell state;
* window-of-k RDPG agents (``agent.act_window = k``), :class:`WindowPolicy`:
  ``(prev_action, history [n, k - 1, D], count [n])``: the agent's last ``k - 1`` views,
  oldest first, left-padded with zeros, and how many of them are real (0 to ``k - 1``, as
  float32);
* recurrent agents trained with a frame stack of ``s`` (the LSTM or the window reads
  stacked views of ``s * D`` values), :class:`StackedLstmPolicy`: ``(prev_action, stack
  [n, s - 1, D], h, c)`` and :class:`StackedWindowPolicy`: ``(prev_action, stack, history
  [n, k - 1, s * D], count)``, ``stack`` the last ``s - 1`` views as above.

``prev_action`` is the previous action in the environment's bounds (zeros at an episode
start); it enters the network only with ``train.prev_action_obs``. To start an episode for
some environments, replace their rows by those of ``initial_state``.

The Rust policy acts for one environment at a time; a batch of ``n > 1`` environments gives
each the actions it would get alone up to float32 rounding (about 1e-6: libtorch's matrix
products sum in another order for another batch size), not bit for bit. The module is
scriptable (``torch.jit.script``) and exports to ONNX (``torch.onnx.export(...,
dynamo=False)``; ``state_names`` names the state's tensors). Weights are read from the
agent's ``weights.safetensors`` with numpy (no ``safetensors`` package needed), checked
against its ``manifest.json`` when there is one. Like the Rust policy, the module assumes
finite observations (the Rust policy refuses others; here they give non-finite actions).
"""

import json
import math
import zlib
from pathlib import Path
from typing import Any, Dict, List, Optional, Tuple

import numpy as np
import torch
from torch import Tensor, nn

__all__ = [
    "to_torch",
    "FeedForwardPolicy",
    "StackedFeedForwardPolicy",
    "LstmPolicy",
    "WindowPolicy",
    "StackedLstmPolicy",
    "StackedWindowPolicy",
]

#: The agent formats (``agent.json``'s ``format``) this reader knows.
_FORMATS = (1, 2)

#: ``RdpgConfig::default()``'s values of the settings that shape the actor, for agent files
#: that leave a field out (format 1 agents predate ``act_window``).
_RDPG_DEFAULTS: Dict[str, Any] = {
    "trunk": "lidar",
    "lidar_dim": 10,
    "lidar_channels": 64,
    "lidar_kernel": 3,
    "lidar_fc": 64,
    "body_fc": 192,
    "recurrent": True,
    "actor_hidden": 256,
    "actor_head": [],
    "core_skip": False,
    "act_window": 0,
}

#: ``PpoConfig::default()``'s hidden widths.
_PPO_DEFAULT_HIDDEN = [64, 64]

#: The policies' states (see the module docs).
_State2 = Tuple[Tensor, Tensor]
_State3 = Tuple[Tensor, Tensor, Tensor]
_State4 = Tuple[Tensor, Tensor, Tensor, Tensor]


class _Weights:
    """The tensors of a ``weights.safetensors`` file (an 8-byte little-endian header length, a
    JSON header of name -> dtype, shape and data offsets, then the raw data), decoded on
    demand with numpy."""

    def __init__(self, path: Path, raw: bytes):
        self.path = path
        n = int.from_bytes(raw[:8], "little") if len(raw) >= 8 else -1
        if not 0 <= n <= len(raw) - 8:
            raise ValueError(f"{path}: truncated or not a safetensors file")
        try:
            header = json.loads(raw[8 : 8 + n])
        except ValueError as e:
            raise ValueError(f"{path}: corrupt safetensors header ({e})") from None
        header.pop("__metadata__", None)
        self.header: Dict[str, Dict[str, Any]] = header
        self.data = memoryview(raw)[8 + n :]

    def get(self, key: str, shape: Tuple[int, ...]) -> Tensor:
        """Tensor ``key`` (a float32 copy), which must have ``shape``."""
        meta = self.header.get(key)
        if meta is None:
            raise ValueError(f"{self.path}: no tensor {key!r} (the agent's config needs {shape})")
        if meta["dtype"] != "F32":
            raise ValueError(f"{self.path}: tensor {key!r} is {meta['dtype']}, not F32")
        if tuple(meta["shape"]) != shape:
            raise ValueError(
                f"{self.path}: tensor {key!r} has shape {tuple(meta['shape'])}, the agent's "
                f"config implies {shape}"
            )
        begin, end = meta["data_offsets"]
        if end - begin != 4 * math.prod(shape) or not 0 <= begin <= end <= len(self.data):
            raise ValueError(f"{self.path}: tensor {key!r} has bad offsets {[begin, end]}")
        return torch.tensor(np.frombuffer(self.data[begin:end], dtype="<f4").reshape(shape))

    def linear(self, prefix: str, in_dim: int, out_dim: int) -> nn.Linear:
        """The linear layer ``prefix`` (``{prefix}.weight``, ``{prefix}.bias``)."""
        layer = nn.Linear(in_dim, out_dim, device="meta")
        layer.weight = nn.Parameter(self.get(f"{prefix}.weight", (out_dim, in_dim)))
        layer.bias = nn.Parameter(self.get(f"{prefix}.bias", (out_dim,)))
        return layer


def _mlp(
    w: _Weights,
    net: str,
    layer: str,
    in_dim: int,
    hidden: List[int],
    act: nn.Module,
    head: Optional[int],
) -> nn.Sequential:
    """Rust's ``common::tensor::Mlp``: layers ``{net}.{layer}0``, ``{net}.{layer}1``... each
    followed by ``act``, then, with ``head`` outputs, the linear layer ``{net}.head``."""
    layers: List[nn.Module] = []
    for i, width in enumerate(hidden):
        layers += [w.linear(f"{net}.{layer}{i}", in_dim, width), act]
        in_dim = width
    if head is not None:
        layers.append(w.linear(f"{net}.head", in_dim, head))
    return nn.Sequential(*layers)


class _LidarTrunk(nn.Module):
    """The walker trunk (``nets.rs``, ``TrunkNet::Lidar``): the last ``lidar_dim`` values
    through a 1-D convolution, ReLU, max-pool (2) and FC + ReLU; the others (body) through
    FC + ReLU; the two concatenated, lidar first."""

    def __init__(self, conv: nn.Conv1d, lidar_fc: nn.Linear, body_fc: nn.Linear, body_dim: int):
        super().__init__()
        self.conv = conv
        self.lidar_fc = lidar_fc
        self.body_fc = body_fc
        self.body_dim = body_dim

    def forward(self, x: Tensor) -> Tensor:
        lidar = x[:, self.body_dim :].unsqueeze(1)
        pooled = torch.max_pool1d(self.conv(lidar).relu(), 2, 2).flatten(1, 2)
        body = self.body_fc(x[:, : self.body_dim]).relu()
        return torch.cat([self.lidar_fc(pooled).relu(), body], 1)


def _trunk(w: _Weights, cfg: Dict[str, Any], in_dim: int) -> Tuple[nn.Module, int]:
    """The actor's observation embedding (``actor.trunk.*``) and its width."""
    trunk = cfg["trunk"]
    if isinstance(trunk, dict) and set(trunk) == {"mlp"}:
        hidden = list(trunk["mlp"]["hidden"])
        return _mlp(w, "actor.trunk", "fc", in_dim, hidden, nn.ReLU(), None), hidden[-1]
    if trunk != "lidar":
        raise ValueError(f"{w.path.parent / 'agent.json'}: unknown trunk {trunk!r}")
    lidar_dim, ch, k = cfg["lidar_dim"], cfg["lidar_channels"], cfg["lidar_kernel"]
    conv = nn.Conv1d(1, ch, k, device="meta")
    conv.weight = nn.Parameter(w.get("actor.trunk.lidar_conv.weight", (ch, 1, k)))
    conv.bias = nn.Parameter(w.get("actor.trunk.lidar_conv.bias", (ch,)))
    body_dim = in_dim - lidar_dim
    pooled = (lidar_dim - k + 1) // 2
    lidar_fc = w.linear("actor.trunk.lidar_fc", ch * pooled, cfg["lidar_fc"])
    body_fc = w.linear("actor.trunk.body_fc", body_dim, cfg["body_fc"])
    return _LidarTrunk(conv, lidar_fc, body_fc, body_dim), cfg["lidar_fc"] + cfg["body_fc"]


class _Lstm(nn.Module):
    """The actor's LSTM (``actor.core.lstm.*``, libtorch's gate order i, f, g, o), with the
    two libtorch calls the Rust side makes: ``step`` (``lstm_cell``, acting) and ``scan``
    (the fused sequence kernel, the window agent's re-encoding)."""

    def __init__(self, w: _Weights, in_dim: int, hidden: int):
        super().__init__()
        p = "actor.core.lstm"
        self.weight_ih = nn.Parameter(w.get(f"{p}.weight_ih_l0", (4 * hidden, in_dim)))
        self.weight_hh = nn.Parameter(w.get(f"{p}.weight_hh_l0", (4 * hidden, hidden)))
        self.bias_ih = nn.Parameter(w.get(f"{p}.bias_ih_l0", (4 * hidden,)))
        self.bias_hh = nn.Parameter(w.get(f"{p}.bias_hh_l0", (4 * hidden,)))

    def step(self, x: Tensor, h: Tensor, c: Tensor) -> Tuple[Tensor, Tensor]:
        """One step: ``x [n, E]``, ``h``, ``c`` ``[n, H]`` -> next ``(h, c)``."""
        return torch.lstm_cell(
            x, [h, c], self.weight_ih, self.weight_hh, self.bias_ih, self.bias_hh
        )

    def scan(self, x: Tensor, h: Tensor, c: Tensor) -> Tuple[Tensor, Tensor]:
        """The state after the steps of ``x [n, T, E]`` from ``(h, c)`` (``[n, H]`` each)."""
        params = [self.weight_ih, self.weight_hh, self.bias_ih, self.bias_hh]
        # Arguments as the Rust side passes them (`Lstm::seq`): biases, 1 layer, dropout 0,
        # train = true (no effect without dropout), one direction, batch first.
        hx = [h.unsqueeze(0), c.unsqueeze(0)]
        _, hn, cn = torch.lstm(x, hx, params, True, 1, 0.0, True, False, True)
        return hn.squeeze(0), cn.squeeze(0)


class _Head(nn.Module):
    """``nets.rs``'s actor head: from the core's output ``y [n, H]`` (after its input
    ``x [n, E]`` with ``core_skip``), the ``actor_head`` layers (FC + ReLU), then FC + tanh."""

    def __init__(self, skip: bool, layers: nn.Module):
        super().__init__()
        self.skip = skip
        self.layers = layers

    def forward(self, x: Tensor, y: Tensor) -> Tensor:
        if self.skip:
            y = torch.cat([x, y], -1)
        return self.layers(y)


class _Mean(nn.Module):
    """The mean half ``[..., :act_dim]`` of a SAC actor's output ``[mean, log_std]``."""

    def __init__(self, act_dim: int):
        super().__init__()
        self.act_dim = act_dim

    def forward(self, out: Tensor) -> Tensor:
        return out[..., : self.act_dim]


class _FeedForwardActor(nn.Module):
    """A DDPG/TD3 actor: trunk, FC + ReLU core, head."""

    def __init__(self, trunk: nn.Module, core: nn.Module, head: _Head):
        super().__init__()
        self.trunk = trunk
        self.core = core
        self.head = head

    def forward(self, view: Tensor) -> Tensor:
        x = self.trunk(view)
        return self.head(x, torch.relu(self.core(x)))


class _Policy(nn.Module):
    """What every agent kind shares: the agent's view of a full observation (hidden
    components dropped, the previous action in front with ``prev_action_obs``) and the action
    mapped to the environment's bounds."""

    def __init__(self, keep: Tensor, prev_action_obs: bool, act_low: Tensor, act_high: Tensor):
        super().__init__()
        self.register_buffer("keep", keep)
        self.register_buffer("act_low", act_low)
        self.register_buffer("act_range", act_high - act_low)
        self.prev_action_obs = prev_action_obs

    def _view(self, obs: Tensor, prev: Tensor) -> Tensor:
        """The agent's input ``[n, D]`` for full observations ``obs [n, obs_dim]``."""
        seen = obs.index_select(1, self.keep)
        if self.prev_action_obs:
            return torch.cat([prev, seen], 1)
        return seen

    def _env_action(self, a: Tensor) -> Tensor:
        """``common::policy::to_env_action``: ``[-1, 1]`` (clipped) to the env's bounds."""
        return self.act_low + (a.clamp(-1.0, 1.0) + 1.0) * 0.5 * self.act_range

    def _no_action(self, n: int) -> Tensor:
        """``prev_action`` at an episode start: zeros ``[n, act_dim]``."""
        return self.act_low.new_zeros((n, self.act_low.shape[0]))

    def _no_views(self, n: int, k: int, d: int) -> Tensor:
        """``k`` views of ``d`` values before an episode's first: zeros ``[n, k, d]``."""
        return self.act_low.new_zeros((n, k, d))


def _stacked(view: Tensor, stack: Tensor) -> _State2:
    """A frame stack's step (``rdpg_envs::FrameStack``): the agent's input ``[n, s * D]``,
    the earlier views ``stack [n, s - 1, D]`` then ``view [n, D]``, and the stack after it."""
    n = view.shape[0]
    stacked = torch.cat([stack.reshape(n, -1), view], 1)
    return stacked, torch.cat([stack[:, 1:], view.unsqueeze(1)], 1)


class FeedForwardPolicy(_Policy):
    """A feed-forward agent: DDPG, TD3 and TD3-FORK (trunk, FC + ReLU, FC + tanh) or PPO (the
    Gaussian policy's mean, a tanh MLP, which the action's clipping clamps to ``[-1, 1]``).
    State: ``(prev_action [n, act_dim],)``."""

    state_names = ("prev_action",)

    def __init__(self, net: nn.Module, **base: Any):
        super().__init__(**base)
        self.net = net

    def forward(self, obs: Tensor, state: Tuple[Tensor]) -> Tuple[Tensor, Tuple[Tensor]]:
        a = self._env_action(self.net(self._view(obs, state[0])))
        return a, (a,)

    @torch.jit.export
    def initial_state(self, n: int) -> Tuple[Tensor]:
        """The state of ``n`` environments at an episode start."""
        return (self._no_action(n),)


class StackedFeedForwardPolicy(_Policy):
    """A feed-forward agent trained with a frame stack of ``k``: it acts on its last ``k``
    views side by side, oldest first (``rdpg_envs::FrameStack``).
    State: ``(prev_action [n, act_dim], history [n, k - 1, D])``."""

    state_names = ("prev_action", "history")

    def __init__(self, net: nn.Module, k: int, view_dim: int, **base: Any):
        super().__init__(**base)
        self.net = net
        self.k = k
        self.view_dim = view_dim

    def forward(self, obs: Tensor, state: _State2) -> Tuple[Tensor, _State2]:
        prev, history = state
        stacked, history = _stacked(self._view(obs, prev), history)
        a = self._env_action(self.net(stacked))
        return a, (a, history)

    @torch.jit.export
    def initial_state(self, n: int) -> _State2:
        """The state of ``n`` environments at an episode start."""
        return (self._no_action(n), self._no_views(n, self.k - 1, self.view_dim))


class LstmPolicy(_Policy):
    """A recurrent RDPG agent: trunk, LSTM (its state carried over the episode), FC + tanh.
    State: ``(prev_action [n, act_dim], h [n, H], c [n, H])``."""

    state_names = ("prev_action", "h", "c")

    def __init__(self, trunk: nn.Module, lstm: _Lstm, head: _Head, **base: Any):
        super().__init__(**base)
        self.trunk = trunk
        self.lstm = lstm
        self.head = head

    def forward(self, obs: Tensor, state: _State3) -> Tuple[Tensor, _State3]:
        prev, h, c = state
        a, h, c = self._act(self._view(obs, prev), h, c)
        return a, (a, h, c)

    def _act(self, view: Tensor, h: Tensor, c: Tensor) -> _State3:
        """The action for the agent's input ``view`` and the LSTM state after it."""
        x = self.trunk(view)
        h, c = self.lstm.step(x, h, c)
        return self._env_action(self.head(x, h)), h, c

    def _zero(self, n: int) -> Tensor:
        """The LSTM's state at an episode start: zeros ``[n, H]``."""
        return self.lstm.weight_hh.new_zeros((n, self.lstm.weight_hh.shape[1]))

    @torch.jit.export
    def initial_state(self, n: int) -> _State3:
        """The state of ``n`` environments at an episode start."""
        return (self._no_action(n), self._zero(n), self._zero(n))


class StackedLstmPolicy(LstmPolicy):
    """A recurrent RDPG agent trained with a frame stack of ``s``: its LSTM steps on the last
    ``s`` views side by side, oldest first.
    State: ``(prev_action, stack [n, s - 1, D], h [n, H], c [n, H])``."""

    state_names = ("prev_action", "stack", "h", "c")

    def __init__(self, trunk: nn.Module, lstm: _Lstm, head: _Head, s: int, view_dim: int,
                 **base: Any):
        super().__init__(trunk, lstm, head, **base)
        self.s = s
        self.view_dim = view_dim

    def forward(self, obs: Tensor, state: _State4) -> Tuple[Tensor, _State4]:
        prev, stack, h, c = state
        stacked, stack = _stacked(self._view(obs, prev), stack)
        a, h, c = self._act(stacked, h, c)
        return a, (a, stack, h, c)

    @torch.jit.export
    def initial_state(self, n: int) -> _State4:
        """The state of ``n`` environments at an episode start."""
        stack = self._no_views(n, self.s - 1, self.view_dim)
        return (self._no_action(n), stack, self._zero(n), self._zero(n))


class WindowPolicy(_Policy):
    """A window-of-k RDPG agent (``act_window = k``): each step re-encodes the last ``k - 1``
    views from a zero LSTM state (only the real ones: the left padding of an episode's first
    steps never enters the state), then acts on the new view from there.
    State: ``(prev_action [n, act_dim], history [n, k - 1, D], count [n])``."""

    state_names = ("prev_action", "history", "count")

    def __init__(
        self, trunk: nn.Module, lstm: _Lstm, head: _Head, k: int, view_dim: int, **base: Any
    ):
        super().__init__(**base)
        self.trunk = trunk
        self.lstm = lstm
        self.head = head
        self.k = k
        self.view_dim = view_dim

    def forward(self, obs: Tensor, state: _State3) -> Tuple[Tensor, _State3]:
        prev, history, count = state
        a, history, count = self._act(self._view(obs, prev), history, count)
        return a, (a, history, count)

    def _act(self, view: Tensor, history: Tensor, count: Tensor) -> _State3:
        """The action for the agent's input ``view`` after its ``history`` (``count`` real
        views), and the history and count after it."""
        n, s = history.shape[0], self.k - 1
        x = self.trunk(history.reshape(n * s, self.view_dim)).reshape(n, s, -1)
        zero = self.lstm.weight_hh.new_zeros((n, self.lstm.weight_hh.shape[1]))
        h, c = zero, zero
        # The Rust side scans each window over its real steps only (`scan_state`, one fused
        # call per length): here every length for every environment, each keeping its own.
        for steps in range(1, s + 1):
            hs, cs = self.lstm.scan(x[:, s - steps :], zero, zero)
            real = (count == steps).unsqueeze(1)
            h, c = torch.where(real, hs, h), torch.where(real, cs, c)
        x_t = self.trunk(view)
        h, _ = self.lstm.step(x_t, h, c)
        a = self._env_action(self.head(x_t, h))
        history = torch.cat([history[:, 1:], view.unsqueeze(1)], 1)
        return a, history, (count + 1.0).clamp(max=float(s))

    @torch.jit.export
    def initial_state(self, n: int) -> _State3:
        """The state of ``n`` environments at an episode start."""
        history = self._no_views(n, self.k - 1, self.view_dim)
        return (self._no_action(n), history, self.act_low.new_zeros((n,)))


class StackedWindowPolicy(WindowPolicy):
    """A window-of-k RDPG agent trained with a frame stack of ``s``: its window holds the
    stacked inputs (``s`` views side by side, oldest first) of its last ``k - 1`` steps.
    State: ``(prev_action, stack [n, s - 1, D], history [n, k - 1, s * D], count [n])``."""

    state_names = ("prev_action", "stack", "history", "count")

    def __init__(
        self, trunk: nn.Module, lstm: _Lstm, head: _Head, k: int, s: int, view_dim: int,
        **base: Any
    ):
        super().__init__(trunk, lstm, head, k, s * view_dim, **base)
        self.s = s
        self.stack_dim = view_dim

    def forward(self, obs: Tensor, state: _State4) -> Tuple[Tensor, _State4]:
        prev, stack, history, count = state
        stacked, stack = _stacked(self._view(obs, prev), stack)
        a, history, count = self._act(stacked, history, count)
        return a, (a, stack, history, count)

    @torch.jit.export
    def initial_state(self, n: int) -> _State4:
        """The state of ``n`` environments at an episode start."""
        stack = self._no_views(n, self.s - 1, self.stack_dim)
        history = self._no_views(n, self.k - 1, self.view_dim)
        return (self._no_action(n), stack, history, self.act_low.new_zeros((n,)))


def _read(agent_dir: Path, name: str) -> bytes:
    """File ``name`` of the agent directory, checked against the size and CRC-32 that the
    directory's ``manifest.json`` (when it has one, as every agent saved since format 2 does)
    lists for it."""
    path, manifest = agent_dir / name, agent_dir / "manifest.json"
    data = path.read_bytes()
    if manifest.exists():
        seal = json.loads(manifest.read_text())["files"].get(name)
        if seal is None:
            raise ValueError(f"{path}: not listed in {manifest}")
        if len(data) != seal["len"] or zlib.crc32(data) != seal["crc32"]:
            raise ValueError(f"{path}: damaged (its size or CRC-32 differs from {manifest})")
    return data


def _feed_forward(net: nn.Module, stack: int, view_dim: int, base: Dict[str, Any]) -> _Policy:
    """A feed-forward actor ``net`` on ``stack`` views of ``view_dim`` values."""
    if stack == 1:
        return FeedForwardPolicy(net, **base)
    return StackedFeedForwardPolicy(net, stack, view_dim, **base)


def _rdpg_actor(
    w: _Weights,
    cfg: Dict[str, Any],
    view_dim: int,
    stack: int,
    act_dim: int,
    base: Dict[str, Any],
) -> _Policy:
    """The actor of an RDPG/DDPG/SAC agent (``actor.*``) as the module of its kind, on
    ``stack`` views of ``view_dim`` values."""
    hidden = cfg["actor_hidden"]
    trunk, embed = _trunk(w, cfg, stack * view_dim)
    core = _Lstm(w, embed, hidden) if cfg["recurrent"] else w.linear("actor.core.fc", embed, hidden)
    layers: List[nn.Module] = []
    width = hidden + (embed if cfg["core_skip"] else 0)
    for i, h in enumerate(cfg["actor_head"]):
        layers += [w.linear(f"actor.head_mlp.fc{i}", width, h), nn.ReLU()]
        width = h
    if cfg.get("sac") is None:
        layers += [w.linear("actor.head", width, act_dim), nn.Tanh()]
    else:
        # A SAC actor's output layer gives the mean and the log standard deviation; the
        # deterministic policy is tanh(mean).
        layers += [w.linear("actor.head", width, 2 * act_dim), _Mean(act_dim), nn.Tanh()]
    head = _Head(bool(cfg["core_skip"]), nn.Sequential(*layers))
    if not cfg["recurrent"]:
        return _feed_forward(_FeedForwardActor(trunk, core, head), stack, view_dim, base)
    window = cfg["act_window"]
    if window and stack > 1:
        return StackedWindowPolicy(trunk, core, head, window, stack, view_dim, **base)
    if window:
        return WindowPolicy(trunk, core, head, window, view_dim, **base)
    if stack > 1:
        return StackedLstmPolicy(trunk, core, head, stack, view_dim, **base)
    return LstmPolicy(trunk, core, head, **base)


def to_torch(
    agent_dir: Any,
    config: Dict[str, Any],
    obs_low: np.ndarray,
    obs_high: np.ndarray,
    act_low: np.ndarray,
    act_high: np.ndarray,
) -> nn.Module:
    """The agent saved in ``agent_dir`` (``agent.json``, ``weights.safetensors``) as a
    float32 module acting as ``rdpg.Policy`` does on full observations, in eval mode with its
    parameters frozen (``requires_grad_()`` to train it further).

    ``config`` is the run's parsed ``config.toml`` (its ``algo`` and the ``[train]`` settings
    ``hide_obs``, ``prev_action_obs`` and ``frame_stack`` are read); the bounds are those of the full environment's spaces (the
    observation bounds give its size). See the module docs for the state layouts. An
    algorithm, agent format or setting this reader does not know, or files that do not fit
    each other, is a ``ValueError`` naming the file (and tensor).
    """
    algo = config.get("algo")
    if algo not in ("rdpg", "ddpg", "sac", "ppo"):
        raise ValueError(
            f"config.toml: algo {algo!r}, expected \"rdpg\", \"ddpg\", \"sac\" or \"ppo\""
        )
    agent_dir = Path(agent_dir)
    meta_path = agent_dir / "agent.json"
    meta = json.loads(_read(agent_dir, "agent.json"))
    if meta.get("format") not in _FORMATS:
        raise ValueError(f"{meta_path}: agent format {meta.get('format')}, known: {_FORMATS}")
    if meta.get("double"):
        raise ValueError(f"{meta_path}: a float64 agent (double = true), not float32")
    w = _Weights(agent_dir / "weights.safetensors", _read(agent_dir, "weights.safetensors"))

    train = config.get("train", {})
    obs_dim, act_dim = len(obs_low), len(act_low)
    hide = sorted(set(train.get("hide_obs", [])))
    if any(not 0 <= i < obs_dim for i in hide):
        raise ValueError(f"config.toml: train.hide_obs {hide} not all in 0..{obs_dim - 1}")
    stack = train.get("frame_stack", 1)
    if not isinstance(stack, int) or stack < 1:
        raise ValueError(f"config.toml: train.frame_stack {stack!r}, expected an int >= 1")
    prev_action_obs = bool(train.get("prev_action_obs", False))
    view_dim = obs_dim - len(hide) + (act_dim if prev_action_obs else 0)
    if (meta["obs_dim"], meta["act_dim"]) != (stack * view_dim, act_dim):
        raise ValueError(
            f"{meta_path}: obs_dim {meta['obs_dim']}, act_dim {meta['act_dim']}; the environment "
            f"as configured gives the agent {stack * view_dim} inputs and takes {act_dim} actions"
        )
    base = dict(
        keep=torch.tensor([i for i in range(obs_dim) if i not in hide], dtype=torch.long),
        prev_action_obs=prev_action_obs,
        act_low=torch.tensor(np.asarray(act_low, np.float32)),
        act_high=torch.tensor(np.asarray(act_high, np.float32)),
    )
    if algo == "ppo":
        hidden = list(meta["config"].get("hidden", _PPO_DEFAULT_HIDDEN))
        mean = _mlp(w, "policy", "l", stack * view_dim, hidden, nn.Tanh(), act_dim)
        policy: _Policy = _feed_forward(mean, stack, view_dim, base)
    else:
        cfg = {**_RDPG_DEFAULTS, **meta["config"]}
        policy = _rdpg_actor(w, cfg, view_dim, stack, act_dim, base)
    return policy.eval().requires_grad_(False)
