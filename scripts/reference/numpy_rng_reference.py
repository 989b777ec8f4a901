#!/usr/bin/env python3
"""Reference values for `rdpg_core::rng::NpRng`, the numpy-compatible generator.

numpy's `np.random.Generator(np.random.PCG64(np.random.SeedSequence(seed)))` (what
`gymnasium.utils.seeding.np_random(seed)` builds) is the ground truth; this script only calls
numpy's public Python API.

Regenerate the test fixture (from the repository root; needs numpy >= 2):

    /work/venvs/ref/bin/python scripts/reference/numpy_rng_reference.py > tests/fixtures/numpy_rng.json

Regenerate the ziggurat tables embedded in `crates/rdpg-core/src/rng.rs` (rewrites the block
between the `BEGIN GENERATED ZIGGURAT TABLES` / `END GENERATED ZIGGURAT TABLES` markers):

    /work/venvs/ref/bin/python scripts/reference/numpy_rng_reference.py --rust-tables crates/rdpg-core/src/rng.rs

The tables are recovered from numpy's *behaviour*: the PCG64 state is set (through
`bit_generator.state`) so that the next raw 64-bit outputs are chosen words, then
`standard_normal()` is called and the result / the number of words consumed is observed.

* `wi[i]`: a word with layer `i`, positive sign and `rabs = 1` returns exactly `wi[i]`.
* `ki[i]`: the smallest `rabs` that is *not* accepted on the first word (binary search on
  how many words were consumed).
* `fi[i]`: for rejection-path words, a binary search on the uniform that follows finds the
  acceptance boundary; the unique double consistent with all boundaries, searched around
  `exp(-x_i^2 / 2)` (`x_i = wi[i] * 2^52`, `fi[0] = 1`), is kept.
"""

import json
import math
import random as pyrandom
import re
import sys

import numpy as np

M64 = (1 << 64) - 1
M128 = (1 << 128) - 1
# The PCG64 multiplier numpy uses (128-bit LCG, XSL-RR output).
PCG_MULT = 0x2360ED051FC65DA44385DF649FCCF645
PCG_MULT_INV = pow(PCG_MULT, -1, 1 << 128)

SEEDS = [0, 1, 42, 12345, 2**32 + 7, 2**63 + 3]
UNIFORM_ARGS = [
    (0.0, 1.0),
    (-1.0, 1.0),
    (-0.05, 0.05),
    (0.0, 14.0 / 30.0),
    (-8.0, 8.0),
    (2.5, 2.5),
    (-1e6, 3e6),
    (1e-300, 2e-300),
]
INTEGER_ARGS = [
    (3, 5),
    (1, 3),
    (4, 5),
    (5, 10),
    (1, 5),
    (0, 1000000),
    (0, 2**40),
    (0, 2**32),
    (0, 2**32 + 1),
    (-5, 5),
    (-(2**62), 2**62),
    (0, 2**63 - 1),
    (-(2**63), 2**63 - 1),
    (7, 8),
    (0, 3),
    (0, 2**31 + 12345),
]


def state_dict(bg):
    s = bg.state
    return {
        "state": str(s["state"]["state"]),
        "inc": str(s["state"]["inc"]),
        "has_uint32": int(s["has_uint32"]),
        "uinteger": int(s["uinteger"]),
    }


def gen(seed):
    return np.random.Generator(np.random.PCG64(np.random.SeedSequence(seed)))


def as_float(x):
    return float(x)


def interleaved_ops(seed):
    """A fixed pattern of calls, like the walker terrain: uint32 buffer and doubles mixed."""
    pick = pyrandom.Random(seed ^ 0x5EED)
    ops = []
    for _ in range(160):
        k = pick.randrange(12)
        if k == 0:
            ops.append(["uniform", -1.0, 1.0])
        elif k == 1:
            ops.append(["uniform", 0.0, 14.0 / 30.0])
        elif k == 2:
            ops.append(["integers", 3, 5])
        elif k == 3:
            ops.append(["integers", 1, 3])
        elif k == 4:
            ops.append(["integers", 4, 5])
        elif k == 5:
            ops.append(["integers", 5, 10])
        elif k == 6:
            ops.append(["integers", 1, 5])
        elif k == 7:
            ops.append(["random"])
        elif k == 8:
            ops.append(["standard_normal"])
        elif k == 9:
            ops.append(["integers", 0, 2**40])
        elif k == 10:
            ops.append(["integers", 0, 1000000])
        else:
            ops.append(["normal", 0.5, 0.2])
    return ops


def run_op(g, op):
    name = op[0]
    if name == "uniform":
        return as_float(g.uniform(op[1], op[2]))
    if name == "integers":
        return int(g.integers(op[1], op[2]))
    if name == "random":
        return as_float(g.random())
    if name == "standard_normal":
        return as_float(g.standard_normal())
    if name == "normal":
        return as_float(g.normal(op[1], op[2]))
    raise ValueError(name)


def seed_case(seed):
    case = {"seed": str(seed)}
    g = gen(seed)
    case["init_state"] = state_dict(g.bit_generator)
    case["raw"] = [str(int(v)) for v in g.bit_generator.random_raw(24)]

    g = gen(seed)
    case["random"] = [as_float(g.random()) for _ in range(24)]

    g = gen(seed)
    case["uniform"] = []
    for rep in range(3):
        for a, b in UNIFORM_ARGS:
            case["uniform"].append([a, b, as_float(g.uniform(a, b))])

    g = gen(seed)
    case["integers"] = []
    for rep in range(4):
        for lo, hi in INTEGER_ARGS:
            case["integers"].append([lo, hi, int(g.integers(lo, hi))])
    case["integers_end_state"] = state_dict(g.bit_generator)

    g = gen(seed)
    case["choice"] = [[n, int(g.choice(n))] for n in (1, 2, 3, 10, 1000, 2**35) * 3]

    g = gen(seed)
    ops = interleaved_ops(seed)
    case["interleaved"] = [op + [run_op(g, op)] for op in ops]
    case["interleaved_end_state"] = state_dict(g.bit_generator)

    g = gen(seed)
    case["standard_normal"] = [as_float(g.standard_normal()) for _ in range(300)]
    case["standard_normal_end_state"] = state_dict(g.bit_generator)

    g = gen(seed)
    case["normal"] = [
        [loc, scale, as_float(g.normal(loc, scale))]
        for loc, scale in [(0.0, 1.0), (1.5, 0.1), (-3.0, 2.0), (0.0, 0.0)] * 5
    ]
    return case


# --- crafting states whose next raw outputs are chosen words --------------------------------


def pcg_output(s):
    rot = s >> 122
    v = ((s >> 64) ^ s) & M64
    return ((v >> rot) | (v << ((64 - rot) & 63))) & M64


def craft(r1, r2):
    """(state, inc) such that the next two raw outputs are r1 then r2 (inc odd)."""
    s1 = r1  # high half 0: rotation 0, output = low half
    h = 0x1234
    rot = h >> 58
    lo = (((r2 << rot) | (r2 >> ((64 - rot) & 63))) & M64) ^ h
    if (lo - r1) % 2 == 0:
        h ^= 1
        lo ^= 1
    s2 = (h << 64) | lo
    assert pcg_output(s2) == r2
    inc = (s2 - s1 * PCG_MULT) & M128
    assert inc & 1
    s0 = ((s1 - inc) * PCG_MULT_INV) & M128
    return s0, inc, s1, s2


class Crafter:
    def __init__(self):
        self.bg = np.random.PCG64(0)
        self.g = np.random.Generator(self.bg)

    def set(self, r1, r2=0):
        s0, inc, s1, s2 = craft(r1, r2)
        self.bg.state = {
            "bit_generator": "PCG64",
            "state": {"state": s0, "inc": inc},
            "has_uint32": 0,
            "uinteger": 0,
        }
        return s0, inc, s1, s2

    def cur(self):
        return self.bg.state["state"]["state"]


def word(idx, sign, rabs):
    """numpy's standard_normal splits a raw word: 8 bits layer, 1 bit sign, 52 bits rabs."""
    return idx | (sign << 8) | (rabs << 9)


U53 = 1.0 / 9007199254740992.0


def extract_tables():
    c = Crafter()
    wi, ki = [], []
    for idx in range(256):
        c.set(word(idx, 0, 1))
        wi.append(float(c.g.standard_normal()))
        lo, hi = 0, 1 << 52
        while lo < hi:
            m = (lo + hi) // 2
            _, _, s1, _ = c.set(word(idx, 0, m))
            c.g.standard_normal()
            if c.cur() == s1:
                lo = m + 1
            else:
                hi = m
        ki.append(lo)

    def numpy_kstar(idx, rabs):
        lo, hi = 0, 1 << 53
        while lo < hi:
            m = (lo + hi) // 2
            _, _, _, s2 = c.set(word(idx, 0, rabs), m << 11)
            c.g.standard_normal()
            if c.cur() == s2:  # accepted with the second word
                lo = m + 1
            else:
                hi = m
        return lo

    def model_kstar(idx, rabs, f, fprev):
        x = rabs * wi[idx]
        e = math.exp(-0.5 * x * x)
        d = fprev - f
        lo, hi = 0, 1 << 53
        while lo < hi:
            m = (lo + hi) // 2
            if d * (m * U53) + f < e:
                lo = m + 1
            else:
                hi = m
        return lo

    fi = [1.0]
    for idx in range(1, 256):
        span = (1 << 52) - ki[idx]
        probes = [ki[idx] + int(span * q) for q in (0.01, 0.05, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.95, 0.999)]
        seen = [numpy_kstar(idx, r) for r in probes]
        x = wi[idx] * 2.0**52
        guess = math.exp(-0.5 * x * x)
        cands = []
        below = guess
        for _ in range(300):
            below = math.nextafter(below, -1.0)
        f = below
        for _ in range(601):
            if all(model_kstar(idx, r, f, fi[-1]) == s for r, s in zip(probes, seen)):
                cands.append(f)
            f = math.nextafter(f, 2.0)
        if len(cands) != 1:
            raise SystemExit(f"fi[{idx}]: {len(cands)} candidates")
        fi.append(cands[0])
    return ki, wi, fi


def rust_tables():
    ki, wi, fi = extract_tables()
    r = wi[255] * 2.0**52
    lines = [
        "// BEGIN GENERATED ZIGGURAT TABLES (scripts/reference/numpy_rng_reference.py --rust-tables)",
        f"/// Right edge of the base layer of the 256-layer normal ziggurat.",
        f"const ZIG_R: f64 = {r!r};",
        f"/// `1 / ZIG_R`.",
        f"const ZIG_INV_R: f64 = {1.0 / r!r};",
        "/// Acceptance thresholds on the 52-bit magnitude, per layer.",
        "#[rustfmt::skip]",
        "static ZIG_KI: [u64; 256] = [",
    ]
    for i in range(0, 256, 4):
        lines.append("    " + " ".join(f"0x{v:013x}," for v in ki[i : i + 4]))
    lines.append("];")
    lines.append("/// Layer widths divided by 2^52.")
    lines.append("#[rustfmt::skip]")
    lines.append("static ZIG_WI: [f64; 256] = [")
    for i in range(0, 256, 3):
        lines.append("    " + " ".join(f"{v!r}," for v in wi[i : i + 3]))
    lines.append("];")
    lines.append("/// Density at the layer edges (`fi[0] = 1`).")
    lines.append("#[rustfmt::skip]")
    lines.append("static ZIG_FI: [f64; 256] = [")
    for i in range(0, 256, 3):
        lines.append("    " + " ".join(f"{v!r}," for v in fi[i : i + 3]))
    lines.append("];")
    lines.append("// END GENERATED ZIGGURAT TABLES")
    return "\n".join(lines) + "\n"


def crafted_normal_cases():
    """States that steer standard_normal into its rare branches (rejection test, tail)."""
    ki, wi, _ = extract_tables_cache()
    c = Crafter()
    cases = []

    def record(r1, r2, n=4):
        s0, inc, _, _ = c.set(r1, r2)
        vals = [float(c.g.standard_normal()) for _ in range(n)]
        cases.append({"state": str(s0), "inc": str(inc), "values": vals})

    pick = pyrandom.Random(2024)
    for idx in [0, 0, 0, 0, 1, 2, 3, 37, 38, 39, 100, 128, 200, 254, 255]:
        for sign in (0, 1):
            span = (1 << 52) - ki[idx]
            rabs = ki[idx] + pick.randrange(span)
            # Uniform near the acceptance boundary for this word, and a random one.
            lo, hi = 0, 1 << 53
            while lo < hi:
                m = (lo + hi) // 2
                _, _, _, s2 = c.set(word(idx, sign, rabs), m << 11)
                c.g.standard_normal()
                if c.cur() == s2:
                    lo = m + 1
                else:
                    hi = m
            for k in (max(lo - 1, 0), min(lo, (1 << 53) - 1), pick.randrange(1 << 53)):
                record(word(idx, sign, rabs), k << 11)
    return cases


_TABLES = None


def extract_tables_cache():
    global _TABLES
    if _TABLES is None:
        _TABLES = extract_tables()
    return _TABLES


def main():
    if len(sys.argv) == 3 and sys.argv[1] == "--rust-tables":
        path = sys.argv[2]
        src = open(path).read()
        pat = re.compile(r"// BEGIN GENERATED ZIGGURAT TABLES.*?// END GENERATED ZIGGURAT TABLES\n", re.S)
        if not pat.search(src):
            raise SystemExit(f"no generated-table markers in {path}")
        src = pat.sub(lambda _: rust_tables(), src)
        open(path, "w").write(src)
        return
    if len(sys.argv) != 1:
        raise SystemExit(__doc__)
    out = {
        "numpy_version": np.__version__,
        "seeds": [seed_case(s) for s in SEEDS],
        "crafted_normal": crafted_normal_cases(),
    }
    json.dump(out, sys.stdout, separators=(",", ":"))
    sys.stdout.write("\n")


if __name__ == "__main__":
    main()
