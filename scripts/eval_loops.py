#!/usr/bin/env python3
"""Check pcl_rast_slam loop-closure edges against ground truth, and the recall of revisits.

For every sequence NN it reads OUT/NN_loops/summary.json ("loop_edges": query_frame,
candidate_frame, active, T_candidate_query as a row-major 4x4) and the ground-truth poses
(KITTI format, LiDAR frame, one 3x4 row-major line per frame).

Loop edge error: E = inv(T_gt) * T_est with T_gt = inv(P_candidate) * P_query;
translation error = |t(E)| [m], rotation error = angle(R(E)) [deg]. An edge with more than
--max-trans m or --max-rot deg error is a FALSE loop.

Revisits: frame i is a revisit frame when some frame j < i - --min-gap (default 100) lies
within --radius m (default 10, 3D distance) of it. A revisit segment is a maximal run of
consecutive revisit frames; segments shorter than --min-len (default 10) frames are ignored.
A segment is found when it contains the query_frame of at least one accepted loop edge
(by default only edges still active at the end; --all-edges also counts dropped ones).

GT lookup order for a sequence: --gt-pattern (default OUT/NN_gt_poses.txt), then the "gt"
path recorded in summary.json. Frame indices are used as GT line indices, which holds for
runs with -first 0 -stride 1 (checked against summary params).

Segments whose middle frame is < --min-path (50) m along the path from its nearest earlier
neighbour are stops (standing at a light), not revisits; they are counted in the strict
revisit_found/total column and excluded from the moving_found/total column.

Usage: scripts/eval_loops.py --out RESULTS [--seqs 00 01 ...] [-v] [--json FILE]
(RESULTS holds NN_loops/ from pcl_rast_slam -output RESULTS/NN_loops -gt ..., and
NN_gt_poses.txt copies of the ground truth, or the "gt" path in summary.json is used.)
Standard library only.
"""
import argparse
import json
import math
import os
import sys


def read_kitti(path):
    poses = []
    with open(path) as f:
        for line in f:
            v = line.split()
            if len(v) < 12:
                continue
            v = [float(x) for x in v[:12]]
            poses.append(([v[0:3], v[4:7], v[8:11]], [v[3], v[7], v[11]]))
    return poses


def mat_from_flat(m):
    if len(m) == 4 and isinstance(m[0], list):  # nested rows
        m = [x for row in m for x in row]
    return ([m[0:3], m[4:7], m[8:11]], [m[3], m[7], m[11]])


def matmul(A, B):
    return [[sum(A[i][k] * B[k][j] for k in range(3)) for j in range(3)] for i in range(3)]


def matvec(A, v):
    return [sum(A[i][k] * v[k] for k in range(3)) for i in range(3)]


def transpose(A):
    return [[A[j][i] for j in range(3)] for i in range(3)]


def inv(T):
    R, t = T
    Rt = transpose(R)
    return (Rt, [-x for x in matvec(Rt, t)])


def compose(A, B):
    RA, tA = A
    RB, tB = B
    return (matmul(RA, RB), [a + b for a, b in zip(matvec(RA, tB), tA)])


def rot_angle_deg(R):
    c = (R[0][0] + R[1][1] + R[2][2] - 1.0) / 2.0
    return math.degrees(math.acos(max(-1.0, min(1.0, c))))


def revisit_segments(poses, radius, min_gap, min_len):
    """Maximal runs of frames with an earlier (> min_gap frames) neighbour within radius.
    Returns [(first, last, info)] where info describes the segment's middle frame: its
    nearest earlier neighbour, their distance and the heading difference (angle between the
    two LiDAR x axes, deg; ~180 means driving the other way)."""
    pts = [t for _, t in poses]
    cell = radius
    grid = {}
    nearest = [None] * len(pts)
    r2 = radius * radius
    for i, p in enumerate(pts):
        j = i - min_gap - 1  # frames j < i - min_gap are eligible
        if j >= 0:
            q = pts[j]
            grid.setdefault((int(math.floor(q[0] / cell)), int(math.floor(q[1] / cell)),
                             int(math.floor(q[2] / cell))), []).append(j)
        cx, cy, cz = (int(math.floor(p[0] / cell)), int(math.floor(p[1] / cell)),
                      int(math.floor(p[2] / cell)))
        best = None
        for dx in (-1, 0, 1):
            for dy in (-1, 0, 1):
                for dz in (-1, 0, 1):
                    for k in grid.get((cx + dx, cy + dy, cz + dz), ()):
                        q = pts[k]
                        d2 = (p[0] - q[0]) ** 2 + (p[1] - q[1]) ** 2 + (p[2] - q[2]) ** 2
                        if d2 <= r2 and (best is None or d2 < best[1]):
                            best = (k, d2)
        nearest[i] = best
    cum = [0.0]
    for a, b in zip(pts, pts[1:]):
        cum.append(cum[-1] + math.sqrt(sum((x - y) ** 2 for x, y in zip(a, b))))
    segs = []
    start = None
    for i, nb in enumerate(nearest + [None]):
        if nb is not None and start is None:
            start = i
        elif nb is None and start is not None:
            if i - start >= min_len:
                m = (start + i - 1) // 2
                k, d2 = nearest[m]
                Ra, Rb = poses[m][0], poses[k][0]
                c = sum(Ra[r][0] * Rb[r][0] for r in range(3))
                info = {"mid_frame": m, "earlier_frame": k, "dist_m": math.sqrt(d2),
                        "heading_diff_deg": math.degrees(math.acos(max(-1.0, min(1.0, c)))),
                        "path_between_m": cum[m] - cum[k]}
                segs.append((start, i - 1, info))
            start = None
    return segs


def analyse(nn, out, args):
    run = os.path.join(out, "%s_loops" % nn)
    sj = os.path.join(run, "summary.json")
    if not os.path.isfile(sj):
        return None
    with open(sj) as f:
        s = json.load(f)
    gt_path = args.gt_pattern.replace("OUT", out).replace("NN", nn)
    if not os.path.isfile(gt_path):
        gt_path = s.get("gt", "")
    if not gt_path or not os.path.isfile(gt_path):
        return {"seq": nn, "error": "no GT file"}
    gt = read_kitti(gt_path)
    p = s.get("params", {})
    warn = []
    if p.get("first", 0) not in (0, None) or p.get("stride", 1) != 1:
        warn.append("first/stride != 0/1: frame indices may not be GT line indices")
    if s.get("frames") != len(gt):
        warn.append("frames %s != GT lines %d" % (s.get("frames"), len(gt)))
    edges = []
    for e in s.get("loop_edges", []):
        q, c = e["query_frame"], e["candidate_frame"]
        T_est = mat_from_flat(e["T_candidate_query"])
        T_gt = compose(inv(gt[c]), gt[q])
        E = compose(inv(T_gt), T_est)
        te = math.sqrt(sum(x * x for x in E[1]))
        re = rot_angle_deg(E[0])
        gt_dist = math.sqrt(sum(x * x for x in T_gt[1]))
        edges.append({"query_frame": q, "candidate_frame": c, "active": e.get("active", True),
                      "inliers": e.get("inliers"), "t_err_m": te, "r_err_deg": re,
                      "gt_dist_m": gt_dist,
                      "false": te > args.max_trans or re > args.max_rot})
    segs = revisit_segments(gt, args.radius, args.min_gap, args.min_len)
    counted = [e for e in edges if args.all_edges or e["active"]]
    found = []
    for a, b, _ in segs:
        found.append(any(a <= e["query_frame"] <= b for e in counted))
    outside = [e for e in counted
               if not any(a <= e["query_frame"] <= b for a, b, _ in segs)]
    active = [e for e in edges if e["active"]]
    return {
        "seq": nn, "gt": gt_path, "frames": s.get("frames"), "warnings": warn,
        "loops_accepted": s.get("loops_accepted"),
        "loops_dropped_inconsistent": s.get("loops_dropped_inconsistent"),
        "edges": len(edges), "edges_active": len(active),
        "false_all": sum(e["false"] for e in edges),
        "false_active": sum(e["false"] for e in active),
        "worst_t_err_m": max((e["t_err_m"] for e in edges), default=None),
        "worst_r_err_deg": max((e["r_err_deg"] for e in edges), default=None),
        "worst_t_err_active_m": max((e["t_err_m"] for e in active), default=None),
        "worst_r_err_active_deg": max((e["r_err_deg"] for e in active), default=None),
        "segments": [dict(first=a, last=b, found=f, **info) for (a, b, info), f in zip(segs, found)],
        "segments_total": len(segs), "segments_found": sum(found),
        "moving_segments_total": sum(1 for s in segs if s[2]["path_between_m"] >= args.min_path),
        "moving_segments_found": sum(f for s, f in zip(segs, found)
                                     if s[2]["path_between_m"] >= args.min_path),
        "edges_outside_segments": len(outside),
        "edge_details": edges,
    }


def fmt(x, spec):
    return "-" if x is None else format(x, spec)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", required=True, help="folder with NN_loops/ result folders")
    ap.add_argument("--seqs", nargs="*", default=["%02d" % i for i in range(11)])
    ap.add_argument("--gt-pattern", default="OUT/NN_gt_poses.txt")
    ap.add_argument("--max-trans", type=float, default=0.5)
    ap.add_argument("--max-rot", type=float, default=2.0)
    ap.add_argument("--radius", type=float, default=10.0)
    ap.add_argument("--min-gap", type=int, default=100)
    ap.add_argument("--min-len", type=int, default=10)
    ap.add_argument("--min-path", type=float, default=50.0,
                    help="a segment whose middle frame and its nearest earlier neighbour are "
                         "less than this far apart along the path is a stop, not a revisit "
                         "(reported separately: 'moving' columns)")
    ap.add_argument("--all-edges", action="store_true",
                    help="count dropped (inactive) edges for revisit recall too")
    ap.add_argument("-v", action="store_true", help="print every edge and segment")
    ap.add_argument("--json", help="write the full analysis here")
    args = ap.parse_args()

    results = []
    hdr = ("seq  frames edges(act) false(all/act) worst_t_m worst_r_deg "
           "worst_t_act worst_r_act  revisit_found/total  moving_found/total  edges_outside_seg")
    print(hdr)
    print("-" * len(hdr))
    for nn in args.seqs:
        r = analyse(nn, args.out, args)
        if r is None:
            print("%s   (no summary.json)" % nn)
            continue
        results.append(r)
        if "error" in r:
            print("%s   %s" % (nn, r["error"]))
            continue
        print("%-4s %6s %5d(%d) %8d/%-5d %9s %11s %11s %11s  %8d/%-10d %7d/%-10d %d" % (
            nn, r["frames"], r["edges"], r["edges_active"], r["false_all"], r["false_active"],
            fmt(r["worst_t_err_m"], ".3f"), fmt(r["worst_r_err_deg"], ".3f"),
            fmt(r["worst_t_err_active_m"], ".3f"), fmt(r["worst_r_err_active_deg"], ".3f"),
            r["segments_found"], r["segments_total"], r["moving_segments_found"],
            r["moving_segments_total"], r["edges_outside_segments"]))
        for w in r["warnings"]:
            print("     warning: " + w)
        if args.v:
            for seg in r["segments"]:
                print("     segment %5d-%5d (%4d frames) %-6s  mid %d ~ earlier %d: %.1f m, "
                      "heading diff %.0f deg, %.0f m apart along the path" % (
                          seg["first"], seg["last"], seg["last"] - seg["first"] + 1,
                          "found" if seg["found"] else "MISSED", seg["mid_frame"],
                          seg["earlier_frame"], seg["dist_m"], seg["heading_diff_deg"],
                          seg["path_between_m"]))
            for e in r["edge_details"]:
                print("     edge q=%5d c=%5d active=%d inl=%s gt_dist=%6.2f m  t_err=%.3f m "
                      "r_err=%.3f deg%s" % (
                          e["query_frame"], e["candidate_frame"], e["active"], e["inliers"],
                          e["gt_dist_m"], e["t_err_m"], e["r_err_deg"],
                          "  FALSE" if e["false"] else ""))
    tot = [r for r in results if "error" not in r]
    print("-" * len(hdr))
    print("total: edges %d (active %d), false %d (active %d), revisit segments found %d/%d "
          "(moving: %d/%d)" % (
        sum(r["edges"] for r in tot), sum(r["edges_active"] for r in tot),
        sum(r["false_all"] for r in tot), sum(r["false_active"] for r in tot),
        sum(r["segments_found"] for r in tot), sum(r["segments_total"] for r in tot),
        sum(r["moving_segments_found"] for r in tot),
        sum(r["moving_segments_total"] for r in tot)))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(results, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
