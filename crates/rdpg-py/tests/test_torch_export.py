"""Trained agents as PyTorch modules (``rdpg._torch.to_torch``) act as the Rust policy.

Each agent runs whole episodes closed-loop in its environment with ``rdpg.Policy`` (the Rust
actor); its module then gets the same full observations open-loop, state threaded, and must
give the same actions. The agents: every zoo entry (LSTM RDPG, TD3, TD3-FORK), a window-of-k
RDPG agent trained on the cue task here, and small agents with random weights written here for
what no shipped agent uses: the paper's lidar trunk, hidden observation components, the
previous action as input, a window agent reading it, head layers after the core with the skip
connection around it (LSTM and feed-forward), PPO, and frame-stacked agents (feed-forward, LSTM, window).
"""

from __future__ import annotations

import io
import json
import shutil
import tomllib
import warnings
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import torch

import rdpg
from helpers import ZOO, train_window_run
from rdpg._torch import to_torch

SEEDS = (3_000_000, 3_000_001, 3_000_002)
MAX_STEPS = 300  # per episode, to stay fast

#: Agents with random weights (written by `_synthetic_entry`): run settings and agent config.
SYNTHETIC = {
    "lidar-lstm": ("rdpg", {"hide_obs": [2, 3], "prev_action_obs": True}, {}),
    "lidar-window": (
        "rdpg",
        {"prev_action_obs": True},
        {"act_window": 4, "scan_len": 3, "update_len": 1, "tau": 0.005},
    ),
    "lidar-ddpg": (
        "ddpg",
        {"hide_obs": [13]},
        {"recurrent": False, "scan_len": 0, "opt_len": 1, "update_len": 1},
    ),
    "lidar-skip-lstm": (
        "rdpg",
        {"prev_action_obs": True},
        {"actor_head": [12, 6], "critic_head": [10], "core_skip": True},
    ),
    "lidar-skip-ddpg": (
        "ddpg",
        {},
        {"recurrent": False, "scan_len": 0, "opt_len": 1, "update_len": 1,
         "actor_head": [12], "core_skip": True},
    ),
    "lidar-sac-lstm": (
        "sac",
        {"prev_action_obs": True},
        {"tau": 0.005, "actor_head": [12], "core_skip": True, "sac": {}},
    ),
    "lidar-sac-ff": (
        "sac",
        {"hide_obs": [2]},
        {"recurrent": False, "scan_len": 0, "opt_len": 1, "update_len": 1, "tau": 0.005,
         "sac": {}},
    ),
    "lidar-tqc-ff": (
        "sac",
        {},
        {"recurrent": False, "scan_len": 0, "opt_len": 1, "update_len": 1, "tau": 0.005,
         "sac": {"tqc": {"quantiles": 5, "drop_per_critic": 1}}},
    ),
    "ppo": ("ppo", {"hide_obs": [2, 3], "prev_action_obs": True}, {"hidden": [32, 16]}),
    "lidar-ddpg-stack": (
        "ddpg",
        {"prev_action_obs": True, "frame_stack": 3},
        {"recurrent": False, "scan_len": 0, "opt_len": 1, "update_len": 1},
    ),
    "ppo-stack": ("ppo", {"hide_obs": [2], "frame_stack": 2}, {"hidden": [32, 16]}),
    "lidar-lstm-stack": ("rdpg", {"prev_action_obs": True, "frame_stack": 2}, {}),
    "lidar-window-stack": (
        "rdpg",
        {"hide_obs": [3], "frame_stack": 3},
        {"act_window": 4, "scan_len": 3, "update_len": 1, "tau": 0.005},
    ),
}

#: The small lidar networks of the synthetic RDPG/DDPG agents.
LIDAR_AGENT = {
    "trunk": "lidar",
    "lidar_channels": 8,
    "lidar_fc": 16,
    "body_fc": 24,
    "actor_hidden": 32,
    "critic_hidden": 16,
    "critic_action_fc": 8,
    "device": "cpu",
    "num_threads": 1,
}


def _cases() -> list:
    """The agents tested: (kind, what) for `_entry`."""
    zoo = sorted(p.name for p in ZOO.iterdir() if (p / "agent").is_dir()) if ZOO.is_dir() else []
    cases = [pytest.param(("zoo", name), id=name) for name in zoo]
    if not zoo:
        skip = pytest.mark.skip(reason=f"no agents in {ZOO}")
        cases.append(pytest.param(("zoo", None), id="zoo", marks=skip))
    cases.append(pytest.param(("window", None), id="window"))
    cases += [pytest.param(("synthetic", name), id=f"synthetic-{name}") for name in SYNTHETIC]
    return cases


# --- Synthetic agents: the files `RdpgAgent::save` / `PpoAgent::save` write, random weights.


def _write_safetensors(path: Path, tensors: dict[str, np.ndarray]) -> None:
    header, blobs, offset = {}, [], 0
    for name in sorted(tensors):
        data = np.ascontiguousarray(tensors[name], dtype="<f4").tobytes()
        span = [offset, offset + len(data)]
        header[name] = {"dtype": "F32", "shape": list(tensors[name].shape), "data_offsets": span}
        blobs.append(data)
        offset += len(data)
    head = json.dumps(header).encode()
    head += b" " * (-len(head) % 8)
    path.write_bytes(len(head).to_bytes(8, "little") + head + b"".join(blobs))


def _linear(name: str, in_dim: int, out_dim: int) -> dict[str, tuple[int, ...]]:
    return {f"{name}.weight": (out_dim, in_dim), f"{name}.bias": (out_dim,)}


def _rdpg_shapes(cfg: dict, obs_dim: int, act_dim: int) -> dict[str, tuple[int, ...]]:
    """The variables of an RDPG/DDPG/SAC agent with a lidar trunk (`nets.rs`), critic included
    (a SAC actor's output layer gives mean and log std; SAC has no target actor and a
    `log_alpha`; a TQC critic outputs its atoms)."""
    shapes: dict[str, tuple[int, ...]] = {}
    ch, af = cfg["lidar_channels"], cfg["critic_action_fc"]
    sac = "sac" in cfg
    actor_out = 2 * act_dim if sac else act_dim
    # A TQC critic's output layer gives its atoms.
    atoms = ((cfg.get("sac") or {}).get("tqc") or {}).get("quantiles", 1)
    nets = (("actor", cfg["actor_hidden"], actor_out), ("critic", cfg["critic_hidden"], atoms))
    for net, hidden, out in nets:
        shapes[f"{net}.trunk.lidar_conv.weight"] = (ch, 1, 3)
        shapes[f"{net}.trunk.lidar_conv.bias"] = (ch,)
        shapes |= _linear(f"{net}.trunk.lidar_fc", ch * 4, cfg["lidar_fc"])
        shapes |= _linear(f"{net}.trunk.body_fc", obs_dim - 10, cfg["body_fc"])
        embed = cfg["lidar_fc"] + cfg["body_fc"] + (af if net == "critic" else 0)
        if cfg.get("recurrent", True):
            lstm = f"{net}.core.lstm"
            shapes[f"{lstm}.weight_ih_l0"] = (4 * hidden, embed)
            shapes[f"{lstm}.weight_hh_l0"] = (4 * hidden, hidden)
            shapes[f"{lstm}.bias_ih_l0"] = shapes[f"{lstm}.bias_hh_l0"] = (4 * hidden,)
        else:
            shapes |= _linear(f"{net}.core.fc", embed, hidden)
        width = hidden + (embed if cfg.get("core_skip", False) else 0)
        for i, h in enumerate(cfg.get(f"{net}_head", [])):
            shapes |= _linear(f"{net}.head_mlp.fc{i}", width, h)
            width = h
        shapes |= _linear(f"{net}.head", width, out)
    shapes |= _linear("critic.act_fc", act_dim, af)
    if cfg.get("tau", 0.0) > 0:
        shapes |= {f"target.{k}": v for k, v in shapes.items() if not (sac and k.startswith("actor"))}
    if sac:
        shapes["log_alpha"] = (1,)
    return shapes


def _ppo_shapes(hidden: list[int], obs_dim: int, act_dim: int) -> dict[str, tuple[int, ...]]:
    shapes: dict[str, tuple[int, ...]] = {"policy.log_std": (act_dim,)}
    for net, out in (("policy", act_dim), ("value", 1)):
        widths = [obs_dim, *hidden]
        for i in range(len(hidden)):
            shapes |= _linear(f"{net}.l{i}", widths[i], widths[i + 1])
        shapes |= _linear(f"{net}.head", widths[-1], out)
    return shapes


def _synthetic_entry(root: Path, name: str) -> Path:
    """A zoo-style entry (`config.toml`, sealed `agent/`) of synthetic agent `name`."""
    algo, train, agent = SYNTHETIC[name]
    env = rdpg.RdpgEnv("BipedalWalker-v3")
    obs_dim, act_dim = env.observation_space.shape[0], env.action_space.shape[0]
    obs_dim += act_dim * train.get("prev_action_obs", False) - len(train.get("hide_obs", []))
    obs_dim *= train.get("frame_stack", 1)
    if algo == "ppo":
        config = {**agent, "device": "cpu", "num_threads": 1}
        shapes = _ppo_shapes(agent["hidden"], obs_dim, act_dim)
        meta = {"kl_coef": 1.0}
    else:
        config = {**LIDAR_AGENT, **agent}
        shapes = _rdpg_shapes(config, obs_dim, act_dim)
        rng_state = {"state_hi": 1, "state_lo": 2, "inc_hi": 3, "inc_lo": 5}
        meta = {"double": False, "rng": {**rng_state, "has_uint32": False, "uinteger": 0}}
    rng = np.random.default_rng(sum(map(ord, name)))
    # Weights ~ N(0, 1/fan_in), biases ~ N(0, 0.1): actions that vary without saturating.
    scale = {k: 1.0 / np.sqrt(np.prod(s[1:]) if len(s) > 1 else 10.0) for k, s in shapes.items()}
    tensors = {k: rng.normal(0.0, scale[k], s) for k, s in shapes.items()}
    entry = root / name
    (entry / "agent").mkdir(parents=True)
    lines = [f'algo = "{algo}"', "[train]", 'env = "BipedalWalker-v3"']
    lines += [f"{k} = {json.dumps(v)}" for k, v in train.items()]
    (entry / "config.toml").write_text("\n".join(lines) + "\n")
    meta |= {"format": 2, "config": config, "obs_dim": obs_dim, "act_dim": act_dim}
    meta |= {"seed": 0, "updates": 0}
    (entry / "agent" / "agent.json").write_text(json.dumps(meta))
    _write_safetensors(entry / "agent" / "weights.safetensors", tensors)
    _seal(entry / "agent")
    return entry


def _seal(agent_dir: Path) -> None:
    """Writes `manifest.json` (size and CRC-32 of each file), as `checkpoint::seal` does."""
    files = {}
    for name in ("agent.json", "weights.safetensors"):
        data = (agent_dir / name).read_bytes()
        files[name] = {"len": len(data), "crc32": zlib.crc32(data)}
    (agent_dir / "manifest.json").write_text(json.dumps({"files": files}))


# --- Recording the Rust policy and replaying its observations.


@dataclass
class Recording:
    """An agent's entry, its module, and episodes of the Rust policy: per episode the full
    observations `[T, obs_dim]` it acted on and its actions `[T, act_dim]`."""

    entry: Path
    module: torch.nn.Module
    obs: list[np.ndarray]
    actions: list[np.ndarray]


def _entry(kind: str, what, tmp: Path) -> Path:
    """The zoo-style entry (`config.toml`, `agent/`) of a case, made under `tmp` if need be."""
    if kind == "zoo":
        return ZOO / what
    if kind == "synthetic":
        return _synthetic_entry(tmp, what)
    # A window-of-k agent trained here (the cue task, k = 4), as a zoo-style entry.
    run = train_window_run(tmp / "window-run")
    entry = tmp / "window"
    shutil.copytree(run / "checkpoints" / "best" / "agent", entry / "agent")
    shutil.copy(run / "config.toml", entry / "config.toml")
    return entry


@pytest.fixture(scope="module", params=_cases())
def recording(request, tmp_path_factory) -> Recording:
    """A case's module and the Rust policy's episodes (seeds `SEEDS`, `MAX_STEPS` at most)."""
    entry = _entry(*request.param, tmp_path_factory.mktemp("agents"))
    policy = rdpg.Policy.load(entry)
    env = rdpg.RdpgEnv(policy.env_id, action_repeat=policy.action_repeat)
    config = tomllib.loads((entry / "config.toml").read_text())
    o_space, a_space = env.observation_space, env.action_space
    module = to_torch(entry / "agent", config, o_space.low, o_space.high, a_space.low, a_space.high)
    all_obs, all_actions = [], []
    for seed in SEEDS:
        obs, _ = env.reset(seed=seed)
        policy.reset()
        seen, acts = [], []
        for _ in range(MAX_STEPS):
            a = policy.act(obs)
            seen.append(obs)
            acts.append(a)
            obs, _, terminated, truncated, _ = env.step(a)
            if terminated or truncated:
                break
        all_obs.append(np.stack(seen))
        all_actions.append(np.stack(acts))
    return Recording(entry, module, all_obs, all_actions)


def _replay(module, obs: np.ndarray) -> np.ndarray:
    """The module's actions for the observations `[T, n, obs_dim]` of `n` episodes, from
    their starts, state threaded: `[T, n, act_dim]`."""
    state = module.initial_state(obs.shape[1])
    out = []
    with torch.no_grad():
        for o in obs:
            a, state = module(torch.from_numpy(o), state)
            out.append(a.numpy())
    return np.stack(out)


def _batch(rec: Recording) -> tuple[np.ndarray, np.ndarray]:
    """The episodes' first `T` steps side by side (`T` the shortest episode):
    observations `[T, 3, obs_dim]` and the Rust actions `[T, 3, act_dim]`."""
    t = min(len(o) for o in rec.obs)
    return np.stack([o[:t] for o in rec.obs], 1), np.stack([a[:t] for a in rec.actions], 1)


def test_the_module_acts_as_the_rust_policy(recording):
    for obs, want in zip(recording.obs, recording.actions):
        got = _replay(recording.module, obs[:, None])[:, 0]
        assert got.dtype == np.float32 and got.shape == want.shape
        diff = np.abs(got - want).max()
        assert diff <= 1e-6, f"{recording.entry}: max |torch - rust| = {diff}"


def test_a_batch_of_episodes_acts_as_each_alone(recording):
    # Up to float32 rounding: libtorch's matrix products sum in another order for a batch of
    # 3 than for 1 (measured: at most 4e-6, with the LSTM state carried over 300 steps).
    obs, want = _batch(recording)
    diff = np.abs(_replay(recording.module, obs) - want).max()
    assert diff <= 1e-5, f"{recording.entry}: max |batched - rust| = {diff}"


def test_the_module_is_scriptable(recording):
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*torch.jit.script.*deprecated")
        scripted = torch.jit.script(recording.module)
    obs, _ = _batch(recording)
    obs = obs[:50]
    assert np.array_equal(_replay(scripted, obs), _replay(recording.module, obs))


@pytest.fixture(scope="module")
def onnx_model(recording) -> bytes:
    """The module exported to ONNX (TorchScript exporter), batch size dynamic; inputs `obs`
    and the state's names, outputs `action` and `next_<name>` for each."""
    pytest.importorskip("onnx")
    module = recording.module
    names = list(module.state_names)
    outputs = ["action", *(f"next_{n}" for n in names)]
    f = io.BytesIO()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(
            module,
            (torch.zeros(2, recording.obs[0].shape[1]), module.initial_state(2)),
            f,
            dynamo=False,
            input_names=["obs", *names],
            output_names=outputs,
            dynamic_axes={name: {0: "n"} for name in ["obs", *names, *outputs]},
        )
    return f.getvalue()


def test_the_module_exports_to_onnx(onnx_model):
    import onnx

    model = onnx.load_from_string(onnx_model)
    onnx.checker.check_model(model)
    assert [o.name for o in model.graph.output][0] == "action"


def test_onnx_runtime_acts_as_the_module(recording, onnx_model):
    ort = pytest.importorskip("onnxruntime")
    session = ort.InferenceSession(onnx_model, providers=["CPUExecutionProvider"])
    inputs = {i.name for i in session.get_inputs()}  # unused state inputs are pruned
    names = recording.module.state_names
    obs, _ = _batch(recording)
    want = _replay(recording.module, obs)
    state = [s.numpy() for s in recording.module.initial_state(obs.shape[1])]
    # onnxruntime's own kernels round otherwise than libtorch's: each is some 1e-5 from the
    # float64 result at the worst steps measured, so they may differ by as much (1.3e-5).
    for o, w in zip(obs, want):
        feed = {"obs": o, **{n: s for n, s in zip(names, state) if n in inputs}}
        action, *state = session.run(None, feed)
        diff = np.abs(action - w).max()
        assert diff <= 5e-5, f"{recording.entry}: max |onnxruntime - torch| = {diff}"


def test_agents_it_cannot_build_are_value_errors_naming_the_file(tmp_path):
    entry = ZOO / "walker-td3"
    if not (entry / "agent").is_dir():
        pytest.skip(f"{entry} is not in this checkout")
    config = tomllib.loads((entry / "config.toml").read_text())
    space = rdpg.RdpgEnv(config["train"]["env"])
    o, a = space.observation_space, space.action_space
    bounds = (o.low, o.high, a.low, a.high)
    agent = tmp_path / "agent"
    shutil.copytree(entry / "agent", agent)

    with pytest.raises(ValueError, match="algo 'tqc'"):
        to_torch(agent, {**config, "algo": "tqc"}, *bounds)
    hidden = {**config, "train": {**config["train"], "hide_obs": [0]}}
    with pytest.raises(ValueError, match="agent.json: obs_dim 24"):
        to_torch(agent, hidden, *bounds)

    meta = json.loads((agent / "agent.json").read_text())
    for change, message in [
        ({"format": 9}, "agent format 9"),
        ({"double": True}, "float64 agent"),
        ({"config": {**meta["config"], "trunk": {"cnn": {}}}}, "unknown trunk"),
        ({"config": {**meta["config"], "actor_hidden": 128}}, r"'actor.core.fc.weight' has shape"),
    ]:
        (agent / "agent.json").write_text(json.dumps({**meta, **change}))
        _seal(agent)
        with pytest.raises(ValueError, match=message):
            to_torch(agent, config, *bounds)

    (agent / "agent.json").write_text(json.dumps(meta))
    _seal(agent)
    weights = (agent / "weights.safetensors").read_bytes()
    renamed = weights.replace(b"actor.head.bias", b"actor.head.bia_")
    (agent / "weights.safetensors").write_bytes(renamed)
    with pytest.raises(ValueError, match="weights.safetensors: damaged"):
        to_torch(agent, config, *bounds)
    _seal(agent)
    with pytest.raises(ValueError, match="weights.safetensors: no tensor 'actor.head.bias'"):
        to_torch(agent, config, *bounds)


def test_a_bad_frame_stack_is_refused_by_name(tmp_path):
    entry = _synthetic_entry(tmp_path, "lidar-lstm-stack")
    config = tomllib.loads((entry / "config.toml").read_text())
    env = rdpg.RdpgEnv("BipedalWalker-v3")
    bounds = (env.observation_space.low, env.observation_space.high,
              env.action_space.low, env.action_space.high)
    with pytest.raises(ValueError, match="frame_stack 0"):
        to_torch(entry / "agent", {**config, "train": {"frame_stack": 0}}, *bounds)
