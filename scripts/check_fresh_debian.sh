#!/usr/bin/env bash
# Runs the README's two commands on a fresh Debian 12: a minimal system made with
# debootstrap (apt and a shell, nothing of the build), a clone of this repository's
# HEAD in it and a copy of ../shared beside the clone. What setup_debian.sh forgets to
# install fails here, where on a developer's machine another package may have brought
# it along (CI's green run on the machine that made a change cannot show that).
#
#   sudo scripts/check_fresh_debian.sh [FOLDER]   (default /tmp/pcl_rast_fresh_debian)
#
# Needs root (debootstrap, chroot, bind mounts) and Debian's package mirror, ~7 GB of
# disk and about 20 minutes on two cores: the base system, the packages, the build, the
# whole test suite and the demo. FOLDER is made anew; it is left behind for a look at
# its logs (FOLDER/root/work/main/build) and removed by the next run.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
folder="${1:-/tmp/pcl_rast_fresh_debian}"
chroot_dir="$folder/root"

if [ "$(id -u)" -ne 0 ]; then
  echo "check_fresh_debian: needs root (debootstrap and chroot)" >&2
  exit 2
fi
if ! command -v debootstrap > /dev/null; then
  apt-get update -qq
  apt-get install -y -qq debootstrap > /dev/null
fi

mounts=(proc sys dev dev/pts)
unmount() {
  for ((i = ${#mounts[@]} - 1; i >= 0; i--)); do
    umount "$chroot_dir/${mounts[i]}" 2> /dev/null || true
  done
}

# Only a folder this script made (it leaves a marker) is removed; any other that is
# not empty is refused, so that a wrong argument cannot delete anything else.
marker="$folder/.pcl_rast_fresh_debian"
if [ -e "$folder" ] && [ -n "$(ls -A "$folder" 2> /dev/null)" ]; then
  if [ ! -f "$marker" ]; then
    echo "check_fresh_debian: '$folder' is not empty and was not made by this script" >&2
    exit 2
  fi
  unmount
  if grep -q " $chroot_dir/" /proc/mounts; then
    echo "check_fresh_debian: something is still mounted under $chroot_dir" >&2
    exit 1
  fi
  rm -rf "$folder"
fi
mkdir -p "$folder"
touch "$marker"
trap unmount EXIT

start=$(date +%s)
echo "check_fresh_debian: debootstrap bookworm (minbase) into $chroot_dir"
debootstrap --variant=minbase --include=ca-certificates bookworm "$chroot_dir" \
  http://deb.debian.org/debian > "$folder/debootstrap.log" 2>&1 ||
  { tail -20 "$folder/debootstrap.log"; exit 1; }
# The host's package sources (updates and security too), as a new machine has them.
if [ -f /etc/apt/sources.list.d/debian.sources ]; then
  cp /etc/apt/sources.list.d/debian.sources "$chroot_dir/etc/apt/sources.list.d/"
  rm -f "$chroot_dir/etc/apt/sources.list"
fi
for m in "${mounts[@]}"; do
  mount --bind "/$m" "$chroot_dir/$m"
done

# The committed HEAD, as CI clones it, and a read-only ../shared beside it.
git clone -q "$root" "$chroot_dir/work/main"
if [ -d "$root/../shared" ]; then
  cp -r "$root/../shared" "$chroot_dir/work/shared"
  chmod -R a-w "$chroot_dir/work/shared"
fi

# A clean environment: no variable of the host's session leaks in.
run() { # name command
  echo "check_fresh_debian: $1"
  chroot "$chroot_dir" /usr/bin/env -i HOME=/root LANG=C.UTF-8 \
    PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin \
    bash -c "cd /work/main && $2" > "$folder/$1.log" 2>&1 ||
    { tail -40 "$folder/$1.log"; echo "check_fresh_debian: $1 FAILED ($folder/$1.log)"; exit 1; }
}
run run_tests ./scripts/run_tests.sh
grep -E "tests passed|Total Test time" "$folder/run_tests.log"
run run_demo ./scripts/run_demo.sh
tail -5 "$folder/run_demo.log"
for f in map.pcd render.png poses_kitti.txt poses_tum.txt summary.json; do
  [ -s "$chroot_dir/work/main/demo_output/slam/$f" ] ||
    { echo "check_fresh_debian: the demo wrote no $f"; exit 1; }
done
echo "check_fresh_debian: both README commands passed on a fresh Debian 12 in" \
  "$(( $(date +%s) - start )) s"
