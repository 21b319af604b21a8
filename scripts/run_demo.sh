#!/usr/bin/env bash
# The project's main job on an embedded default: installs what is missing, builds,
# simulates a short HDL-64 drive around a loop, runs pcl_rast_slam on it and
# evaluates the trajectory against the simulator's ground truth.
# Outputs go to ./demo_output (or $1).
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
build="${PCL_RAST_BUILD_DIR:-$root/build}"
out="$(realpath -m "${1:-$root/demo_output}")"
"$root/scripts/setup_debian.sh"
"$root/scripts/build.sh" -DPCL_RAST_BUILD_TESTS=OFF

mkdir -p "$out"
echo "== simulating a 300-frame HDL-64 loop drive into $out/sequence"
"$build/tools/pcl_rast_simulate" -path loop -frames 300 -sensor hdl64 -seed 1 \
  -output "$out/sequence"
echo "== running pcl_rast_slam"
"$build/tools/pcl_rast_slam" -input "$out/sequence" -output "$out/slam" \
  -gt "$out/sequence/poses.txt"
echo "== evaluating against the simulator's ground truth"
"$build/tools/pcl_rast_eval" "$out/slam/poses_kitti.txt" "$out/sequence/poses.txt"
echo
echo "map:        $out/slam/map.pcd"
echo "render:     $out/slam/render.png"
echo "trajectory: $out/slam/poses_kitti.txt (KITTI), $out/slam/poses_tum.txt (TUM)"
echo "summary:    $out/slam/summary.json"
