"""rdpg for Python: rdpg's environments under Gymnasium ids, a vector env, trained policies.

    import gymnasium as gym
    import rdpg                                   # registers the rdpg/... ids

    env = gym.make("rdpg/BipedalWalker-v3")       # bit-identical to gym.make("BipedalWalker-v3")
    policy = rdpg.Policy.load(rdpg.zoo("walker-td3"))   # a run or zoo directory
    obs, _ = env.reset(seed=3_000_000)
    policy.reset()
    done = False
    while not done:
        obs, r, term, trunc, _ = env.step(policy.act(obs))
        done = term or trunc

Environments step in Rust (the GIL released); the vector env steps its environments on Rust
threads with Gymnasium's next-step (default) or same-step autoreset. ``import rdpg`` and the
environments load no libtorch: torch is imported the first time a ``Policy`` is loaded. Errors
raised by the Rust side are ``ValueError`` (bad input: unknown id, wrong action shape, NaN,
bad policy directory) or ``RuntimeError`` (a failure inside an environment), with the Rust
message.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from . import _rdpg
from ._util import count as _count, f32 as _f32, spaces_of as _spaces
from .policy import Policy

__all__ = ["RdpgEnv", "RdpgVectorEnv", "Policy", "ENV_IDS", "make_vec", "zoo"]

#: The rdpg environment ids and their time limits (those of Gymnasium for its own envs).
ENV_IDS: dict[str, int] = {
    "BipedalWalker-v3": 1600,
    "BipedalWalkerHardcore-v3": 2000,
    "Pendulum-v1": 200,
    "PendulumNoVel-v1": 200,
    "CueMemory-v0": 6,
    "DelayedCue-v0": 12,
}

_FPS = {"BipedalWalker-v3": 50, "BipedalWalkerHardcore-v3": 50}


def _seed_words(seed: int) -> list[int]:
    """A seed of any size as its little-endian 32-bit words, as numpy's ``SeedSequence`` reads
    an int (Gymnasium seeds with any non-negative int)."""
    seed, words = int(seed), []
    while True:
        words.append(seed & 0xFFFFFFFF)
        seed >>= 32
        if not seed:
            return words


def _indices(name: str, values: Any) -> list[int]:
    return [_count(f"{name}[{k}]", v) for k, v in enumerate(values)]


def _action_bytes(action: Any, shape: tuple[int, ...]) -> bytes:
    a = np.asarray(action)
    if a.dtype.kind not in "fiu":
        raise TypeError(f"action of dtype {a.dtype}: expected a real array of shape {shape}")
    a = a.astype(np.float32, copy=False)
    if a.shape != shape:
        raise ValueError(f"action of shape {a.shape}, expected {shape}")
    return np.ascontiguousarray(a).tobytes()


def _info(raw: tuple) -> dict[str, Any]:
    """A step's info dict from the extension's ``(success, stock_reward, course)``."""
    success, stock, course = raw
    info: dict[str, Any] = {"success": success}
    if stock is not None:
        info["stock_reward"] = stock
    if course is not None:
        # Walkers: the stump, staircase or pit the hull is over or just in front of, and the
        # obstacles passed so far (what `rdpg eval` counts per obstacle kind).
        at, stump, stairs, pit = course
        info["obstacles_passed"] = {"stump": stump, "stairs": stairs, "pit": pit}
        if at is not None:
            info["obstacle"] = at
    return info


class RdpgEnv(gym.Env):
    """One rdpg environment with Gymnasium's API.

    Keyword options: ``reward="paper"`` (the walkers' reward of the paper), ``hide_obs=[...]``
    (observation components removed, e.g. velocities), ``render_mode="rgb_array"``, and the
    hardcore training options of ``rdpg train``: ``fall_penalty=-1.0`` (the reward of a fall;
    ``info["stock_reward"]`` keeps the stock one) and ``action_repeat=3`` (each action held for
    3 frames, rewards summed; the time limit then counts frames, as in training, so an episode
    truncates after ``ceil(limit / 3)`` steps).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 50}

    def __init__(
        self,
        env_id: str,
        render_mode: str | None = None,
        reward: str = "stock",
        hide_obs: list[int] | tuple[int, ...] = (),
        fall_penalty: float | None = None,
        action_repeat: int = 1,
    ):
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode {render_mode!r}: rdpg envs render 'rgb_array' only")
        # The time limit is Gymnasium's TimeLimit wrapper (added by gymnasium.make from the
        # registration, or by max_episode_steps=), as for Gymnasium's own walkers; with an
        # action repeat the env's own limit counts frames and ends the episode first.
        self._env = _rdpg.Env(
            env_id,
            reward,
            _indices("hide_obs", hide_obs),
            False,
            fall_penalty,
            _count("action_repeat", action_repeat, 1),
        )
        self.env_id = env_id
        self.reward = reward
        self.hide_obs = tuple(hide_obs)
        self.fall_penalty = fall_penalty
        self.action_repeat = action_repeat
        self.render_mode = render_mode
        self.metadata = {"render_modes": ["rgb_array"], "render_fps": _FPS.get(env_id, 30)}
        self.observation_space = _spaces(*self._env.observation_bounds())
        self.action_space = _spaces(*self._env.action_bounds())

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        if seed is not None:
            _count("seed", seed)
        super().reset(seed=seed)
        obs = self._env.reset(None if seed is None else _seed_words(seed))
        return _f32(obs, self.observation_space.shape), {}

    def step(self, action):
        obs, reward, terminated, truncated, info = self._env.step(
            _action_bytes(action, self.action_space.shape)
        )
        shape = self.observation_space.shape
        return _f32(obs, shape), reward, terminated, truncated, _info(info)

    def render(self):
        if self.render_mode != "rgb_array":
            return None
        rgb, h, w = self._env.render()
        return np.frombuffer(rgb, dtype=np.uint8).reshape(h, w, 3).copy()


class RdpgVectorEnv(VectorEnv):
    """``num_envs`` rdpg environments stepped in parallel on Rust threads (GIL released),
    each with its registered time limit, the same options as ``RdpgEnv``.

    Autoreset: ``AutoresetMode.NEXT_STEP``, Gymnasium's default: the step that ends an episode
    returns its last observation; the next step of that sub-env ignores its action and returns
    the first observation of a new episode (reward 0, both flags false). With
    ``autoreset_mode=AutoresetMode.SAME_STEP`` the step that ends an episode returns the new
    episode's first observation and puts the last one in ``info["final_obs"]`` (and its info
    in ``info["final_info"]``). Infos are those of ``SyncVectorEnv`` over ``RdpgEnv``
    instances: each key of the single env's info (``success``, ...) batched, with its ``_key``
    mask.
    ``reset(seed=s)`` seeds sub-env ``i`` with ``s + i``, as Gymnasium's ``SyncVectorEnv`` does.
    """

    def __init__(
        self,
        env_id: str,
        num_envs: int,
        reward: str = "stock",
        hide_obs: list[int] | tuple[int, ...] = (),
        threads: int | None = None,
        fall_penalty: float | None = None,
        action_repeat: int = 1,
        max_episode_steps: int | None = None,
        autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
    ):
        # `gymnasium.make_vec` passes the registration's `max_episode_steps`: each sub-env
        # keeps its registered time limit, so only that value is accepted; any other keyword
        # is a TypeError, as for the single env.
        if max_episode_steps not in (None, ENV_IDS.get(env_id)):
            raise ValueError(
                f"max_episode_steps = {max_episode_steps}: the vector env keeps {env_id}'s "
                f"registered limit {ENV_IDS.get(env_id)}"
            )
        mode = AutoresetMode(autoreset_mode)
        if mode not in (AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP):
            raise ValueError(f"autoreset_mode {mode}: rdpg's vector env has NEXT_STEP and SAME_STEP")
        hide = _indices("hide_obs", hide_obs)
        self._env = _rdpg.VecEnv(
            env_id,
            _count("num_envs", num_envs, 1),
            reward,
            hide,
            None if threads is None else _count("threads", threads, 1),
            fall_penalty,
            _count("action_repeat", action_repeat, 1),
            mode == AutoresetMode.SAME_STEP,
        )
        one = _rdpg.Env(env_id, reward, hide)
        self.env_id = env_id
        self.reward = reward
        self.hide_obs = tuple(hide)
        self.fall_penalty = fall_penalty
        self.action_repeat = action_repeat
        self.num_envs = num_envs
        self.single_observation_space = _spaces(*one.observation_bounds())
        self.single_action_space = _spaces(*one.action_bounds())
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self.action_space = batch_space(self.single_action_space, num_envs)
        self.metadata = {"autoreset_mode": mode}
        self.render_mode = None
        self._obs_shape = (num_envs,) + self.single_observation_space.shape
        self._act_shape = (num_envs,) + self.single_action_space.shape

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        if seed is not None:
            _count("seed", seed)
            self._np_random, self._np_random_seed = gym.utils.seeding.np_random(seed)
        words = None if seed is None else _seed_words(seed)
        return _f32(self._env.reset(words), self._obs_shape), {}

    def step(self, actions):
        obs, rew, term, trunc, raw, finals = self._env.step(_action_bytes(actions, self._act_shape))
        infos: dict[str, Any] = {}
        one = self.single_observation_space.shape
        for i, (r, last) in enumerate(zip(raw, finals)):
            if r is None:
                continue
            info = _info(r)
            if last is not None:
                # SAME_STEP: the ended episode's last observation and info; the env's own
                # info is then its reset's (empty).
                infos = self._add_info(infos, {"final_obs": _f32(last, one), "final_info": info}, i)
            else:
                infos = self._add_info(infos, info, i)
        return (
            _f32(obs, self._obs_shape),
            np.frombuffer(rew, dtype=np.float64).copy(),
            np.frombuffer(term, dtype=np.uint8).astype(bool),
            np.frombuffer(trunc, dtype=np.uint8).astype(bool),
            infos,
        )


def make_vec(env_id: str, num_envs: int, **kwargs: Any) -> RdpgVectorEnv:
    """The vector env of ``rdpg/<id>`` (or ``<id>``) with ``num_envs`` sub-envs."""
    return RdpgVectorEnv(env_id.removeprefix("rdpg/"), num_envs, **kwargs)


def zoo(name: str) -> Path:
    """The directory of zoo entry ``name`` (e.g. ``"walker-td3"``), from any working
    directory: under ``$RDPG_ZOO`` when set, else in the ``zoo/`` of the checkout the package
    was installed from."""
    root = os.environ.get("RDPG_ZOO")
    base = Path(root) if root else Path(__file__).resolve().parents[4] / "zoo"
    path = base / name
    if not (path / "agent").is_dir():
        raise FileNotFoundError(
            f"{path}: no zoo entry {name!r} (set RDPG_ZOO to the zoo directory of an rdpg checkout)"
        )
    return path


def _register() -> None:
    for env_id, steps in ENV_IDS.items():
        gym.register(
            id=f"rdpg/{env_id}",
            entry_point=RdpgEnv,
            vector_entry_point=RdpgVectorEnv,
            max_episode_steps=steps,
            kwargs={"env_id": env_id},
        )


_register()
