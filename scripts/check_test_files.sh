#!/usr/bin/env bash
# Compiles every test file on its own: no unity batch, no precompiled header. The test
# programs compile their files four to a translation unit (test/CMakeLists.txt), where
# a file that forgets an include still compiles when the file before it has it; a new
# order of the files, or the ASan build (no precompiled header), then fails (session
# 66: std::mt19937 without <random>). Objects only: nothing is linked or run, and the
# libraries are not built. Not part of CI (about 10 CPU-minutes); run it before landing
# a change that adds includes to, or moves, a test file.
#
#   scripts/check_test_files.sh [BUILD]   (default: build-standalone)
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
build="${1:-$root/build-standalone}"
command -v ninja > /dev/null ||
  { echo "$0: needs ninja (scripts/setup_debian.sh installs it)" >&2; exit 1; }
cmake -S "$root" -B "$build" -G Ninja -DCMAKE_BUILD_TYPE=Release \
  -DPCL_RAST_BUILD_TESTS=ON -DPCL_RAST_TESTS_BUILD_TOOLS=OFF \
  -DPCL_RAST_TEST_UNITY=OFF -DPCL_RAST_TEST_PCH=OFF -DPCL_RAST_TEST_OPTIMIZATION=-O0 \
  > "$build.configure.log" 2>&1
# The object files of the three test programs, one per test file.
mapfile -t objects < <(ninja -C "$build" -t targets all |
  sed -n 's|^\(test/CMakeFiles/test_[a-z]*\.dir/.*\.cpp\.o\):.*|\1|p')
[ ${#objects[@]} -gt 0 ] || { echo "$0: no test object files in $build" >&2; exit 1; }
if cmake --build "$build" -j"$(nproc)" --target "${objects[@]}" > "$build.build.log" 2>&1; then
  echo "check_test_files.sh: ${#objects[@]} test files compile on their own"
else
  grep -E "error|FAILED" "$build.build.log" | head -40
  echo "check_test_files.sh: a test file does not compile on its own ($build.build.log)" >&2
  exit 1
fi
