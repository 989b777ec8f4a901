"""rdpg as a Stable-Baselines3 / Gymnasium user meets it: ``import rdpg`` without libtorch,
``Policy.make_env`` / ``check_env``, SB3's ``predict`` contract and ``evaluate_policy``,
vector-env infos equal to ``SyncVectorEnv``'s, pickling, and SB3 training on rdpg's walker
equal to training on Gymnasium's."""

from __future__ import annotations

import pickle
import shutil
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode, SyncVectorEnv

import rdpg
from helpers import ROOT, ZOO, eval_returns, train_window_run

TEST_SEED = 3_000_000


def _zoo(name: str) -> Path:
    path = ZOO / name
    if not (path / "agent").is_dir():
        pytest.skip(f"{path} is not in this checkout")
    return path


def test_import_rdpg_and_its_envs_load_no_libtorch():
    code = (
        "import sys, gymnasium as gym, rdpg\n"
        "env = gym.make('rdpg/BipedalWalker-v3'); env.reset(seed=0); env.step(env.action_space.sample())\n"
        "vec = rdpg.make_vec('BipedalWalker-v3', 2); vec.reset(seed=0)\n"
        "maps = open('/proc/self/maps').read()\n"
        "print('torch' in sys.modules, 'libtorch' in maps)\n"
        f"rdpg.Policy.load({str(ZOO / 'walker-td3')!r})\n"
        "print('torch' in sys.modules, 'libtorch' in open('/proc/self/maps').read())\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False", "False", "True", "True"], out.stdout + out.stderr


def test_make_env_builds_the_env_the_policy_was_trained_for_and_check_env_refuses_others():
    policy = rdpg.Policy.load(_zoo("hardcore-td3-paper"))
    assert policy.action_repeat == 3
    env = policy.make_env()
    assert env.unwrapped.action_repeat == 3 and env.unwrapped.reward == "stock"
    policy.check_env(env)
    policy.check_env(policy.make_vec(2))
    for other, why in [
        (gym.make("BipedalWalkerHardcore-v3"), "for 1 frame"),
        (gym.make("rdpg/BipedalWalkerHardcore-v3"), "for 1 frame"),
        (gym.make("rdpg/BipedalWalker-v3", action_repeat=3), "BipedalWalker-v3"),
        (gym.make("rdpg/BipedalWalkerHardcore-v3", action_repeat=3, hide_obs=[2]), "hides"),
    ]:
        with pytest.raises(ValueError, match=why):
            policy.check_env(other)
    with pytest.raises(ValueError, match="action_repeat"):
        policy.make_env(action_repeat=1)
    # The policy's return in its own env is rdpg eval's (the frames summed in the env, in
    # the same order).
    want = eval_returns(policy.path, "--episodes", "1", "--seed", str(TEST_SEED))
    obs, _ = env.reset(seed=TEST_SEED)
    ret, done, state = 0.0, False, None
    while not done:
        action, state = policy.predict(obs, state)
        obs, r, term, trunc, _ = env.step(action)
        ret, done = ret + r, term or trunc
    assert [ret] == want


def _episode_obs(policy: rdpg.Policy, seed: int, steps: int) -> np.ndarray:
    env = policy.make_env()
    obs, _ = env.reset(seed=seed)
    seen = [obs]
    policy.reset()
    for _ in range(steps - 1):
        obs, _, term, trunc, _ = env.step(policy.act(obs))
        if term or trunc:
            break
        seen.append(obs)
    return np.array(seen)


@pytest.mark.parametrize("name", ["walker-rdpg", "walker-td3", "hardcore-td3-paper"])
def test_predict_follows_sb3s_contract_with_an_explicit_state(name):
    policy = rdpg.Policy.load(_zoo(name))
    runs = [_episode_obs(policy, TEST_SEED + k, 60) for k in range(2)]
    n = min(len(r) for r in runs)
    # What act gives on each episode alone, from its start.
    want = []
    for r in runs:
        policy.reset()
        want.append(np.array([policy.act(o) for o in r[:n]]))
    # predict over both episodes at once, the state threaded through the calls.
    state = None
    for t in range(n):
        start = np.array([t == 0, t == 0])
        actions, state = policy.predict(np.stack([r[t] for r in runs]), state, start)
        assert actions.shape == (2,) + policy.action_space.shape
        np.testing.assert_array_equal(actions, np.stack([w[t] for w in want]))
        if policy.state_len:
            assert state.shape == (2, policy.state_len) and state.dtype == np.float32
        else:
            assert state is None
    # One observation gives one action; episode_start restarts a row whatever its state.
    action, one = policy.predict(runs[0][0])
    np.testing.assert_array_equal(action, want[0][0])
    if policy.state_len:
        again, _ = policy.predict(runs[0][:1], state[:1] + 7.0, np.array([True]))
        np.testing.assert_array_equal(again[0], want[0][0])
        with pytest.raises(ValueError, match="state of shape"):
            policy.predict(runs[0][:1], np.zeros((1, policy.state_len + 1)))
    with pytest.raises(ValueError, match="deterministic"):
        policy.predict(runs[0][0], deterministic=False)


@pytest.fixture(scope="module")
def window_run(tmp_path_factory) -> Path:
    """A tiny window-of-k (k = 4) recurrent run on the cue task, trained by the rdpg binary."""
    return train_window_run(tmp_path_factory.mktemp("runs") / "window")


def test_predict_carries_a_window_of_k_agents_observations(window_run):
    policy = rdpg.Policy.load(window_run)
    obs_dim = policy.observation_space.shape[0]
    assert policy.state_len == 1 + 3 * obs_dim  # how many are real, then the last k - 1
    env = policy.make_env()
    for seed in range(3):
        obs, _ = env.reset(seed=seed)
        policy.reset()
        state, done = None, False
        while not done:
            a, state = policy.predict(obs, state)
            np.testing.assert_array_equal(a, policy.act(obs))
            np.testing.assert_array_equal(state[0, -obs_dim:], obs)
            obs, _, term, trunc, _ = env.step(a)
            done = term or trunc
    with pytest.raises(ValueError, match="window length"):
        bad = state.copy()
        bad[0, 0] = 9.0
        policy.predict(obs, bad)


def test_act_and_act_batch_keep_separate_states():
    policy = rdpg.Policy.load(_zoo("walker-rdpg"))
    obs = _episode_obs(policy, TEST_SEED, 20)
    policy.reset()
    alone = [policy.act(o) for o in obs]
    policy.reset()
    mixed = []
    for o in obs:
        policy.act_batch(np.stack([o[::-1].copy(), o]))  # another stream in the batch
        mixed.append(policy.act(o))
    np.testing.assert_array_equal(np.array(mixed), np.array(alone))


def _same_infos(a: dict, b: dict, where: str) -> None:
    assert a.keys() == b.keys(), where
    for k in a:
        if isinstance(a[k], dict):
            _same_infos(a[k], b[k], f"{where}.{k}")
        elif k == "final_obs":
            for x, y in zip(a[k], b[k]):
                assert (x is None and y is None) or np.array_equal(x, y), where
        elif k == "final_info":
            for x, y in zip(a[k], b[k]):
                assert (x is None and y is None) or x.keys() == y.keys(), where
        else:
            assert a[k].dtype == b[k].dtype and np.array_equal(a[k], b[k]), f"{where}.{k}"


@pytest.mark.parametrize("mode", [AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP])
def test_vector_env_infos_are_sync_vector_envs(mode):
    # Paper reward and a fall penalty: every info key a walker has (stock_reward, success,
    # obstacles); wild actions end episodes early, so autoresets happen.
    kw = dict(reward="paper", fall_penalty=-10.0)
    ours = rdpg.make_vec("BipedalWalkerHardcore-v3", 3, autoreset_mode=mode, **kw)
    theirs = SyncVectorEnv(
        [lambda: rdpg.RdpgEnv("BipedalWalkerHardcore-v3", **kw) for _ in range(3)],
        autoreset_mode=mode,
    )
    oa, _ = ours.reset(seed=11)
    ob, _ = theirs.reset(seed=11)
    assert np.array_equal(oa, ob)
    rng = np.random.default_rng(0)
    ended = 0
    for t in range(300):
        act = rng.uniform(-1, 1, (3, 4)).astype(np.float32)
        ra, rb = ours.step(act), theirs.step(act)
        for k in range(4):
            assert np.array_equal(ra[k], rb[k]), (t, k)
        _same_infos(ra[4], rb[4], f"step {t}")
        ended += int(ra[2].sum() + ra[3].sum())
    assert ended >= 3


def test_a_policy_pickles_as_its_directory(tmp_path):
    entry = tmp_path / "walker-rdpg"
    shutil.copytree(_zoo("walker-rdpg"), entry)
    policy = rdpg.Policy.load(entry)
    obs = _episode_obs(policy, TEST_SEED, 5)
    copy = pickle.loads(pickle.dumps(policy))
    policy.reset()
    copy.reset()
    for o in obs:
        np.testing.assert_array_equal(copy.act(o), policy.act(o))
    data = pickle.dumps(policy)
    shutil.rmtree(entry)
    with pytest.raises(FileNotFoundError, match=str(entry)):
        pickle.loads(data)


def test_memory_probes_as_rdpg_eval_does(tmp_path):
    # A recurrent agent limited to its last k observations: every acting form agrees, the
    # returns are `rdpg eval --memory k`'s, and the limit survives pickling.
    entry = _zoo("walker-rdpg")
    policy = rdpg.Policy.load(entry, memory=2)
    assert "memory=2" in repr(policy)
    want = eval_returns(entry, "--episodes", "1", "--seed", str(TEST_SEED), "--memory", "2")
    env = policy.make_env()
    obs, _ = env.reset(seed=TEST_SEED)
    policy.reset()
    copy = pickle.loads(pickle.dumps(policy))
    copy.reset()
    ret, done, state = 0.0, False, None
    while not done:
        a = policy.act(obs)
        np.testing.assert_array_equal(policy.act_batch(obs[None])[0], a)
        np.testing.assert_array_equal(copy.act(obs), a)
        action, state = policy.predict(obs, state)
        np.testing.assert_array_equal(action, a)
        obs, r, term, trunc, _ = env.step(a)
        ret, done = ret + r, term or trunc
    assert [ret] == want
    assert want != eval_returns(entry, "--episodes", "1", "--seed", str(TEST_SEED))
    with pytest.raises(ValueError, match="as trained"):
        policy.to_torch()
    with pytest.raises(ValueError, match="at least 1"):
        rdpg.Policy.load(entry, memory=0)
    with pytest.raises(ValueError, match="feed-forward"):
        rdpg.Policy.load(_zoo("walker-td3"), memory=4)


class _TestSeeds(gym.Wrapper):
    """Resets episode ``k`` with seed ``3000000 + k``, as ``rdpg eval`` does (SB3's vector
    env seeds only the first reset)."""

    def __init__(self, env: gym.Env):
        super().__init__(env)
        self.k = 0

    def reset(self, *, seed=None, options=None):
        self.k += 1
        return self.env.reset(seed=TEST_SEED + self.k - 1, options=options)


@pytest.mark.parametrize("name", ["walker-rdpg", "hardcore-td3-paper"])
def test_sb3_evaluate_policy_gives_rdpg_evals_returns(name):
    pytest.importorskip("stable_baselines3")
    from stable_baselines3.common.evaluation import evaluate_policy
    from stable_baselines3.common.monitor import Monitor

    policy = rdpg.Policy.load(_zoo(name))
    episodes = 2
    want = eval_returns(policy.path, "--episodes", str(episodes), "--seed", str(TEST_SEED))
    returns, lengths = evaluate_policy(
        policy, Monitor(_TestSeeds(policy.make_env())), n_eval_episodes=episodes,
        return_episode_rewards=True,
    )
    # Monitor rounds each return to 6 decimals.
    assert returns == pytest.approx(want, abs=1e-6)


def test_sb3_trains_on_rdpg_walker_exactly_as_on_gymnasiums():
    pytest.importorskip("stable_baselines3")
    import torch
    from stable_baselines3 import PPO

    params = []
    for make in (lambda: gym.make("rdpg/BipedalWalker-v3"), lambda: gym.make("BipedalWalker-v3")):
        model = PPO("MlpPolicy", make(), n_steps=512, batch_size=128, n_epochs=2, seed=0,
                    device="cpu")
        model.learn(total_timesteps=2048)
        params.append(model.policy.state_dict())
    assert params[0].keys() == params[1].keys()
    for k in params[0]:
        assert torch.equal(params[0][k], params[1][k]), k


def test_the_readmes_python_example_runs_from_any_directory(tmp_path):
    text = (ROOT / "README.md").read_text()
    section = text[text.index("\n## Python\n"):]
    code = section[section.index("```python\n") + 10 : section.index("\n```", section.index("```python\n"))]
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    assert lines[0].startswith("return ") and "crossed the course" in lines[0], out.stdout
    assert lines[1].startswith("SB3 evaluate_policy: ("), out.stdout
    assert lines[2].startswith("tensor([["), out.stdout
