#!/usr/bin/env bash
# With -j, ctest starts the longest tests first, by the times its last runs recorded in
# BUILD/Testing/Temporary/CTestCostData.txt. A fresh build folder (every CI run) has no
# such file, and ctest then starts the tests in the order they are declared: a long
# test declared late ran alone on one core at the end (TSan's 49 s placement test did,
# session 66). This gives such a folder the times a run of the same suite recorded
# (test/ctest_costs/KIND.txt); a folder with times of its own keeps them. A test the
# file does not name (a new one) counts as short and starts after the named ones.
#
#   scripts/seed_test_costs.sh BUILD KIND            seed BUILD (KIND: release, asan, tsan)
#   scripts/seed_test_costs.sh --update BUILD KIND   write KIND.txt from BUILD's times
#
# Only the order depends on these times: a stale file costs wall time, never a result.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
update=0
if [ "${1:-}" = --update ]; then
  update=1
  shift
fi
[ $# -eq 2 ] || { echo "usage: $0 [--update] BUILD KIND" >&2; exit 1; }
build="$1"
seed="$root/test/ctest_costs/$2.txt"
data="$build/Testing/Temporary/CTestCostData.txt"

if [ "$update" = 1 ]; then
  [ -f "$data" ] || { echo "$0: no test times in $data (run ctest there first)" >&2; exit 1; }
  # "name runs seconds" per test until the "---" line that lists failed tests; names
  # with spaces (parameterized tests) are left out, as the ctest of Debian 12 cannot
  # read them back. Tests under a second hardly change the order.
  tmp="$(mktemp "$seed.XXXXXX")"
  awk '/^---/ { exit } NF == 3 && $3 >= 1.0 { printf "%s 1 %.1f\n", $1, $3 }' "$data" |
    sort -k3,3 -g -r > "$tmp"
  mv "$tmp" "$seed"
  echo "$seed: $(wc -l < "$seed") tests"
  exit 0
fi

[ -f "$seed" ] || { echo "$0: no test times for '$2' ($seed)" >&2; exit 1; }
[ -f "$data" ] && exit 0
mkdir -p "$(dirname "$data")"
cp "$seed" "$data"
