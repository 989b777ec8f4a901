"""rdpg for Python: rdpg's environments under Gymnasium ids, a vector env, trained policies.

    import gymnasium as gym
    import rdpg                                   # registers the rdpg/... ids

    env = gym.make("rdpg/BipedalWalker-v3")       # bit-identical to gym.make("BipedalWalker-v3")
    policy = rdpg.Policy.load("zoo/walker-td3")   # a run or zoo directory
    obs, _ = env.reset(seed=3_000_000)
    policy.reset()
    done = False
    while not done:
        obs, r, term, trunc, _ = env.step(policy.act(obs))
        done = term or trunc

Environments step in Rust (the GIL released); the vector env steps its environments on Rust
threads with Gymnasium's default next-step autoreset. Errors raised by the Rust side are
``ValueError`` (bad input: unknown id, wrong action shape, NaN, bad policy directory) or
``RuntimeError`` (a failure inside an environment), with the Rust message.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

# The extension links the libtorch of the installed torch: importing torch first loads it.
import torch  # noqa: F401

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from . import _rdpg

__all__ = ["RdpgEnv", "RdpgVectorEnv", "Policy", "ENV_IDS", "make_vec"]

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


def _f32(b: bytes, shape: tuple[int, ...]) -> np.ndarray:
    return np.frombuffer(b, dtype=np.float32).reshape(shape).copy()


def _spaces(low: list[float], high: list[float]) -> spaces.Box:
    return spaces.Box(np.array(low, np.float32), np.array(high, np.float32), dtype=np.float32)


def _seed_words(seed: int) -> list[int]:
    """A seed of any size as its little-endian 32-bit words, as numpy's ``SeedSequence`` reads
    an int (Gymnasium seeds with any non-negative int)."""
    seed, words = int(seed), []
    while True:
        words.append(seed & 0xFFFFFFFF)
        seed >>= 32
        if not seed:
            return words


def _count(name: str, value: Any, least: int = 0) -> int:
    """``value`` as an int of at least ``least``, or a ValueError/TypeError naming ``name``
    (rather than the extension's bare OverflowError)."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise TypeError(f"{name}: an int, got {type(value).__name__}")
    if value < least:
        raise ValueError(f"{name} = {value}: must be at least {least}")
    return int(value)


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
        obs, reward, terminated, truncated, success, stock, course = self._env.step(
            _action_bytes(action, self.action_space.shape)
        )
        info: dict[str, Any] = {"success": success}
        if stock is not None:
            info["stock_reward"] = stock
        if course is not None:
            # Walkers: the stump, staircase or pit the hull is over or just in front of, and
            # the obstacles passed so far (what `rdpg eval` counts per obstacle kind).
            at, stump, stairs, pit = course
            info["obstacles_passed"] = {"stump": stump, "stairs": stairs, "pit": pit}
            if at is not None:
                info["obstacle"] = at
        return _f32(obs, self.observation_space.shape), reward, terminated, truncated, info

    def render(self):
        if self.render_mode != "rgb_array":
            return None
        rgb, h, w = self._env.render()
        return np.frombuffer(rgb, dtype=np.uint8).reshape(h, w, 3).copy()


class RdpgVectorEnv(VectorEnv):
    """``num_envs`` rdpg environments stepped in parallel on Rust threads (GIL released),
    each with its registered time limit.

    Autoreset: ``AutoresetMode.NEXT_STEP``, Gymnasium's default: the step that ends an episode
    returns its last observation; the next step of that sub-env ignores its action and returns
    the first observation of a new episode (reward 0, both flags false). ``reset(seed=s)``
    seeds sub-env ``i`` with ``s + i``, as Gymnasium's ``SyncVectorEnv`` does.
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
    ):
        # `gymnasium.make_vec` passes the registration's `max_episode_steps`: each sub-env
        # keeps its registered time limit, so only that value is accepted; any other keyword
        # is a TypeError, as for the single env.
        if max_episode_steps not in (None, ENV_IDS.get(env_id)):
            raise ValueError(
                f"max_episode_steps = {max_episode_steps}: the vector env keeps {env_id}'s "
                f"registered limit {ENV_IDS.get(env_id)}"
            )
        hide = _indices("hide_obs", hide_obs)
        self._env = _rdpg.VecEnv(
            env_id,
            _count("num_envs", num_envs, 1),
            reward,
            hide,
            None if threads is None else _count("threads", threads, 1),
            fall_penalty,
            _count("action_repeat", action_repeat, 1),
        )
        one = _rdpg.Env(env_id, reward, hide)
        self.num_envs = num_envs
        self.single_observation_space = _spaces(*one.observation_bounds())
        self.single_action_space = _spaces(*one.action_bounds())
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self.action_space = batch_space(self.single_action_space, num_envs)
        self.metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP}
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
        obs, rew, term, trunc = self._env.step(_action_bytes(actions, self._act_shape))
        return (
            _f32(obs, self._obs_shape),
            np.frombuffer(rew, dtype=np.float64).copy(),
            np.frombuffer(term, dtype=np.uint8).astype(bool),
            np.frombuffer(trunc, dtype=np.uint8).astype(bool),
            {},
        )


def make_vec(env_id: str, num_envs: int, **kwargs: Any) -> RdpgVectorEnv:
    """The vector env of ``rdpg/<id>`` (or ``<id>``) with ``num_envs`` sub-envs."""
    return RdpgVectorEnv(env_id.removeprefix("rdpg/"), num_envs, **kwargs)


class Policy:
    """A trained rdpg agent (a run directory, or a zoo entry), acting deterministically.

    ``Policy.load(path, checkpoint="best")`` (a run's ``"latest"``, ``"selected"`` by
    ``rdpg select``, or a kept agent's step; a zoo entry has its one agent); ``reset()`` at the start of each episode (recurrent agents keep
    their state inside); ``act(obs)`` for one observation of a plain Gymnasium env of the
    agent's ``env_id`` (a run trained with hidden observation components drops them itself);
    ``act_batch(obs)`` for ``[n, obs_dim]`` observations of a vector env, each row with its
    own state (``reset_one(i)`` when sub-env ``i`` starts a new episode). ``action_repeat``
    is the number of frames each action was held for in training (1 for most agents): step
    the env that many times with each action, as ``rdpg eval`` does.
    """

    def __init__(self, inner: _rdpg.Policy, path: Path):
        self._p = inner
        self.path = path
        self.env_id: str = inner.env_id
        self.algo: str = inner.algo
        self.action_repeat: int = inner.action_repeat
        one = _rdpg.Env(self.env_id)
        self.observation_space = _spaces(*one.observation_bounds())
        self.action_space = _spaces(*one.action_bounds())

    @classmethod
    def load(cls, path: str | Path, checkpoint: str | int = "best") -> "Policy":
        path = Path(path)
        return cls(_rdpg.Policy(str(path), str(checkpoint)), path)

    def reset(self) -> None:
        self._p.reset()

    def reset_one(self, i: int) -> None:
        self._p.reset_one(_count("i", i))

    def act(self, obs) -> np.ndarray:
        o = np.asarray(obs, dtype=np.float32)
        if o.shape != self.observation_space.shape:
            raise ValueError(f"observation of shape {o.shape}, expected {self.observation_space.shape}")
        return _f32(self._p.act(o.tobytes()), self.action_space.shape)

    def act_batch(self, obs) -> np.ndarray:
        o = np.asarray(obs, dtype=np.float32)
        if o.ndim != 2 or o.shape[1:] != self.observation_space.shape:
            raise ValueError(f"observations of shape {o.shape}, expected (n, {self.observation_space.shape[0]})")
        n = o.shape[0]
        return _f32(self._p.act_batch(np.ascontiguousarray(o).tobytes(), n), (n,) + self.action_space.shape)


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
