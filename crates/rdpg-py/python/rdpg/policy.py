"""Trained rdpg agents for Python: ``rdpg.Policy``.

The policy extension (``rdpg._policy``) links libtorch, so it is imported, after torch, the
first time a policy is loaded: ``import rdpg`` and the environments load no libtorch.
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

import numpy as np

from ._util import count, f32, spaces_of


def _extension():
    """The policy extension, with the libtorch it links loaded first (by importing torch)."""
    import torch  # noqa: F401

    try:
        from . import _policy
    except ImportError as e:
        raise ImportError(
            f"rdpg's policy module is not built ({e}): run scripts/setup/setup_python.sh"
        ) from e
    return _policy


def _unpickle(path: str, checkpoint: str, memory: int | None = None) -> "Policy":
    if not Path(path).is_dir():
        raise FileNotFoundError(
            f"{path}: the directory of the pickled policy is gone (a Policy pickles as its "
            "directory and checkpoint, not its weights)"
        )
    return Policy.load(path, checkpoint, memory=memory)


class Policy:
    """A trained rdpg agent (a run directory, or a zoo entry), acting deterministically on full
    observations of its environment (a run trained with hidden observation components or its
    previous action as input builds that view itself).

    ``Policy.load(path, checkpoint="best", memory=None)``: a run's ``"best"``, ``"latest"``,
    ``"selected"`` (by ``rdpg select``) or a kept agent's step; a zoo entry has its one agent.
    ``memory=k`` probes a recurrent agent's memory as ``rdpg eval --memory k`` does: it acts
    remembering at most its last ``k`` observations (its state re-encoded from zero over
    them at every step).

    - ``make_env(**overrides)`` / ``make_vec(n)``: the env the policy was trained for (its id
      and action repeat; stock reward unless overridden). ``check_env(env)`` refuses an env
      whose options disagree with the policy's, where that can be seen.
    - ``predict(obs, state, episode_start)``: Stable-Baselines3's contract, with the recurrent
      state passed in and returned (``evaluate_policy(policy, env)`` works).
    - ``act(obs)`` for one env; ``act_batch(obs)`` for ``[n, obs_dim]`` observations of a
      vector env, row ``i`` with its own state (``reset_one(i)`` when sub-env ``i`` starts an
      episode); ``reset()`` starts new episodes for both. Their states are separate.
    - ``to_torch()``: the actor as a ``torch.nn.Module`` (exportable to ONNX).

    ``action_repeat`` is the number of frames each action was held for in training: the env of
    ``make_env`` does that. A policy pickles as its directory and checkpoint.
    """

    def __init__(self, inner: Any, path: Path, checkpoint: str, memory: int | None = None):
        from . import _rdpg

        self._p = inner
        self.path = path
        self.checkpoint = checkpoint
        #: The observations the policy remembers at most (``None``: its whole episode).
        self.memory = memory
        self.env_id: str = inner.env_id
        self.algo: str = inner.algo
        self.action_repeat: int = inner.action_repeat
        with open(path / "config.toml", "rb") as f:
            #: The run's resolved config (``config.toml``).
            self.config: dict[str, Any] = tomllib.load(f)
        one = _rdpg.Env(self.env_id)
        self.observation_space = spaces_of(*one.observation_bounds())
        self.action_space = spaces_of(*one.action_bounds())
        #: Values of one environment's state in ``predict`` (0: the policy carries none).
        self.state_len: int = inner.state_len

    @classmethod
    def load(
        cls, path: str | Path, checkpoint: str | int = "best", memory: int | None = None
    ) -> "Policy":
        path = Path(path)
        if not path.exists():
            raise FileNotFoundError(f"{path}: no such run or zoo directory")
        if memory is not None and (not isinstance(memory, int) or memory < 1):
            raise ValueError(f"memory={memory!r}: an int, at least 1 (observations remembered)")
        inner = _extension().Policy(str(path), str(checkpoint), memory)
        return cls(inner, path, str(checkpoint), memory)

    def __reduce__(self):
        return (_unpickle, (str(self.path.resolve()), self.checkpoint, self.memory))

    def __repr__(self) -> str:
        memory = "" if self.memory is None else f", memory={self.memory}"
        return (
            f"Policy({str(self.path)!r}, checkpoint={self.checkpoint!r}{memory}: "
            f"{self.algo} on {self.env_id})"
        )

    # --- the env it acts in -------------------------------------------------------------

    def _env_kwargs(self, overrides: dict[str, Any]) -> dict[str, Any]:
        for key, mine in (("action_repeat", self.action_repeat), ("hide_obs", ())):
            if key in overrides and tuple(np.atleast_1d(overrides[key])) != tuple(np.atleast_1d(mine)):
                raise ValueError(
                    f"{key}={overrides[key]!r}: this policy acts with {key}={mine!r} (it takes "
                    "full observations and applies its own mask)"
                )
        return {**overrides, "action_repeat": self.action_repeat}

    def make_env(self, **overrides: Any):
        """``gymnasium.make("rdpg/<env_id>")`` with the policy's action repeat; ``overrides``
        (``render_mode``, ``reward``, ``fall_penalty``, ...) go to ``RdpgEnv``. The reward is
        the stock one unless overridden, as in ``rdpg eval``."""
        import gymnasium as gym

        return gym.make(f"rdpg/{self.env_id}", **self._env_kwargs(overrides))

    def make_vec(self, num_envs: int, **overrides: Any):
        """``rdpg.make_vec`` of the policy's env with its action repeat (see ``make_env``)."""
        from . import make_vec

        return make_vec(self.env_id, num_envs, **self._env_kwargs(overrides))

    def check_env(self, env: Any) -> None:
        """Raises ``ValueError`` when ``env`` (a Gymnasium env or vector env, wrapped or not,
        or a Stable-Baselines3 VecEnv) is not one this policy acts in: another env id, another
        action repeat (Gymnasium's own walkers step one frame per action), hidden observation
        components."""
        from . import RdpgEnv, RdpgVectorEnv

        for e in getattr(env, "envs", None) or [env]:
            base = getattr(e, "unwrapped", e)
            if isinstance(base, (RdpgEnv, RdpgVectorEnv)):
                env_id, repeat, hide = base.env_id, base.action_repeat, base.hide_obs
            else:
                spec = getattr(e, "spec", None) or getattr(base, "spec", None)
                env_id, repeat, hide = (spec.id if spec else None), 1, ()
            problems = []
            if env_id is not None and env_id.removeprefix("rdpg/") != self.env_id:
                problems.append(f"it is {env_id}, the policy's is {self.env_id}")
            if repeat != self.action_repeat:
                problems.append(
                    f"it holds each action for {repeat} frame(s), the policy was trained "
                    f"holding it for {self.action_repeat}"
                )
            if hide:
                problems.append(f"it hides observation components {list(hide)}")
            if problems:
                raise ValueError(
                    f"{self.path}: not the env this policy acts in ({'; '.join(problems)}): "
                    "use policy.make_env()"
                )

    # --- acting ---------------------------------------------------------------------------

    def reset(self) -> None:
        """Starts new episodes for ``act`` and every environment of ``act_batch``."""
        self._p.reset()

    def reset_one(self, i: int) -> None:
        """Starts a new episode for environment ``i`` of ``act_batch``."""
        self._p.reset_one(count("i", i))

    def _observations(self, obs: Any) -> tuple[np.ndarray, bool]:
        o = np.asarray(obs, dtype=np.float32)
        shape = self.observation_space.shape
        if o.shape == shape:
            return o[None], True
        if o.ndim != 2 or o.shape[1:] != shape:
            raise ValueError(f"observations of shape {o.shape}, expected {shape} or (n, {shape[0]})")
        return np.ascontiguousarray(o), False

    def act(self, obs: Any) -> np.ndarray:
        """The action for one observation, continuing ``act``'s own state."""
        o, single = self._observations(obs)
        if not single:
            raise ValueError(f"observation of shape {o.shape}, expected {self.observation_space.shape}")
        return f32(self._p.act(o.tobytes()), self.action_space.shape)

    def act_batch(self, obs: Any) -> np.ndarray:
        """Actions for ``[n, obs_dim]`` observations, row ``i`` continuing its own state."""
        o, single = self._observations(obs)
        if single:
            raise ValueError(f"observations of shape {o.shape[1:]}, expected (n, {o.shape[1]})")
        n = o.shape[0]
        return f32(self._p.act_batch(o.tobytes(), n), (n,) + self.action_space.shape)

    def predict(
        self,
        observation: Any,
        state: Any = None,
        episode_start: Any = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """Stable-Baselines3's ``predict``: ``(actions, state)`` for one observation or a batch
        ``[n, obs_dim]``. ``state`` is what the previous call returned (``[n, state_len]``;
        None: every environment starts an episode); ``episode_start[i]`` true starts
        environment ``i``'s episode afresh. A stateless policy returns None as its state. Only
        deterministic actions: exploration belongs to training."""
        if not deterministic:
            raise ValueError("rdpg policies act deterministically: call predict(..., deterministic=True)")
        o, single = self._observations(observation)
        n = o.shape[0]
        if episode_start is None:
            starts = np.full(n, state is None)
        else:
            starts = np.asarray(episode_start, dtype=bool).reshape(-1)
            if starts.shape != (n,):
                raise ValueError(f"episode_start of {starts.size} values for {n} observation(s)")
        width = self.state_len
        raw = None
        if state is not None and width:
            s = np.asarray(state, dtype=np.float32)
            if s.size != n * width:
                raise ValueError(f"state of shape {s.shape}, expected ({n}, {width}) as predict returned it")
            raw = np.ascontiguousarray(s.reshape(n, width)).tobytes()
        actions, states = self._p.act_states(o.tobytes(), n, raw, starts.tolist())
        a = f32(actions, (n,) + self.action_space.shape)
        return (a[0] if single else a), (f32(states, (n, width)) if width else None)

    # --- export ---------------------------------------------------------------------------

    def to_torch(self):
        """The actor as a ``torch.nn.Module`` giving this policy's actions: ``forward(obs
        [n, obs_dim], state) -> (actions [n, act_dim], state)`` on full observations, with
        ``initial_state(n)``; see ``rdpg._torch`` for each agent kind's state. The agent as
        trained: a policy loaded with ``memory`` is refused."""
        from ._torch import to_torch

        if self.memory is not None:
            raise ValueError(
                f"to_torch exports the agent as trained; load it without memory={self.memory}"
            )

        return to_torch(
            Path(self._p.agent_dir),
            self.config,
            self.observation_space.low,
            self.observation_space.high,
            self.action_space.low,
            self.action_space.high,
        )
