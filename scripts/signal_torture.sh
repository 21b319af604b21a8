#!/usr/bin/env bash
# Signals at random moments against the output sets (issue 12).
#
#   scripts/signal_torture.sh BUILD_DIR SCANS [RUNS_PER_TOOL=20] [SEED=1]
#
# For pcl_rast_slam, pcl_rast_odometry and pcl_rast_localize (on a session pcl_rast_slam
# saves of SCANS first) on the scan folder SCANS, and pcl_rast_simulate on a generated
# path: first one complete run into a fresh output folder, then
# RUNS_PER_TOOL runs into the same folder, each sent SIGINT, SIGTERM or SIGHUP (chosen at
# random) at a random moment of its run, every fourth of them a second signal 20 ms
# later, and every fifth a SIGKILL instead, timed to land while the outputs are written.
# After each run `pcl_rast_eval -check-output` must find exactly one complete set: the
# old one or the new one, never a mix. Prints one line per run and a tally; exit 1 on any
# mixed or missing set.
set -uo pipefail
build="$1"
scans="$2"
runs="${3:-20}"
RANDOM="${4:-1}"
tools="$build/tools"
work="$(mktemp -d)"
trap 'sleep 1; rm -rf "$work"' EXIT
bad=0

# Seconds (3 decimals) that a complete run takes, to spread the signals over it.
timed_run() { # tool out
  local s e
  s=$(date +%s%N)
  (run_tool "$1" "$2") > "$work/first.log" 2>&1 || { cat "$work/first.log"; exit 2; }
  e=$(date +%s%N)
  echo $(( (e - s) / 1000000 ))
}

run_tool() { # tool out; execs: call it in a subshell or in the background
  case "$1" in
  pcl_rast_slam) exec_args=(-input "$scans" -output "$2" -software-render -quiet) ;;
  pcl_rast_odometry) exec_args=(-input "$scans" -output "$2") ;;
  pcl_rast_localize)
    exec_args=(-session "$work/session" -input "$scans" -output "$2" -software-render -quiet) ;;
  pcl_rast_simulate) exec_args=(-path loop -frames 60 -output "$2") ;;
  esac
  exec "$tools/$1" "${exec_args[@]}"
}

check_set() { # tool out
  if [ "$1" = pcl_rast_simulate ]; then
    # A sequence, not an output set: poses.txt and times.txt must agree in length.
    local p t
    p=$(wc -l < "$2/poses.txt"); t=$(wc -l < "$2/times.txt")
    [ "$p" = "$t" ] && echo "sequence of $p frames" && return 0
    echo "poses.txt $p lines, times.txt $t"; return 1
  fi
  "$tools/pcl_rast_eval" -check-output "$2"
}

"$tools/pcl_rast_slam" -input "$scans" -output "$work/session_run" -save-session "$work/session" \
  -software-render -quiet > "$work/session.log" 2>&1 || { cat "$work/session.log"; exit 2; }
for tool in pcl_rast_slam pcl_rast_odometry pcl_rast_localize pcl_rast_simulate; do
  out="$work/$tool"
  ms=$(timed_run "$tool" "$out")
  echo "== $tool: a complete run takes $ms ms"
  for i in $(seq 1 "$runs"); do
    sigs=(INT TERM HUP)
    sig=${sigs[$((RANDOM % 3))]}
    kind="$sig"
    delay_ms=$(( RANDOM % (ms + 200) ))
    [ $((i % 4)) -eq 0 ] && kind="$sig+$sig"
    [ $((i % 5)) -eq 0 ] && { kind=KILL; delay_ms=$(( ms * (80 + RANDOM % 25) / 100 )); }
    run_tool "$tool" "$out" > "$work/run.log" 2>&1 &
    pid=$!
    sleep "$(printf '%d.%03d' $((delay_ms / 1000)) $((delay_ms % 1000)))"
    case "$kind" in
    KILL) kill -KILL "$pid" 2>/dev/null ;;
    *+*) kill -"$sig" "$pid" 2>/dev/null; sleep 0.02; kill -"$sig" "$pid" 2>/dev/null ;;
    *) kill -"$sig" "$pid" 2>/dev/null ;;
    esac
    wait "$pid" 2>/dev/null
    rc=$?
    if verdict=$(check_set "$tool" "$out" 2>&1); then ok=ok; else ok=MIXED; bad=$((bad + 1)); fi
    printf '%-18s run %2d  %-9s at %5d ms  exit %3d  %-5s %s\n' "$tool" "$i" "$kind" "$delay_ms" \
      "$rc" "$ok" "$(echo "$verdict" | head -1)"
  done
done
echo "signal_torture: $bad mixed or missing sets"
[ "$bad" -eq 0 ]
