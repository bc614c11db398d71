#!/usr/bin/env python3
"""tetra3rs and `startrack solve` side by side on the same fields (a bench, not CI).

    python3 -m venv /tmp/t3 && /tmp/t3/bin/pip install tetra3rs==0.14.0
    target/release/startrack catalog case --out /tmp/case --fields 1000 --seed 7
    target/release/startrack solve --case /tmp/case --out /tmp/case/ours.csv
    /tmp/t3/bin/python host-tests/bench/tetra3rs_side_by_side.py /tmp/case /tmp/case/ours.csv

Both solve every field of the case lost in space (tetra3rs with its own database for a
15 degree field, generated from the Gaia + Hipparcos catalog it ships, cached next to the
case). A solution is wrong when its boresight is more than 0.1 degree from the truth
(`truth.csv`). Prints solved, wrong, median and 99th-percentile time per field, and
database size for both, and the boresight RMS error of the right solutions. Times are each solver's own: `time_us` from `startrack solve`
(identification and attitude), `solve_time_ms` from tetra3rs.
"""
import csv
import math
import os
import sys

import tetra3rs


def boresight(q):
    """ICRS direction of camera +z for a scalar-first Hamilton ICRS->camera quaternion."""
    w, x, y, z = q
    # Third row of R(q): camera z axis in ICRS.
    return (2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y))


def angle_deg(a, b):
    d = sum(p * q for p, q in zip(a, b))
    c = [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
    return math.degrees(math.atan2(math.sqrt(sum(v * v for v in c)), d))


def radec_vec(ra_deg, dec_deg):
    ra, dec = math.radians(ra_deg), math.radians(dec_deg)
    return (math.cos(dec) * math.cos(ra), math.cos(dec) * math.sin(ra), math.sin(dec))


def pct(v, p):
    v = sorted(v)
    return v[round((len(v) - 1) * p)] if v else float("nan")


def main():
    case, ours_csv = sys.argv[1], sys.argv[2]
    truth = {r["field"]: boresight([float(r[k]) for k in ("qw", "qx", "qy", "qz")])
             for r in csv.DictReader(open(os.path.join(case, "truth.csv")))}
    db_path = os.path.join(case, "tetra3rs-15deg.db")
    if os.path.exists(db_path):
        db = tetra3rs.SolverDatabase.load_from_file(db_path)
    else:
        db = tetra3rs.SolverDatabase.generate_from_gaia(max_fov_deg=15.0, epoch_proper_motion_year=2025.0)
        db.save_to_file(db_path)
    rows = {"ours": {"solved": 0, "wrong": 0, "t": []}, "tetra3rs": {"solved": 0, "wrong": 0, "t": []}}
    for r in csv.DictReader(open(ours_csv)):
        s = rows["ours"]
        s["t"].append(float(r["time_us"]))
        if r["solved"] == "1":
            s["solved"] += 1
            b = boresight([float(r[k]) for k in ("qw", "qx", "qy", "qz")])
            err = angle_deg(b, truth[r["field"]])
            s["wrong"] += err > 0.1
            s.setdefault("err", []).append(err)
    names = sorted(f[:-4] for f in os.listdir(os.path.join(case, "fields")) if f.endswith(".csv"))
    for name in names:
        # tetra3rs: origin at the image centre, +x right, +y down (ours: column, row from
        # the top-left pixel's centre), so the principal point moves to 0.
        pts = [tetra3rs.Centroid(float(r["x_px"]) - 511.5, float(r["y_px"]) - 511.5, float(r["flux_e"]))
               for r in csv.DictReader(open(os.path.join(case, "fields", name + ".csv")))]
        res = db.solve_from_centroids(pts, fov_estimate_deg=15.0, image_width=1024, image_height=1024)
        s = rows["tetra3rs"]
        s["t"].append(res.solve_time_ms * 1000.0)
        if isinstance(res, tetra3rs.SolveResult) and bool(res):
            s["solved"] += 1
            err = angle_deg(radec_vec(res.ra_deg, res.dec_deg), truth[name])
            s["wrong"] += err > 0.1
            s.setdefault("err", []).append(err)
    n = len(names)
    ours_db = 584404
    t3_db = os.path.getsize(db_path)
    print(f"{n} fields from {case}")
    print("| solver | solved | wrong | boresight RMS (right solutions) | median time per field | p99 time per field | database |")
    print("|---|---|---|---|---|---|---|")
    for name, db_bytes in (("startrack", ours_db), ("tetra3rs", t3_db)):
        s = rows["ours" if name == "startrack" else "tetra3rs"]
        right = [e for e in s.get("err", []) if e <= 0.1]
        rms = math.sqrt(sum(e * e for e in right) / len(right)) * 3600 if right else float("nan")
        print(f"| {name} | {s['solved']} ({100.0 * s['solved'] / n:.1f} %) | {s['wrong']} | {rms:.2f} arcsec | "
              f"{pct(s['t'], 0.5) / 1000:.3f} ms | {pct(s['t'], 0.99) / 1000:.3f} ms | {db_bytes / 1e6:.2f} MB |")


if __name__ == "__main__":
    main()
