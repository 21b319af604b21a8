#!/usr/bin/env bash
# Configures and builds pcl_rast (Release) into ./build. Extra arguments go to cmake.
# Ninja where it is installed (scripts/setup_debian.sh installs it) and the build folder
# is new: it keeps both cores busy to the end of the build, where make waits target by
# target. A build folder keeps the generator it was made with.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
build="${PCL_RAST_BUILD_DIR:-$root/build}"
generator=()
if [ ! -f "$build/CMakeCache.txt" ] && command -v ninja > /dev/null; then
  generator=(-G Ninja)
fi
cmake -S "$root" -B "$build" "${generator[@]}" -DCMAKE_BUILD_TYPE=Release "$@" >/dev/null
cmake --build "$build" -j"$(nproc)"
