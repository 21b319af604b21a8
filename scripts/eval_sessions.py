#!/usr/bin/env python3
"""The targets of issue 13 on a simulated KITTI-length drive (every figure it prints is
simulated).

One realistic world is simulated along a KITTI ground-truth trajectory (raw sweeps with a
PCD time field, realistic traffic, sensor imperfections, mixed scenes, rough ground,
porous vegetation; reporting seed 101 by default, seeds below 100 are for tuning). Its
frames 0..M are the first drive, the rest the second drive: the second drive meets other
traffic (a later time) and other sensor noise (noise is hashed per frame) where it
revisits the first drive's roads. Then:

  map       pcl_rast_slam on the first drive, -save-session
  localize  pcl_rast_localize on the second drive with no initial pose
  alone     pcl_rast_slam on the second drive alone (speed reference, its own session)
  merge     pcl_rast_slam -session on the second drive (multi-session), -save-session
  kidnap    pcl_rast_localize on the second drive with 200 frames cut out
  cold      pcl_rast_localize on 3 scans from each of N random frames of the second drive
            that lie on mapped roads (--cold-every K: from every K-th of them instead, a
            sample large enough to tell a rate of 95 % from 90 %); with --cold-off-every K
            also from every K-th frame off the map, where a placement is wrong when it is
            more than 2 m from ground truth

"On mapped roads": within 5 m of a first-drive position (ground truth); "off the map":
farther than 20 m from every one. The ATE with the map frame aligned once is split into
horizontal and vertical parts, beside the map's own error at the same places (which the
localization follows); the multi-session joint ATE is split the same way per drive.

With --drive-seed D the second drive comes from a second simulation of the same world
along the same trajectory (pcl_rast_simulate -drive-seed D): other traffic, other noise
and another sensor unit's per-beam calibration. The map is still made from the first
simulation's frames 0..M; every step on the second drive reads the second simulation.

With --stride S the second drive is every S-th scan (a vehicle S times as fast at the
same scan rate; the kidnapping cuts the same 200 frames of the drive, 200 / S scans, so
that it lands as far away; a cold start takes 3 scans), and there is no merge.

  scripts/eval_sessions.py [-b BUILD] [-o OUT] [-q SEQ] [-m MAP_LAST] [-r SEED]
                           [-n COLD_STARTS] [--cold-every K] [--cold-off-every K]
                           [-l LAST] [--keep] [--no-merge]
                           [--stride S] [--drive-seed D] [--sim-args ARGS]
                           [--localize-args ARGS]
"""
import argparse
import csv
import json
import math
import os
import random
import shutil
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def run(cmd, log):
    """Run a tool, its stderr into log; returns (exit code, wall seconds)."""
    start = time.monotonic()
    with open(log, "w") as f:
        rc = subprocess.call(cmd, stdout=f, stderr=subprocess.STDOUT)
    return rc, time.monotonic() - start


def read_kitti(path):
    poses = []
    with open(path) as f:
        for line in f:
            v = line.split()
            if len(v) == 12:
                poses.append([float(x) for x in v])
    return poses


def position(p):
    return (p[3], p[7], p[11])


def horizontal_vertical(pairs):
    """RMS of the horizontal and of the vertical part of (estimate, truth) position
    pairs, in the simulator's world frame (z up)."""
    pairs = list(pairs)
    h = sum((a[0] - b[0]) ** 2 + (a[1] - b[1]) ** 2 for a, b in pairs)
    v = sum((a[2] - b[2]) ** 2 for a, b in pairs)
    n = max(1, len(pairs))
    return math.sqrt(h / n), math.sqrt(v / n)


def dist(a, b):
    return math.sqrt(sum((x - y) ** 2 for x, y in zip(a, b)))


def write_kitti(path, poses):
    with open(path, "w") as f:
        for p in poses:
            f.write(" ".join("%.9f" % x for x in p) + "\n")


def pose_from_json(v):
    """[x y z qx qy qz qw] -> KITTI row."""
    x, y, z, qx, qy, qz, qw = v
    r = [[1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qz * qw), 2 * (qx * qz + qy * qw)],
         [2 * (qx * qy + qz * qw), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qx * qw)],
         [2 * (qx * qz - qy * qw), 2 * (qy * qz + qx * qw), 1 - 2 * (qx * qx + qy * qy)]]
    return [r[0][0], r[0][1], r[0][2], x, r[1][0], r[1][1], r[1][2], y,
            r[2][0], r[2][1], r[2][2], z]


def evaluate(build, est, gt, out, name, align="se3"):
    """pcl_rast_eval's JSON of est against gt (KITTI rows, paired by index)."""
    e, g = os.path.join(out, name + "_est.txt"), os.path.join(out, name + "_gt.txt")
    write_kitti(e, est)
    write_kitti(g, gt)
    text = subprocess.check_output(
        [os.path.join(build, "tools", "pcl_rast_eval"), e, g, "-json", "-align", align],
        stderr=subprocess.DEVNULL)
    return json.loads(text)


def ate(build, est, gt, out, name, align="se3"):
    """ATE RMSE [m] of est against gt (KITTI rows, paired by index) via pcl_rast_eval."""
    return evaluate(build, est, gt, out, name, align)["ate_rmse_m"]


def transform_point(t, p):
    """The 4x4 row-major t applied to the point p."""
    return tuple(sum(t[4 * r + k] * p[k] for k in range(3)) + t[4 * r + 3] for r in range(3))


class Spatial:
    """Nearest first-drive position, on a 10 m grid."""

    def __init__(self, points):
        self.cells = {}
        for k, p in enumerate(points):
            self.cells.setdefault((int(p[0] // 10), int(p[1] // 10)), []).append((p, k))

    def nearest_index(self, q, reach=3):
        """(distance, index) of the nearest point (inf, None when none within reach)."""
        cx, cy = int(q[0] // 10), int(q[1] // 10)
        best = (float("inf"), None)
        for dx in range(-reach, reach + 1):
            for dy in range(-reach, reach + 1):
                for p, k in self.cells.get((cx + dx, cy + dy), ()):
                    best = min(best, (dist(p, q), k))
        return best

    def nearest(self, q, reach=3):
        return self.nearest_index(q, reach)[0]


def compose(a, b):
    """KITTI rows a * b."""
    out = []
    for r in range(3):
        row = [sum(a[4 * r + k] * b[4 * k + c] for k in range(3)) for c in range(3)]
        row.append(sum(a[4 * r + k] * b[4 * k + 3] for k in range(3)) + a[4 * r + 3])
        out += row
    return out


def inverse(a):
    """KITTI row of the inverse rigid motion."""
    rt = [a[4 * c + r] for r in range(3) for c in range(3)]
    t = [-sum(rt[3 * r + k] * a[4 * k + 3] for k in range(3)) for r in range(3)]
    return [rt[0], rt[1], rt[2], t[0], rt[3], rt[4], rt[5], t[1], rt[6], rt[7], rt[8], t[2]]


class MapTruth:
    """Where the map puts a second-drive frame: the map's pose of the nearest first-drive
    frame, moved by the true relative motion. The localization follows the map, so a
    placement is judged against this; against ground truth it also carries the map's
    own drift."""

    def __init__(self, gt, map_est, mapped):
        self.gt, self.map_est, self.mapped = gt, map_est, mapped

    def position(self, i):
        d, j = self.mapped.nearest_index(position(self.gt[i]))
        if j is None or j >= len(self.map_est):
            return None
        return position(compose(self.map_est[j], compose(inverse(self.gt[j]), self.gt[i])))

    def error(self, i, est):
        """Distance of the estimated KITTI row est of frame i from the map's pose."""
        p = self.position(i)
        return dist(position(est), p) if p is not None else None


def statuses(path):
    with open(path) as f:
        return list(csv.DictReader(f))


def localized_online(row):
    """Localized as the run went: not localized later by a placement's backtracking."""
    return row["status"] == "localized" and row.get("backtracked", "0") != "1"


def kidnap(a, out, sim, session, gt, second, index, on_map, tool, loc, localized, truth):
    if len(on_map) <= 400 // a.stride:
        print("\nkidnapping: not measured: %d frames on mapped roads" % len(on_map))
        return

    span = 200  # frames of the drive (every a.stride-th of them is in the input)
    cut = on_map[len(on_map) // 2] - span // 2
    kid = os.path.join(out, "kidnap_input")
    shutil.rmtree(kid, ignore_errors=True)
    os.makedirs(os.path.join(kid, "pcd"))
    times = open(os.path.join(sim, "times.txt")).read().split()
    kept = [i for i in second if not cut <= i < cut + span]
    with open(os.path.join(kid, "times.txt"), "w") as f:
        for j, i in enumerate(kept):
            os.symlink(os.path.join(sim, "pcd", "%06d.pcd" % i),
                       os.path.join(kid, "pcd", "%06d.pcd" % j))
            f.write(times[i] + "\n")
    tool("pcl_rast_localize", ["-session", session, "-input", kid, "-output",
                               os.path.join(out, "kidnap")], "kidnap.log")
    ks = json.load(open(os.path.join(out, "kidnap", "summary.json")))
    kp = read_kitti(os.path.join(out, "kidnap", "poses_kitti.txt"))
    krows = statuses(os.path.join(out, "kidnap", "status.csv"))
    gap = next(j for j, i in enumerate(kept) if i >= cut + span)
    recovered = None
    # Right again: where the uncut run put the same scan (within 0.5 m) when that run
    # localized it, else within 2 m of ground truth (the map's own drift is larger than
    # 0.5 m there, and the localization follows the map).
    for j in range(gap, min(gap + 50, len(kept))):
        if not localized_online(krows[j]):
            continue
        i = kept[j]
        if (i in localized and dist(position(kp[j]), position(loc[index[i]])) < 0.5) or \
                (i not in localized and dist(position(kp[j]), position(gt[i])) < 2.0):
            recovered = j - gap
            break
    # Localized at the wrong place after the cut: more than 2 m from the map's own pose
    # of the place (or from ground truth where the map has no such frame).
    false = []
    for j in range(gap, len(kept)):
        if krows[j]["status"] != "localized":
            continue
        e = truth.error(kept[j], kp[j])
        if e is None:
            e = dist(position(kp[j]), position(gt[kept[j]]))
        if e > 2.0:
            false.append(j)
    jumps = [jp["frame"] for jp in ks["jumps"]]
    print("\nkidnapping (frames %d-%d cut): jump reported at input frames %s (the cut is "
          "before input frame %d); right again (within 0.5 m of the uncut run) %s"
          % (cut, cut + span - 1, jumps, gap,
             "after %d frames" % recovered if recovered is not None else "NOT within 50 frames"))
    print("  frames localized more than 2 m off after the cut: %d%s"
          % (len(false), " (input frames %s)" % false[:10] if false else ""))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("-b", "--build", default=os.path.join(ROOT, "build"))
    ap.add_argument("-o", "--out", default="/tmp/pcl_rast_eval_sessions")
    ap.add_argument("-q", "--seq", default="00")
    ap.add_argument("-m", "--map-last", type=int, default=2000)
    ap.add_argument("-r", "--seed", type=int, default=101)
    ap.add_argument("-n", "--cold-starts", type=int, default=20)
    ap.add_argument("--cold-every", type=int, default=0,
                    help="cold starts from every K-th frame on mapped roads instead of "
                         "-n random ones (0: random)")
    ap.add_argument("--cold-off-every", type=int, default=0,
                    help="also cold starts from every K-th frame off the map (0: none)")
    ap.add_argument("-l", "--last", type=int, default=-1,
                    help="last frame simulated (-1: the whole sequence; for a quick check)")
    ap.add_argument("--keep", action="store_true", help="keep the simulated scans")
    ap.add_argument("--no-merge", action="store_true",
                    help="skip the multi-session merge (the longest step)")
    ap.add_argument("--stride", type=int, default=1,
                    help="the second drive at every S-th scan (S times as fast; no merge)")
    ap.add_argument("--drive-seed", type=int, default=0,
                    help="the second drive from another simulation of the same world: "
                         "other traffic, noise and sensor calibration (0: the same "
                         "simulation)")
    ap.add_argument("--sim-args", default="",
                    help="extra arguments of pcl_rast_simulate, e.g. '-elevation-bias 0' "
                         "(a diagnostic: the realistic world is the default)")
    ap.add_argument("--localize-args", default="",
                    help="extra arguments of every pcl_rast_localize run, e.g. "
                         "'-place-min-inliers 30'")
    ap.add_argument("--slam-args", default="",
                    help="extra arguments of every pcl_rast_slam run (the map, the second "
                         "drive alone and the merge), e.g. '-features-on-demand'")
    a = ap.parse_args()
    if a.stride < 1:
        sys.exit("--stride must be >= 1, got %d" % a.stride)
    if a.drive_seed < 0:
        sys.exit("--drive-seed must be >= 0, got %d" % a.drive_seed)
    if a.cold_every < 0 or a.cold_off_every < 0:
        sys.exit("--cold-every and --cold-off-every must be >= 0, got %d and %d"
                 % (a.cold_every, a.cold_off_every))
    if a.stride > 1:
        a.no_merge = True
    tools = os.path.join(a.build, "tools")
    out = os.path.join(a.out, a.seq)
    os.makedirs(out, exist_ok=True)
    gt_path = os.path.join(ROOT, "..", "shared", "data", "kitti-gt-poses", a.seq + ".txt")
    settings = ("realistic: raw sweeps (PCD time field), realistic traffic, sensor "
                "imperfections, mixed scenes, rough ground, porous vegetation; seed %d%s"
                % (a.seed, " (a TUNING seed: do not report)" if a.seed < 100 else ""))
    print("eval_sessions (simulated): KITTI %s, first drive frames 0-%d, second drive the "
          "rest; %s" % (a.seq, a.map_last, settings), flush=True)
    if a.sim_args:
        print("pcl_rast_simulate with %s" % a.sim_args, flush=True)
    if a.stride > 1:
        print("second drive at every %d-th scan (%d times as fast)" % (a.stride, a.stride),
              flush=True)
    if a.drive_seed:
        print("second drive from another simulation of the world: -drive-seed %d (other "
              "traffic, noise and sensor calibration)" % a.drive_seed, flush=True)
    if a.localize_args:
        print("pcl_rast_localize with %s" % a.localize_args, flush=True)
    if a.slam_args:
        print("pcl_rast_slam with %s" % a.slam_args, flush=True)

    def simulate(folder, extra, log):
        if os.path.exists(os.path.join(folder, "poses.txt")):
            return
        rc, s = run([os.path.join(tools, "pcl_rast_simulate"), "-traj", gt_path, "-output",
                     folder, "-seed", str(a.seed), "-last", str(a.last), "-raw-sweep",
                     "-moving-cars", "-traffic", "realistic", "-imperfections", "-format",
                     "pcd", "-scene", "mixed", "-rough-ground", "-porous-vegetation",
                     "-threads", "2"] + extra + a.sim_args.split(), os.path.join(out, log))
        if rc != 0:
            sys.exit("pcl_rast_simulate failed: see %s/%s" % (out, log))
        print("simulated %s in %.0f s" % (os.path.basename(folder), s), flush=True)

    sim = os.path.join(out, "sim")  # the first drive's (and the second's by default)
    simulate(sim, [], "simulate.log")
    gt = read_kitti(os.path.join(sim, "poses.txt"))
    drive = sim  # the second drive's scans
    if a.drive_seed:
        drive = os.path.join(out, "sim_drive%d" % a.drive_seed)
        simulate(drive, ["-drive-seed", str(a.drive_seed)], "simulate_drive.log")
        if read_kitti(os.path.join(drive, "poses.txt")) != gt:
            sys.exit("the second simulation's poses differ from the first's")
    n, m = len(gt), a.map_last
    second_first = m + 1
    second = list(range(second_first, n, a.stride))  # the second drive's scans
    index = {i: k for k, i in enumerate(second)}      # their rows in its outputs
    strided = ["-stride", str(a.stride)] if a.stride > 1 else []
    common = ["-quiet", "-software-render"]

    def tool(name, args, log):
        extra = {"pcl_rast_localize": a.localize_args,
                 "pcl_rast_slam": a.slam_args}.get(name, "").split()
        rc, s = run([os.path.join(tools, name)] + args + extra + common, os.path.join(out, log))
        if rc != 0:
            sys.exit("%s failed (exit %d): see %s/%s" % (name, rc, out, log))
        return s

    session = os.path.join(out, "session")
    steps = [
        ("map", "pcl_rast_slam", ["-input", sim, "-last", str(m), "-output",
                                  os.path.join(out, "map"), "-save-session", session]),
        ("localize", "pcl_rast_localize", ["-session", session, "-input", drive, "-first",
                                           str(second_first), "-output",
                                           os.path.join(out, "localize")] + strided),
        ("alone", "pcl_rast_slam", ["-input", drive, "-first", str(second_first), "-output",
                                    os.path.join(out, "alone"), "-save-session",
                                    os.path.join(out, "alone_session")] + strided),
        ("merge", "pcl_rast_slam", ["-input", drive, "-first", str(second_first), "-output",
                                    os.path.join(out, "merge"), "-session", session,
                                    "-save-session", os.path.join(out, "merged_session")]),
    ]
    for name, program, args in steps:
        if name == "merge" and a.no_merge:
            continue
        if not os.path.exists(os.path.join(out, name, "summary.json")):
            print("%s: %.0f s" % (name, tool(program, args, name + ".log")), flush=True)

    mapped = Spatial([position(p) for p in gt[:m + 1]])
    near = [mapped.nearest(position(gt[i])) for i in range(n)]
    truth = MapTruth(gt, read_kitti(os.path.join(out, "map", "poses_kitti.txt")), mapped)
    on_map = [i for i in second if near[i] <= 5.0]
    off_map = [i for i in second if near[i] > 20.0]

    # ---- second pass ----
    loc = read_kitti(os.path.join(out, "localize", "poses_kitti.txt"))
    rows = statuses(os.path.join(out, "localize", "status.csv"))
    err = {i: dist(position(loc[index[i]]), position(gt[i])) for i in second}
    localized = {i for i in second if rows[index[i]]["status"] == "localized"}
    on_loc = [i for i in on_map if i in localized]
    on_online = [i for i in on_loc if localized_online(rows[index[i]])]
    ate_map = math.sqrt(sum(err[i] ** 2 for i in on_loc) / max(1, len(on_loc)))
    wrong = [i for i in localized if err[i] > 2.0]
    # The map frame placed on the ground truth once, by the map drive's own SE(3)
    # alignment (the ATE convention; nothing of the second drive is fitted): what is
    # left is the localization's error plus the map's local error at each place.
    map_poses = read_kitti(os.path.join(out, "map", "poses_kitti.txt"))
    map_eval = evaluate(a.build, map_poses, gt[:m + 1], out, "map_se3")
    t_gt_map = map_eval["T_gt_estimate"]
    aligned = {i: (transform_point(t_gt_map, position(loc[index[i]])), position(gt[i]))
               for i in on_loc}
    err_aligned = {i: dist(*pair) for i, pair in aligned.items()}
    ate_aligned = math.sqrt(sum(e * e for e in err_aligned.values()) / max(1, len(on_loc)))
    # The map's own error at the same places (its pose of each place, the same fit): the
    # part of the ATE above that the localization inherits.
    map_pose_of = {i: truth.position(i) for i in on_loc}  # None where the map has none
    map_places = [(transform_point(t_gt_map, p), position(gt[i]))
                  for i, p in map_pose_of.items() if p is not None]
    map_place_ate = math.sqrt(sum(dist(*pair) ** 2 for pair in map_places) /
                              max(1, len(map_places)))
    map_err = {i: dist(position(loc[index[i]]), p) if p is not None else None
               for i, p in map_pose_of.items()}
    wrong_on_map = [i for i in on_loc if map_err[i] is not None and map_err[i] > 2.0]
    map_rmse = math.sqrt(sum(e * e for e in map_err.values() if e is not None) /
                         max(1, len([e for e in map_err.values() if e is not None])))
    print("\nsecond pass (pcl_rast_localize, no initial pose), %d frames, %d on mapped roads, "
          "%d off the map:" % (len(second), len(on_map), len(off_map)))
    print("  on mapped roads: %d of %d localized (%.1f %%), ATE in the map frame %.3f m "
          "(against ground truth: includes the map's own error), largest %.3f m"
          % (len(on_loc), len(on_map), 100.0 * len(on_loc) / max(1, len(on_map)), ate_map,
             max([err[i] for i in on_loc] or [0])))
    print("  of those, %d localized as the run went (%.1f %%), %d later, by a placement's "
          "backtracking" % (len(on_online), 100.0 * len(on_online) / max(1, len(on_map)),
                            len(on_loc) - len(on_online)))
    print("  ATE with the map frame aligned once by the map drive's SE(3) fit (the ATE "
          "convention; the second drive is not fitted): %.3f m (horizontal %.3f, vertical "
          "%.3f), largest %.3f m"
          % ((ate_aligned,) + horizontal_vertical(aligned.values()) +
             (max(err_aligned.values() or [0]),)))
    print("  the map's own error at those places, which the localization follows (its pose of "
          "each place, the same fit): %.3f m (horizontal %.3f, vertical %.3f)"
          % ((map_place_ate,) + horizontal_vertical(map_places)))
    print("  placed more than 2 m off: %d frames (%d off the map)"
          % (len(wrong), len([i for i in wrong if i in off_map])))
    print("  against the map's own pose of each place (nearest first-drive frame moved by the "
          "true relative motion): RMSE %.3f m, largest %.3f m, %d frames more than 2 m off"
          % (map_rmse, max([e for e in map_err.values() if e is not None] or [0]),
             len(wrong_on_map)))
    off_status = {}
    for i in off_map:
        status = rows[index[i]]["status"]
        off_status[status] = off_status.get(status, 0) + 1
    print("  off the map: %s" % off_status)
    map_summary = json.load(open(os.path.join(out, "map", "summary.json")))
    map_ate = ate(a.build, map_poses, gt[:m + 1], out, "map", "none")
    print("  the map itself (pcl_rast_slam, frames 0-%d): ATE %.3f m unaligned, %.3f m SE(3)"
          % (m, map_ate, map_summary.get("ate_rmse_m") or map_eval["ate_rmse_m"]))

    # ---- speed, load, memory ----
    ls = json.load(open(os.path.join(out, "localize", "summary.json")))
    al = json.load(open(os.path.join(out, "alone", "summary.json")))
    print("\nspeed on the same %d scans: localize %.1f fps, pcl_rast_slam %.1f fps (ratio %.2f)"
          % (len(second), ls["fps"], al["fps"], ls["fps"] / al["fps"]))
    print("session of %d frames (%d key-frames): loaded in %.2f s; localize peak RSS %.0f MB, "
          "the run that wrote it %.0f MB"
          % (m + 1, ls["session_keyframes"], ls["session_load_s"], ls["peak_rss_mb"],
             map_summary["peak_rss_mb"]))

    # ---- multi-session ----
    if a.no_merge:
        print("\nmulti-session: not measured (--no-merge)")
    else:
        multi_session(a, out, gt, session, second_first)

    # ---- kidnapping: 200 frames cut out of the second drive ----
    try:
        kidnap(a, out, drive, session, gt, second, index, on_map, tool, loc, localized,
               truth)
    except Exception as e:  # report and go on to the cold starts
        print("\nkidnapping: not measured: %s" % e)
    cold_starts(a, out, drive, session, gt, n, on_map, tool, truth)
    if a.cold_off_every > 0:
        cold_starts_off_map(a, out, drive, session, gt, n, off_map, tool)
    if not a.keep:
        shutil.rmtree(sim, ignore_errors=True)
        shutil.rmtree(drive, ignore_errors=True)


def multi_session(a, out, gt, session, second_first):
    ms = json.load(open(os.path.join(out, "merge", "summary.json")))["multi_session"]
    print("\nmulti-session: %s" % ms["message"])

    def keyframe_ate(session_dir, offset_of_drive, name):
        """The SE(3)-aligned key-frame ATE, and each drive's (horizontal, vertical) RMS
        under that fit."""
        s = json.load(open(os.path.join(session_dir, "session.json")))
        drives = s.get("drives") or [{"first_keyframe": 0, "keyframes": len(s["keyframes"])}]
        est, ref, drive_of = [], [], []
        for d, drive in enumerate(drives):
            for k in range(drive["first_keyframe"], drive["first_keyframe"] + drive["keyframes"]):
                kf = s["keyframes"][k]
                est.append(pose_from_json(kf["pose"]))
                ref.append(gt[kf["frame_index"] + offset_of_drive[d]])
                drive_of.append(d)
        result = evaluate(a.build, est, ref, out, name)
        t = result["T_gt_estimate"]
        split = [horizontal_vertical((transform_point(t, position(e)), position(r))
                                     for e, r, dd in zip(est, ref, drive_of) if dd == d)
                 for d in range(len(drives))]
        return result["ate_rmse_m"], split

    first_alone, _ = keyframe_ate(session, [0], "kf_first")
    second_alone, _ = keyframe_ate(os.path.join(out, "alone_session"), [second_first],
                                   "kf_second")
    if ms["connected"]:
        joint, split = keyframe_ate(os.path.join(out, "merged_session"), [0, second_first],
                                    "kf_joint")
        print("  key-frame ATE (SE(3)-aligned): first drive alone %.3f m, second alone %.3f m, "
              "joint %.3f m (target: at most %.3f m)"
              % (first_alone, second_alone, joint, max(first_alone, second_alone) + 0.05))
        if len(split) == 2:
            print("  in the joint fit, horizontal / vertical: first drive %.3f / %.3f m, "
                  "second %.3f / %.3f m" % (split[0] + split[1]))
    else:
        print("  not joined: the second drive is component %d; key-frame ATE alone %.3f m and "
              "%.3f m" % (ms["component"], first_alone, second_alone))


def cold_start(a, out, sim, session, f, tool, folder):
    """pcl_rast_localize on the 3 scans from frame f into out/folder/f: its poses, its
    status rows and the index of its first placement as the run went (None: none)."""
    d = os.path.join(out, folder, str(f))
    tool("pcl_rast_localize", ["-session", session, "-input", sim, "-first", str(f), "-last",
                               str(f + 2 * a.stride), "-stride", str(a.stride), "-output", d],
         folder + ".log")
    rows = statuses(os.path.join(d, "status.csv"))
    first = next((j for j, r in enumerate(rows) if localized_online(r)), None)
    return read_kitti(os.path.join(d, "poses_kitti.txt")), rows, first


def cold_starts(a, out, sim, session, gt, n, on_map, tool, truth):
    last = 2 * a.stride  # the third scan of the start
    candidates = [i for i in on_map if i + last < n]
    if a.cold_every > 0:
        starts = candidates[::a.cold_every]
    else:
        rng = random.Random(a.seed)
        starts = sorted(rng.sample(candidates, min(a.cold_starts, len(candidates))))
    ok = bad = bad_gt = 0
    times_s = []
    missed, wrong = [], []
    for f in starts:
        cp, cr, first = cold_start(a, out, sim, session, f, tool, "cold")
        if first is None:
            missed.append(f)
            continue
        e_gt = dist(position(cp[first]), position(gt[f + first * a.stride]))
        e = truth.error(f + first * a.stride, cp[first])
        times_s.append(sum(float(r["ms"]) for r in cr[:first + 1]) / 1000.0)
        bad_gt += e_gt > 2.0
        if e is None or e > 2.0:
            bad += 1
            wrong.append("%d (%s m)" % (f, "?" if e is None else "%.1f" % e))
        else:
            ok += 1
    print("\ncold start on %d %s on mapped roads: %d localized within 3 scans, %d "
          "wrong (> 2 m from the map's own pose of the place; %d more than 2 m from ground "
          "truth, which includes the map's drift); time to the placement %s s (median)"
          % (len(starts), "frames, one in every %d of those" % a.cold_every if a.cold_every
             else "random frames",
             ok, bad, bad_gt,
             "%.2f" % sorted(times_s)[len(times_s) // 2] if times_s else "-"))
    print("  not localized: %s; wrong: %s" % (", ".join(map(str, missed)) or "none",
                                            ", ".join(wrong) or "none"))


def cold_starts_off_map(a, out, sim, session, gt, n, off_map, tool):
    """Cold starts where the map holds nothing to find: each placement there is
    checked against ground truth (the map's pose of the place does not exist)."""
    starts = [i for i in off_map if i + 2 * a.stride < n][::a.cold_off_every]
    placed, wrong = [], []
    for f in starts:
        cp, _, first = cold_start(a, out, sim, session, f, tool, "cold_off")
        if first is None:
            continue
        e_gt = dist(position(cp[first]), position(gt[f + first * a.stride]))
        placed.append("%d (%.1f m)" % (f, e_gt))
        if e_gt > 2.0:
            wrong.append(f)
    print("\ncold start on %d frames off the map (one in every %d, more than 20 m from the "
          "mapped roads): %d localized, %d of them more than 2 m from ground truth"
          % (len(starts), a.cold_off_every, len(placed), len(wrong)))
    print("  localized: %s" % (", ".join(placed) or "none"))


if __name__ == "__main__":
    main()
