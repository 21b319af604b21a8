#!/usr/bin/env bash
# Installs what is missing, builds, and runs the whole test suite.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
build="${PCL_RAST_BUILD_DIR:-$root/build}"
"$root/scripts/setup_debian.sh"
"$root/scripts/build.sh" -DPCL_RAST_BUILD_TESTS=ON
# The longest tests first, also in a fresh build folder (scripts/seed_test_costs.sh).
"$root/scripts/seed_test_costs.sh" "$build" release
cd "$build"
ctest --output-on-failure -j"$(nproc)"
