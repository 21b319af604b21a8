#!/usr/bin/env bash
# Fuzz every reader with libFuzzer under ASan + UBSan (issue 12).
#
#   scripts/fuzz.sh [SECONDS_PER_TARGET=60] [TARGET...]
#
# Builds the harnesses of fuzz/ with clang into build-fuzz/, writes a seed corpus from
# ../shared/data (fuzz_seeds), runs each target for SECONDS_PER_TARGET with a 1 GB RSS
# limit and leak detection, and prints executions per second, corpus size and peak RSS.
# Every crash, leak or timeout is copied to test/data/hostile/ (scan files) or
# test/data/hostile/text/ (text files), where the regression tests read it, and makes
# the script exit 1. Targets: pcd ply bin poses times calib g2o (default: all).
# PCL_RAST_FUZZ_SKIP_BUILD=1 reuses the harnesses and seeds built before (to run two
# instances side by side on different targets).
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
seconds="${1:-60}"
shift || true
targets=("$@")
[ ${#targets[@]} -eq 0 ] && targets=(pcd ply bin poses times calib g2o)
build="${PCL_RAST_FUZZ_BUILD_DIR:-$root/build-fuzz}"
work="$build/fuzz-work"
data="$root/../shared/data"
[ -d "$data" ] || { echo "fuzz.sh: $data not found: the seed corpus comes from it" >&2; exit 2; }

if [ -z "${PCL_RAST_FUZZ_SKIP_BUILD:-}" ]; then
mkdir -p "$build"
CC=clang CXX=clang++ cmake -S "$root" -B "$build" -DCMAKE_BUILD_TYPE=RelWithDebInfo \
  -DPCL_RAST_BUILD_FUZZERS=ON -DPCL_RAST_BUILD_TESTS=OFF -DPCL_RAST_BUILD_TOOLS=OFF \
  -DPCL_RAST_UNITY_BUILD=ON \
  -DCMAKE_C_FLAGS="-fsanitize=address,undefined" \
  -DCMAKE_CXX_FLAGS="-fsanitize=address,undefined,fuzzer-no-link -fno-sanitize-recover=all" \
  -DCMAKE_EXE_LINKER_FLAGS="-fsanitize=address,undefined" \
  -DCMAKE_SHARED_LINKER_FLAGS="-fsanitize=address,undefined" > "$build/configure.log" 2>&1
cmake --build "$build" -j"$(nproc)" --target fuzz_seeds $(printf 'fuzz_%s ' "${targets[@]}") >/dev/null
fi

mkdir -p "$work"
if [ ! -d "$work/seeds" ] || [ -z "${PCL_RAST_FUZZ_SKIP_BUILD:-}" ]; then
  rm -rf "$work/seeds"
  ASAN_OPTIONS=detect_leaks=0 "$build/fuzz/fuzz_seeds" "$data" "$work/seeds" >/dev/null
fi

status=0
printf '%-6s %10s %8s %8s %8s\n' target execs/s corpus rss_mb findings
for t in "${targets[@]}"; do
  corpus="$work/corpus-$t"
  artifacts="$work/artifacts-$t"
  mkdir -p "$corpus" "$artifacts"
  log="$work/$t.log"
  ASAN_OPTIONS=detect_leaks=1:halt_on_error=1 UBSAN_OPTIONS=halt_on_error=1:print_stacktrace=1 \
    "$build/fuzz/fuzz_$t" "$corpus" "$work/seeds/$t" -max_total_time="$seconds" \
    -rss_limit_mb=1024 -max_len=65536 -timeout=10 -print_final_stats=1 \
    -artifact_prefix="$artifacts/" > "$log" 2>&1 || true
  execs=$(grep -o 'stat::average_exec_per_sec: *[0-9]*' "$log" | grep -o '[0-9]*$' || echo 0)
  rss=$(grep -o 'stat::peak_rss_mb: *[0-9]*' "$log" | grep -o '[0-9]*$' || echo 0)
  files=$(find "$corpus" -type f | wc -l)
  findings=$(find "$artifacts" -type f | wc -l)
  printf '%-6s %10s %8s %8s %8s\n' "$t" "$execs" "$files" "$rss" "$findings"
  if [ "$findings" -gt 0 ]; then
    status=1
    case "$t" in pcd|ply|bin) dest="$root/test/data/hostile"; ext=".$t" ;;
                 *) dest="$root/test/data/hostile/text"; ext=".$t.txt" ;; esac
    mkdir -p "$dest"
    for f in "$artifacts"/*; do cp "$f" "$dest/fuzz-$t-$(basename "$f" | tr -c 'a-zA-Z0-9\n-' '_')$ext"; done
    echo "fuzz.sh: $t: $findings finding(s), see $log; copied to $dest" >&2
  fi
done
exit $status
