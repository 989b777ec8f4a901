#!/usr/bin/env python3
"""What ``import rdpg`` costs: time and resident memory of three statements, each in 5 fresh
processes (median): the envs alone, torch + rdpg (the cost when the package loaded libtorch),
and the first ``Policy.load`` (torch loaded on first use). Usage::

    .venv/bin/python scripts/bench/bench_python_import.py
"""

from __future__ import annotations

import statistics
import subprocess
import sys
from pathlib import Path

ZOO = Path(__file__).resolve().parents[2] / "zoo" / "walker-td3"
CASES = {
    "import rdpg": "import rdpg",
    "import torch, rdpg": "import torch, rdpg",
    "import rdpg; Policy.load": f"import rdpg; rdpg.Policy.load({str(ZOO)!r})",
}

for name, code in CASES.items():
    times, rss = [], []
    for _ in range(5):
        src = (
            f"import time; t = time.perf_counter(); {code}; t = time.perf_counter() - t\n"
            "kb = next(l for l in open('/proc/self/status') if l.startswith('VmRSS')).split()[1]\n"
            "print(t, kb)"
        )
        out = subprocess.run([sys.executable, "-c", src], capture_output=True, text=True, check=True)
        t, kb = out.stdout.split()
        times.append(float(t))
        rss.append(int(kb) / 1024)
    print(f"{name}: {statistics.median(times):.3f} s, {statistics.median(rss):.0f} MiB")
