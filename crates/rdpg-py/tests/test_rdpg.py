"""The rdpg Python package against Gymnasium 1.4.0 (run by scripts/test.sh with pytest).

Parity is exact: the same seeds and float32 actions give Gymnasium's observations, rewards,
`terminated` and `truncated` bit for bit, over whole episodes, in fresh and reused envs.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import rdpg
from helpers import ROOT, eval_returns, train



def _episode_actions(rng: np.random.Generator, n: int, calm: bool) -> np.ndarray:
    # Calm actions keep a walker up until the time limit (truncation); wild ones make it fall.
    scale = 0.05 if calm else 1.0
    return (rng.uniform(-1, 1, (n, 4)) * scale).astype(np.float32)


def _same_episode(a: gym.Env, b: gym.Env, seed: int | None, actions: np.ndarray) -> str:
    oa, _ = a.reset(seed=seed)
    ob, _ = b.reset(seed=seed)
    assert oa.dtype == ob.dtype == np.float32
    assert np.array_equal(oa, ob)
    for k, act in enumerate(actions):
        ra, rb = a.step(act), b.step(act)
        assert np.array_equal(ra[0], rb[0]), f"obs at step {k}"
        assert ra[1] == rb[1], f"reward at step {k}"
        assert (ra[2], ra[3]) == (rb[2], rb[3]), f"flags at step {k}"
        if ra[2] or ra[3]:
            return "terminated" if ra[2] else "truncated"
    raise AssertionError("the episode did not end")


@pytest.mark.parametrize("env_id", ["BipedalWalker-v3", "BipedalWalkerHardcore-v3"])
def test_walkers_equal_gymnasium_over_whole_episodes_fresh_and_reused(env_id):
    ours, theirs = gym.make(f"rdpg/{env_id}"), gym.make(env_id)
    rng = np.random.default_rng(7)
    steps = 2000 if "Hardcore" in env_id else 1600
    endings = []
    # Fresh envs' first episodes, then the same envs reused: seeded resets, and a reset
    # without a seed that continues each env's random stream.
    for seed, calm in [(11, False), (12, True), (None, False), (13, False)]:
        endings.append(_same_episode(ours, theirs, seed, _episode_actions(rng, steps, calm)))
    assert "terminated" in endings
    if "Hardcore" not in env_id:
        assert "truncated" in endings, "the time limit was not reached"


def test_every_id_passes_gymnasium_check_env():
    for env_id in rdpg.ENV_IDS:
        env = gym.make(f"rdpg/{env_id}")
        check_env(env.unwrapped, skip_render_check=True)
        assert env.spec.max_episode_steps == rdpg.ENV_IDS[env_id]


def test_options_and_rendering():
    env = gym.make("rdpg/BipedalWalker-v3", reward="paper", hide_obs=[1, 2, 3])
    obs, _ = env.reset(seed=0)
    assert obs.shape == (21,)
    _, _, _, _, info = env.step(np.zeros(4, np.float32))
    assert "stock_reward" in info
    assert info["obstacles_passed"] == {"stump": 0, "stairs": 0, "pit": 0}
    # Hardcore: standing still at the start, no obstacle at hand; a course has obstacles.
    env = gym.make("rdpg/BipedalWalkerHardcore-v3")
    env.reset(seed=0)
    _, _, _, _, info = env.step(np.zeros(4, np.float32))
    assert "obstacle" not in info and sum(info["obstacles_passed"].values()) == 0
    env = gym.make("rdpg/BipedalWalker-v3", render_mode="rgb_array")
    env.reset(seed=0)
    frame = env.render()
    assert frame.shape == (400, 600, 3) and frame.dtype == np.uint8 and frame.std() > 0


def test_hardcore_training_options_as_kwargs():
    """``action_repeat`` and ``fall_penalty`` (as in ``rdpg train``): the same frames as holding
    each action for 3 steps of the plain env, the stock rewards summed in
    ``info["stock_reward"]``, the reward the same but for a fall's -100 replaced by the
    penalty; the time limit counts frames."""
    k = 3
    ours = gym.make("rdpg/BipedalWalkerHardcore-v3", action_repeat=k, fall_penalty=-1.0)
    plain = gym.make("rdpg/BipedalWalkerHardcore-v3")
    oa, _ = ours.reset(seed=5)
    ob, _ = plain.reset(seed=5)
    assert np.array_equal(oa, ob)
    rng = np.random.default_rng(0)
    for step in range(2000):
        a = rng.uniform(-1, 1, 4).astype(np.float32)
        oa, ra, terma, trunca, info = ours.step(a)
        stock = 0.0
        for _ in range(k):
            ob, rb, termb, truncb, _ = plain.step(a)
            stock += rb
            if termb or truncb:
                break
        assert np.array_equal(oa, ob), f"step {step}"
        assert (terma, trunca) == (termb, truncb)
        assert info["stock_reward"] == pytest.approx(stock, rel=1e-12)
        fell = terma and rb == -100.0
        assert ra == pytest.approx(stock + 100.0 - 1.0 if fell else stock, rel=1e-12)
        if terma or trunca:
            break
    assert terma and fell, "random actions should make the walker fall"
    env = gym.make("rdpg/Pendulum-v1", action_repeat=k)
    env.reset(seed=0)
    steps, done = 0, False
    while not done:
        _, _, term, trunc, _ = env.step(np.zeros(1, np.float32))
        steps, done = steps + 1, term or trunc
    assert trunc and steps == -(-200 // k)
    vec = rdpg.make_vec("BipedalWalkerHardcore-v3", 2, action_repeat=k, fall_penalty=-1.0)
    vec.reset(seed=5)
    with pytest.raises(ValueError, match="action_repeat = 0"):
        gym.make("rdpg/BipedalWalker-v3", action_repeat=0)


def test_vector_env_equals_gymnasium_sync_vector_env_with_next_step_autoreset():
    n = 3
    ours = gym.make_vec("rdpg/BipedalWalker-v3", num_envs=n, vectorization_mode="vector_entry_point")
    theirs = gym.vector.SyncVectorEnv([lambda: gym.make("BipedalWalker-v3") for _ in range(n)])
    assert ours.metadata["autoreset_mode"] == theirs.metadata["autoreset_mode"]
    assert ours.single_observation_space == theirs.single_observation_space
    oa, _ = ours.reset(seed=40)
    ob, _ = theirs.reset(seed=40)
    assert np.array_equal(oa, ob)
    rng = np.random.default_rng(1)
    ended, reset_after_end = 0, False
    for k in range(300):
        act = rng.uniform(-1, 1, (n, 4)).astype(np.float32)
        ra, rb = ours.step(act), theirs.step(act)
        for i in range(4):
            assert np.array_equal(ra[i], rb[i]), f"field {i} at step {k}"
        ended += int(ra[2].sum() + ra[3].sum())
        if ended and not reset_after_end:
            # An unseeded reset right after an episode ended (its autoreset still pending).
            oa, _ = ours.reset()
            ob, _ = theirs.reset()
            assert np.array_equal(oa, ob)
            reset_after_end = True
    assert ended >= 2 and reset_after_end, "the autoreset path was not exercised"


def test_seeds_past_64_bits_seed_as_gymnasium_does():
    # Gymnasium seeds numpy's SeedSequence with any non-negative int; env i of a vector env
    # gets seed + i, past 2**64 too.
    for seed in [2**64 - 1, 2**64, 2**100 + 7]:
        ours, _ = gym.make("rdpg/BipedalWalkerHardcore-v3").reset(seed=seed)
        theirs, _ = gym.make("BipedalWalkerHardcore-v3").reset(seed=seed)
        assert np.array_equal(ours, theirs), seed
    ours = gym.make_vec("rdpg/BipedalWalker-v3", num_envs=2, vectorization_mode="vector_entry_point")
    theirs = gym.vector.SyncVectorEnv([lambda: gym.make("BipedalWalker-v3") for _ in range(2)])
    oa, _ = ours.reset(seed=2**64 - 1)
    ob, _ = theirs.reset(seed=2**64 - 1)
    assert np.array_equal(oa, ob)
    act = np.full((2, 4), 0.3, np.float32)
    assert np.array_equal(ours.step(act)[0], theirs.step(act)[0])


def test_bad_input_raises_with_the_rust_message(tmp_path):
    with pytest.raises(ValueError, match="Nope-v0"):
        rdpg.RdpgEnv("Nope-v0")
    env = gym.make("rdpg/BipedalWalker-v3")
    env.reset(seed=0)
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros(3, np.float32))
    with pytest.raises(ValueError, match="finite"):
        env.step(np.array([0, np.nan, 0, 0], np.float32))
    with pytest.raises(TypeError):
        env.step(np.array(["a", "b", "c", "d"]))
    with pytest.raises(ValueError, match="reward"):
        rdpg.RdpgEnv("BipedalWalker-v3", reward="bonus")
    vec = rdpg.make_vec("BipedalWalker-v3", 2)
    vec.reset(seed=0)
    with pytest.raises(ValueError, match="shape"):
        vec.step(np.zeros((3, 4), np.float32))
    with pytest.raises(FileNotFoundError, match="/nonexistent/run"):
        rdpg.Policy.load("/nonexistent/run")
    with pytest.raises(ValueError, match="not a run or zoo directory"):
        rdpg.Policy.load(tmp_path)


@pytest.fixture(scope="module")
def trained_run(tmp_path_factory) -> Path:
    """A tiny recurrent run on the cue task, trained by the rdpg binary."""
    return train(
        "cue-rdpg.toml", tmp_path_factory.mktemp("runs") / "cue", "--steps", "1500",
        "--set", "train.eval_every=500", "--set", "run.keep_agents_every=500",
        "--set", "train.eval_episodes=10", "--set", "train.test_episodes=10",
    )


@pytest.fixture(scope="module")
def prev_action_run(tmp_path_factory) -> Path:
    """A tiny recurrent run on PendulumNoVel-v1 (actions in [-2, 2]) that reads its previous
    action in front of each observation (`train.prev_action_obs`)."""
    return train(
        "memory-rdpg.toml", tmp_path_factory.mktemp("runs") / "prev-action", "--steps", "2200",
        "--set", "train.prev_action_obs=true", "--set", "off_policy.warmup_steps=1000",
        "--set", "train.eval_every=1100", "--set", "train.eval_episodes=2",
        "--set", "train.test_episodes=2", "--set", "agent.parallel_twins=false",
    )


@pytest.fixture(scope="module")
def stacked_run(tmp_path_factory) -> Path:
    """A tiny feed-forward run on PendulumNoVel-v1 that sees its last 3 views, each with its
    previous action in front (`train.frame_stack`, `train.prev_action_obs`)."""
    return train(
        "memory-ddpg.toml", tmp_path_factory.mktemp("runs") / "stacked", "--steps", "1200",
        "--set", "train.frame_stack=3", "--set", "train.prev_action_obs=true",
        "--set", "off_policy.warmup_steps=600", "--set", "train.eval_every=600",
        "--set", "train.eval_episodes=2", "--set", "train.test_episodes=2",
    )


def _policy_dirs(*runs: Path) -> list[Path]:
    zoo = ROOT / "zoo"
    entries = sorted(p for p in zoo.iterdir() if (p / "agent").is_dir()) if zoo.is_dir() else []
    return list(runs) + entries


def test_a_policy_in_a_plain_gymnasium_loop_scores_what_rdpg_eval_reports(
    trained_run, prev_action_run, stacked_run
):
    for run in _policy_dirs(trained_run, prev_action_run, stacked_run):
        policy = rdpg.Policy.load(run)
        episodes, seed = 3, 3_000_000
        want = eval_returns(run, "--episodes", str(episodes), "--seed", str(seed))
        env = gym.make(f"rdpg/{policy.env_id}")
        got = []
        for k in range(episodes):
            obs, _ = env.reset(seed=seed + k)
            policy.reset()
            ret, done = 0.0, False
            while not done:
                a = policy.act(obs)
                for _ in range(policy.action_repeat):  # agents trained with a frame skip
                    obs, r, term, trunc, _ = env.step(a)
                    ret += r
                    done = term or trunc
                    if done:
                        break
            got.append(ret)
        if policy.action_repeat == 1:
            assert got == want, run
        else:  # rdpg sums each action's frames first: the same frames, another order
            assert got == pytest.approx(want, rel=1e-12), run


def test_batched_policy_acts_like_one_policy_per_env(trained_run):
    # Each row of the batched form keeps its own recurrent state: row k equals a lone policy
    # fed env k only.
    batched = rdpg.Policy.load(trained_run)
    lone = [rdpg.Policy.load(trained_run) for _ in range(2)]
    vec = rdpg.make_vec(batched.env_id, 2)
    envs = [gym.make(f"rdpg/{batched.env_id}") for _ in range(2)]
    obs, _ = vec.reset(seed=5)
    single = [env.reset(seed=5 + k)[0] for k, env in enumerate(envs)]
    batched.reset()
    for p in lone:
        p.reset()
    for _ in range(5):
        a = batched.act_batch(obs)
        assert a.shape == (2,) + batched.action_space.shape
        for k in range(2):
            assert np.array_equal(a[k], lone[k].act(single[k]))
            single[k], *_ = envs[k].step(a[k])
        obs, _, term, trunc, _ = vec.step(a)
        if term.any() or trunc.any():
            break


def test_predict_carries_the_previous_action_input_in_its_state(prev_action_run):
    # A run that reads its previous action: predict's state holds that action first, so
    # predict over an episode, state threaded, equals act.
    policy = rdpg.Policy.load(prev_action_run)
    assert policy.state_len == policy.action_space.shape[0] + 2 * policy.config["agent"]["actor_hidden"]
    env = policy.make_env()
    obs, _ = env.reset(seed=9)
    policy.reset()
    state = None
    for _ in range(50):
        a, state = policy.predict(obs, state)
        assert np.array_equal(a, policy.act(obs))
        assert np.array_equal(state[0, : a.size], a)
        obs, *_ = env.step(a)


def test_a_frame_stacked_policy_carries_its_earlier_views(stacked_run):
    # predict's state: the previous action, then the 2 earlier views ([prev action, cos, sin]
    # each), oldest first, zeros before the episode's first; threaded, it equals act, and the
    # batched form keeps one stack per environment.
    policy = rdpg.Policy.load(stacked_run)
    assert policy.state_len == 1 + 2 * 3
    env = policy.make_env()
    obs, _ = env.reset(seed=9)
    policy.reset()
    state, views, last = None, [], 0.0
    for _ in range(20):
        a, state = policy.predict(obs, state)
        assert np.array_equal(a, policy.act(obs))
        assert np.array_equal(policy.act_batch(np.stack([obs, obs]))[1], a)
        views.append(np.array([last, *obs], np.float32))
        last = a[0]
        earlier = ([np.zeros(3, np.float32)] * 2 + views)[-2:]
        np.testing.assert_array_equal(state[0], np.concatenate([a, *earlier]))
        obs, *_ = env.step(a)


def test_a_damaged_policy_directory_is_refused(trained_run, tmp_path):
    bad = tmp_path / "bad"
    shutil.copytree(trained_run, bad)
    w = bad / "checkpoints" / "best" / "agent" / "weights.safetensors"
    data = bytearray(w.read_bytes())
    data[len(data) // 2] ^= 0x01
    w.write_bytes(bytes(data))
    with pytest.raises(ValueError, match="damaged"):
        rdpg.Policy.load(bad)
    os.remove(bad / "config.toml")
    with pytest.raises(ValueError, match="not a run or zoo directory"):
        rdpg.Policy.load(bad)


def test_a_policy_loads_any_agent_of_a_run(trained_run):
    # Each agent of the run acts as `rdpg eval --checkpoint` scores it, and they differ.
    first_actions = {}
    for checkpoint in ("latest", "500"):
        want = eval_returns(trained_run, "--checkpoint", checkpoint, "--episodes", "4")
        policy = rdpg.Policy.load(trained_run, checkpoint=checkpoint)
        env = gym.make(f"rdpg/{policy.env_id}")
        got = []
        for k in range(4):
            obs, _ = env.reset(seed=3_000_000 + k)
            policy.reset()
            ret, done = 0.0, False
            if k == 0:
                first_actions[checkpoint] = policy.act(obs)
                policy.reset()
            while not done:
                obs, r, term, trunc, _ = env.step(policy.act(obs))
                ret += r
                done = term or trunc
            got.append(ret)
        assert got == want, checkpoint
    assert not np.array_equal(first_actions["latest"], first_actions["500"])
    assert np.array_equal(
        rdpg.Policy.load(trained_run, checkpoint="0500").act(obs),
        rdpg.Policy.load(trained_run, checkpoint=500).act(obs),
    )
    with pytest.raises(ValueError, match="not an agent of a run"):
        rdpg.Policy.load(trained_run, checkpoint="worst")
    with pytest.raises(ValueError, match="holds no agent"):
        rdpg.Policy.load(trained_run, checkpoint=123)
    zoo = ROOT / "zoo" / "walker-td3"
    if zoo.is_dir():
        with pytest.raises(ValueError, match="zoo entry"):
            rdpg.Policy.load(zoo, checkpoint="latest")


def test_every_copy_of_a_batched_policy_is_the_agent_it_loaded(trained_run, tmp_path):
    # A Policy acts from its own copy of the agent: copies made later for more environments
    # are the same agent even when the run's checkpoint changes (here: is gone) meanwhile, and
    # the copy is removed with the Policy.
    import gc
    import tempfile

    def snapshots():
        return set(Path(tempfile.gettempdir()).glob(f"rdpg-policy-{os.getpid()}-*"))

    before = snapshots()
    run = tmp_path / "run"
    shutil.copytree(trained_run, run)
    batched = rdpg.Policy.load(run)
    lone = rdpg.Policy.load(run)
    assert len(snapshots() - before) == 2
    shutil.rmtree(run)
    obs = np.zeros((3,) + batched.observation_space.shape, np.float32)
    a = batched.act_batch(obs)
    lone.reset()
    assert np.array_equal(a[2], lone.act(obs[2]))
    # An environment the batched form has not acted for starts fresh: no copy is made.
    batched.reset_one(10**6)
    with pytest.raises(ValueError):
        batched._p.act_batch(b"", 2**62)
    del batched, lone
    gc.collect()
    assert snapshots() == before


def test_a_policy_whose_config_does_not_fit_its_agent_is_refused(trained_run, tmp_path):
    run = tmp_path / "run"
    shutil.copytree(trained_run, run)
    config = run / "config.toml"
    text = config.read_text()
    assert 'env = "CueMemory-v0"' in text
    config.write_text(text.replace('env = "CueMemory-v0"', 'env = "Pendulum-v1"'))
    with pytest.raises(ValueError, match="does not fit Pendulum-v1"):
        rdpg.Policy.load(run)


def test_a_crafted_agent_is_a_value_error_before_anything_is_allocated(tmp_path):
    """A zoo agent whose config asks for networks its weights could never fill (resealed so
    that the checksums pass) raises ValueError naming agent.json, not a panic or an
    allocation of gigabytes."""
    import zlib

    entry = tmp_path / "crafted"
    shutil.copytree(ROOT / "zoo" / "walker-td3", entry)
    meta_path = entry / "agent" / "agent.json"
    meta = json.loads(meta_path.read_text())
    meta["config"]["actor_hidden"] = 2_000_000_000
    meta_path.write_text(json.dumps(meta))
    files = {}
    for name in ("agent.json", "weights.safetensors"):
        data = (entry / "agent" / name).read_bytes()
        files[name] = {"len": len(data), "crc32": zlib.crc32(data)}
    (entry / "agent" / "manifest.json").write_text(json.dumps({"files": files}))
    with pytest.raises(ValueError, match="does not belong to these weights"):
        rdpg.Policy.load(entry)


def test_bad_arguments_name_themselves():
    """Misspelt keywords are a TypeError for the vector env as for the single one; negative
    counts, indices and seeds a ValueError naming the argument, not a bare OverflowError."""
    with pytest.raises(TypeError, match="action_repaet"):
        rdpg.make_vec("BipedalWalker-v3", 2, action_repaet=3)
    with pytest.raises(TypeError, match="rewad"):
        gym.make_vec("rdpg/BipedalWalker-v3", num_envs=2, rewad="paper")
    with pytest.raises(ValueError, match="num_envs = -1"):
        rdpg.make_vec("BipedalWalker-v3", -1)
    with pytest.raises(ValueError, match=r"hide_obs\[0\] = -1"):
        rdpg.make_vec("BipedalWalker-v3", 2, hide_obs=[-1])
    with pytest.raises(ValueError, match=r"hide_obs\[1\] = -3"):
        gym.make("rdpg/BipedalWalker-v3", hide_obs=[2, -3])
    with pytest.raises(ValueError, match="seed = -1"):
        gym.make("rdpg/BipedalWalker-v3").reset(seed=-1)
    with pytest.raises(ValueError, match="action_repeat = 0"):
        gym.make("rdpg/BipedalWalker-v3", action_repeat=0)
    v = gym.make_vec("rdpg/BipedalWalker-v3", num_envs=2)
    assert v.reset(seed=5)[0].shape == (2, 24)
