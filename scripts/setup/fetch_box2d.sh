#!/usr/bin/env bash
# Fetches pybox2d's own Box2D 2.3.0 C++ sources (the PyPI sdist box2d-py==2.3.8, zlib licence)
# into .deps/box2d-py-2.3.8. These are the sources Gymnasium's physics runs on; the crate
# rdpg-box2d compiles them (see crates/rdpg-box2d/build.rs). Nothing of them is committed.
set -euo pipefail
root="$(cd "$(dirname "$0")/../.." && pwd)"
dest="$root/.deps"
dir="$dest/box2d-py-2.3.8"
if [ -f "$dir/Box2D/Box2D.h" ]; then
  echo "box2d-py 2.3.8 sources already in $dir"
  exit 0
fi
mkdir -p "$dest"
tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT
python3 -m pip download --quiet box2d-py==2.3.8 --no-binary :all: --no-deps -d "$tmp"
tar -xzf "$tmp"/box2d-py-2.3.8.tar.gz -C "$dest"
echo "box2d-py 2.3.8 sources in $dir"
