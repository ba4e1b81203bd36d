#!/usr/bin/env bash
# Installs what is missing, builds, and runs the whole test suite twice: a Release build, then an
# AddressSanitizer + UndefinedBehaviorSanitizer build. Set CIP_SANITIZE=0 to skip the sanitizer pass.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh
jobs=$(nproc)
echo "== Release build and tests"
bash scripts/build.sh build
ctest --test-dir build --output-on-failure -j "$jobs"
if [ "${CIP_SANITIZE:-1}" != "0" ]; then
  echo "== ASan+UBSan build and tests"
  # -O1 -g1 (line tables for the reports): the sanitizers' own advice, and it halves this build; at -O2 -g it
  # took three times as long as the Release build.
  bash scripts/build.sh build-asan -DCMAKE_BUILD_TYPE=RelWithDebInfo -DCMAKE_CXX_FLAGS_RELWITHDEBINFO="-O1 -g1 -DNDEBUG" \
    -DCIP_SANITIZE=ON
  ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
    ctest --test-dir build-asan --output-on-failure -j "$jobs"
fi
