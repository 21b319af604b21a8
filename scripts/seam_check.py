#!/usr/bin/env python3
"""Is a folder of spinning-LiDAR scans motion compensated? (doc/odometry.md, "Session 27")

A spinning head's sweep starts and ends behind the car. In a raw scan the points just
either side of that seam were recorded a whole sweep apart, so against the next scan,
moved by the odometry's motion, the two sides need x-shifts that differ by the distance
driven in one sweep. In a compensated scan both sides need the same shift. For each
pair of consecutive scans this prints the best shift of each side (-1.2 to 1.2 m in
5 cm steps; points 4-30 m away, more than 1.3 m below the sensor's height of KITTI's
1.73 m left out as ground, within 25 deg of the seam). Moving objects near the seam
show on one side only.

  scripts/seam_check.py PCD_FOLDER POSES_KITTI [--seam-deg 180] [--stride 1] [--distort]

PCD_FOLDER holds binary PCDs of four float fields, x y z first (KITTI's layout), named
in scan order by their numbers; POSES_KITTI is the odometry's poses_kitti.txt of the
same scans (pcl_rast_odometry -deskew off). --distort skews each scan as a raw sweep of a
clockwise head whose sweep starts and ends at --seam-deg would be, to see what the
check finds on one. Plain Python, no packages: about 10 s a pair.
"""
import argparse
import math
import os
import re
import struct


def read_pcd_xyz(path):
    data = open(path, 'rb').read()
    if b'DATA binary\n' not in data or b'FIELDS x y z' not in data:
        raise SystemExit(f'{path}: not a binary PCD with fields x y z and a fourth float')
    start = data.index(b'DATA binary\n') + len(b'DATA binary\n')
    count = (len(data) - start) // 16
    return [struct.unpack_from('<fff', data, start + 16 * k) for k in range(count)]


def read_poses(path):
    poses = []
    for line in open(path):
        if line.strip() and not line.startswith('#'):
            v = [float(x) for x in line.split()]
            poses.append([v[0:4], v[4:8], v[8:12]])
    return poses


def relative(a, b):
    """a^-1 b of two 3x4 poses, as (R, t)."""
    ra = [[a[j][i] for j in range(3)] for i in range(3)]
    rot = [[sum(ra[i][k] * b[k][j] for k in range(3)) for j in range(3)] for i in range(3)]
    d = [b[i][3] - a[i][3] for i in range(3)]
    return rot, [sum(ra[i][k] * d[k] for k in range(3)) for i in range(3)]


def seam_side(p, seam_deg, width_deg=25.0):
    """-1 or 1 for a point within width_deg before or after the seam, 0 elsewhere."""
    d = (math.degrees(math.atan2(p[1], p[0])) - seam_deg + 540.0) % 360.0 - 180.0
    if 1.0 < abs(d) < width_deg:
        return 1 if d > 0 else -1
    return 0


def best_shift(points, grid, cell):
    """The x-shift of points that brings them nearest the grid's (truncated at 0.3 m),
    or None without points."""
    if not points:
        return None
    best = None
    for step in range(-24, 25):
        dx = step * 0.05
        cost = 0.0
        for x, y, z in points:
            x += dx
            cx, cy, cz = (int(math.floor(c / cell)) for c in (x, y, z))
            d_min = 0.09
            for i in (-1, 0, 1):
                for j in (-1, 0, 1):
                    for k in (-1, 0, 1):
                        for q in grid.get((cx + i, cy + j, cz + k), ()):
                            d2 = (q[0] - x) ** 2 + (q[1] - y) ** 2 + (q[2] - z) ** 2
                            d_min = min(d_min, d2)
            cost += d_min
        if best is None or cost < best[0]:
            best = (cost, dx)
    return best[1]


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('folder')
    parser.add_argument('poses')
    parser.add_argument('--seam-deg', type=float, default=180.0)
    parser.add_argument('--stride', type=int, default=1)
    parser.add_argument('--distort', action='store_true')
    args = parser.parse_args()
    if args.stride < 1:
        raise SystemExit(f'--stride must be >= 1, got {args.stride}')
    poses = read_poses(args.poses)
    numeric = lambda f: [int(x) if x.isdigit() else x for x in re.split(r'(\d+)', f)]
    files = sorted((f for f in os.listdir(args.folder) if f.endswith('.pcd')), key=numeric)
    if len(files) != len(poses):
        raise SystemExit(f'{len(files)} scans but {len(poses)} poses')
    cell = 0.3

    def structure(n, max_range):  # scan n's points off the ground within max_range
        return [p for p in read_pcd_xyz(os.path.join(args.folder, files[n]))
                if p[2] > -1.3 and 4.0 < math.hypot(p[0], p[1]) < max_range]

    for n in range(0, len(files) - 1, args.stride):
        a, b = structure(n, 30.0), structure(n + 1, 40.0)
        rot, t = relative(poses[n], poses[n + 1])
        if args.distort:  # tau in [-1/2, 1/2] sweep, 0 opposite the seam
            def skew(p):
                az = math.degrees(math.atan2(p[1], p[0])) - args.seam_deg + 180.0
                tau = -((az + 180.0) % 360.0 - 180.0) / 360.0
                return tuple(p[i] - t[i] * tau for i in range(3))
            a = [skew(p) for p in a]
        grid = {}
        for p in b:
            q = [sum(rot[i][j] * p[j] for j in range(3)) + t[i] for i in range(3)]
            grid.setdefault(tuple(int(math.floor(c / cell)) for c in q), []).append(q)
        shifts = {}
        for side in (-1, 1):
            pts = [p for p in a if seam_side(p, args.seam_deg) == side][::4]
            shifts[side] = (best_shift(pts, grid, cell), len(pts))
        shown = {side: 'n/a' if v[0] is None else f'{v[0]:+.2f} m' for side, v in shifts.items()}
        print(f'frame {n}: step {math.sqrt(sum(x * x for x in t)):.2f} m, best x-shift before '
              f'the seam {shown[-1]} ({shifts[-1][1]} pts), after it {shown[1]} '
              f'({shifts[1][1]} pts)', flush=True)


if __name__ == '__main__':
    main()
