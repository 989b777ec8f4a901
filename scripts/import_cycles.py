#!/usr/bin/env python3
"""No import circle between source files (ARCHITECTURE.md): for every crate, each file's
`use super::…` / `use crate::…` / `super::x::` / `crate::x::` paths outside its test module
(from `#[cfg(test)]` on) name the files it imports; a cycle among them is printed and fails."""

import re
import sys
from pathlib import Path

root = Path(__file__).resolve().parent.parent
PATH = re.compile(r"\b(crate|super)((?:::[a-z_][a-z0-9_]*)+)")


def module_of(src: Path, f: Path) -> tuple:
    parts = list(f.relative_to(src).with_suffix("").parts)
    if parts[-1] in ("mod", "lib", "main"):
        parts = parts[:-1]
    return tuple(parts)


def edges(src: Path) -> dict:
    files = {module_of(src, f): f for f in src.rglob("*.rs") if "tests" not in f.parts}
    graph = {}
    for mod, f in files.items():
        text = re.sub(r"//[^\n]*", "", f.read_text().split("#[cfg(test)]")[0])
        # `use super::{a, b::C}` groups: each member's first name.
        for m in re.finditer(r"\b(crate|super)::\{([^}]*)\}", text):
            for item in m.group(2).split(","):
                if item.strip():
                    text += f" {m.group(1)}::{item.strip().split('::')[0]}"
        out = set()
        for m in PATH.finditer(text):
            # `super` is the parent module (of `a/b.rs` and of `a/b/mod.rs` alike).
            target = () if m.group(1) == "crate" else mod[:-1]
            for name in m.group(2).split("::")[1:]:
                if target + (name,) not in files:
                    break
                target += (name,)
            if target not in (mod, ()):
                out.add(target)
        graph[mod] = out
    return graph


def cycles(graph: dict) -> list:
    found, state, stack = [], {}, []

    def visit(v):
        state[v] = 1
        stack.append(v)
        for w in sorted(graph.get(v, ())):
            if state.get(w) == 1:
                found.append(stack[stack.index(w):] + [w])
            elif w not in state:
                visit(w)
        stack.pop()
        state[v] = 2

    for v in sorted(graph):
        if v not in state:
            visit(v)
    return found


bad = 0
for src in sorted(root.glob("crates/*/src")):
    for c in cycles(edges(src)):
        bad += 1
        print(f"{src.parent.name}: import cycle " + " -> ".join("/".join(m) for m in c))
sys.exit(1 if bad else 0)
