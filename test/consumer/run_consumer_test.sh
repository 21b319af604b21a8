#!/usr/bin/env bash
# Installs the built project into a temporary prefix, then configures, builds and
# runs a tiny consumer project that uses find_package(pcl_rast).
# Usage: run_consumer_test.sh BUILD_DIR WORK_DIR
set -euo pipefail
build_dir="$1"
work="$2"
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
rm -rf "$work"
mkdir -p "$work"
cmake --install "$build_dir" --prefix "$work/prefix" >/dev/null
cmake -S "$here/project" -B "$work/build" -DCMAKE_PREFIX_PATH="$work/prefix" \
      -DCMAKE_BUILD_TYPE=Release >/dev/null
# The public headers need no OpenCV: its include path must not reach the consumer.
if grep -rqi "opencv" "$work/build/CMakeFiles/consumer.dir/flags.make"; then
  echo "consumer: OpenCV's include path leaks into the consumer's flags:" >&2
  grep -i "opencv" "$work/build/CMakeFiles/consumer.dir/flags.make" >&2
  exit 1
fi
cmake --build "$work/build" -j2 >/dev/null
cd "$work" && "$work/build/consumer"
