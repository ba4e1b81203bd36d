#!/usr/bin/env bash
# Configures and builds cip. Usage: bash scripts/build.sh [build-dir] [extra cmake args...]
# Default build dir: build (Release). Re-running only rebuilds what changed.
set -euo pipefail
cd "$(dirname "$0")/.."
dir=${1:-build}
shift || true
generator=()
command -v ninja >/dev/null && [ ! -f "$dir/Makefile" ] && generator=(-G Ninja)
cmake -S . -B "$dir" "${generator[@]}" -DCMAKE_BUILD_TYPE=Release "$@" >/dev/null
cmake --build "$dir" -j "$(nproc)"
