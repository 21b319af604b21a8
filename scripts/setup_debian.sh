#!/usr/bin/env bash
# Installs the Debian 12 packages pcl_rast needs to build, test and render.
# Idempotent: packages already present are not touched, and apt is only called
# when something is missing.
set -euo pipefail

packages=(
  build-essential cmake pkg-config git
  ninja-build           # scripts/build.sh and the sanitizer builds
  libpcl-dev            # PCL 1.13 with VTK 9.1, FLANN, Eigen, Boost
  libopencv-dev         # OpenCV 4.6: ORB, images
  libceres-dev          # Ceres 2.1: bundle adjustment, pose graph
  nlohmann-json3-dev    # JSON summaries and evaluation output
  zlib1g-dev            # crc32 of the files sessions and output sets list
  libpng-dev            # the PNG pictures (renders, feature images)
  libgtest-dev libgmock-dev libbenchmark-dev
  xvfb xauth libgl1-mesa-dri libx11-dev  # offscreen VTK rendering (Debian VTK is X-only)
  clang libclang-rt-14-dev  # libFuzzer for scripts/fuzz.sh (the sanitizers of CI are gcc's)
)

missing=()
for pkg in "${packages[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$pkg")
  fi
done

if [ ${#missing[@]} -eq 0 ]; then
  echo "setup_debian: all ${#packages[@]} packages present"
  exit 0
fi

sudo=""
if [ "$(id -u)" -ne 0 ]; then
  sudo="sudo"
fi
echo "setup_debian: installing ${missing[*]}"
export DEBIAN_FRONTEND=noninteractive
$sudo apt-get update -qq
$sudo apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
echo "setup_debian: done"
