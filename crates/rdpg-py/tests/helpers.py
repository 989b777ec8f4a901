"""What the package's tests share: the repository root and the rdpg binary the Rust tests
built (trained runs and `rdpg eval` scores to compare the Python side with)."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[3]
ZOO = ROOT / "zoo"


def rdpg_binary() -> Path:
    found = [ROOT / "target" / p / "rdpg" for p in ("release", "debug")]
    found = [p for p in found if p.exists()]
    if not found:
        pytest.fail("no rdpg binary: build it first (cargo build)")
    return max(found, key=lambda p: p.stat().st_mtime)


def train(config: str, out: Path, *args: str) -> Path:
    """A run of ``configs/<config>`` into ``out`` with the extra ``rdpg train`` arguments."""
    subprocess.run(
        [str(rdpg_binary()), "train", "--quiet", "--config", str(ROOT / "configs" / config),
         "--out", str(out), *args],
        check=True, capture_output=True,
    )
    return out


def eval_returns(run: Path, *args: str) -> list[float]:
    """The per-episode returns ``rdpg eval --run <run> <args>`` reports."""
    out = subprocess.run(
        [str(rdpg_binary()), "eval", "--run", str(run), *args],
        check=True, capture_output=True, text=True,
    )
    return json.loads(out.stdout)["returns"]


def train_window_run(out: Path) -> Path:
    """A tiny window-of-k (k = 4) recurrent run on the cue task (a few seconds)."""
    return train(
        "cue-rdpg.toml", out, "--steps", "1200", "--set", "train.eval_every=600",
        "--set", "train.eval_episodes=5", "--set", "train.test_episodes=5",
        "--set", "agent.act_window=4", "--set", "agent.scan_len=3", "--set", "agent.update_len=1",
        "--set", "agent.burn_in_from_stored_state=false",
    )
