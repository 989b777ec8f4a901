#!/usr/bin/env bash
# Counts the code lines (not blank, not comments, before a file's `#[cfg(test)]` module) of
# every Rust source file under crates/*/src; test-only files (`tests.rs`, `tests/`, or with
# `#![cfg(test)]`) are skipped. Fails naming each file over the limit (600), the size past
# which a file is split into rooms (ARCHITECTURE.md).
set -euo pipefail
cd "$(dirname "$0")/.."
limit=600
over=0
while IFS= read -r f; do
    case "$f" in */tests.rs | */tests/*) continue ;; esac
    if grep -q '^#!\[cfg(test)\]' "$f"; then continue; fi
    n=$(awk '/^#\[cfg\(test\)\]/ { exit } { print }' "$f" | grep -cv '^\s*$\|^\s*//' || true)
    if [ "$n" -gt "$limit" ]; then
        echo "$f: $n code lines (limit $limit): split it into rooms" >&2
        over=1
    fi
done < <(find crates/*/src -name "*.rs" | sort)
exit "$over"
