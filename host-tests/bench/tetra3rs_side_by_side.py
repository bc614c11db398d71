#!/usr/bin/env python3
"""tetra3rs and `startrack solve` side by side on the same fields (a bench, not CI).

    python3 -m venv /tmp/t3 && /tmp/t3/bin/pip install tetra3rs==0.14.0
    cargo build --release -p startrack-host --bin startrack
    target/release/startrack catalog case --out /tmp/case --fields 1000 --seed 7 --prior-error-deg 0.5
    target/release/startrack solve --case /tmp/case --out /tmp/case/lis.csv
    target/release/startrack solve --case /tmp/case --out /tmp/case/track.csv --prior /tmp/case/prior.csv --prior-error-deg 0.5
    /tmp/t3/bin/python host-tests/bench/tetra3rs_side_by_side.py /tmp/case /tmp/case/lis.csv /tmp/case/track.csv 0.5

Both solve every field of the case lost in space, and with a tracking CSV also from the
priors in `prior.csv` (tetra3rs: `attitude_hint` with `strict_hint`). tetra3rs uses its own
database for a 15 degree field, generated from the Gaia + Hipparcos catalog it ships and
cached next to the case. tetra3rs's quaternion has the same convention as ours (scalar
first, ICRS to camera, +z boresight, +x right, +y down; checked: its rotation matrix agrees
with the truth to 1e-4 on solved fields); its centroids are relative to the image centre.
A solution is wrong when its attitude is more than 0.1 degree from the truth (`truth.csv`).
Prints, per solver and mode: solved, wrong, boresight and roll RMS error of the right
solutions, median and 99th-percentile time per field, database size. Times are each
solver's own: `time_us` from `startrack solve`, `solve_time_ms` from tetra3rs.
"""
import csv
import math
import os
import sys

import tetra3rs


def qmul(a, b):
    a0, a1, a2, a3 = a
    b0, b1, b2, b3 = b
    return (a0 * b0 - a1 * b1 - a2 * b2 - a3 * b3,
            a0 * b1 + a1 * b0 + a2 * b3 - a3 * b2,
            a0 * b2 - a1 * b3 + a2 * b0 + a3 * b1,
            a0 * b3 + a1 * b2 - a2 * b1 + a3 * b0)


def error_vector(q, truth):
    """Rotation vector (rad, camera frame) of q * truth^-1: x, y boresight, z roll."""
    w, x, y, z = qmul(q, (truth[0], -truth[1], -truth[2], -truth[3]))
    if w < 0:
        w, x, y, z = -w, -x, -y, -z
    s = math.sqrt(x * x + y * y + z * z)
    if s == 0:
        return (0.0, 0.0, 0.0)
    ang = 2 * math.atan2(s, w)
    return (x / s * ang, y / s * ang, z / s * ang)


def pct(v, p):
    v = sorted(v)
    return v[round((len(v) - 1) * p)] if v else float("nan")


def read_q(path):
    return {r["field"]: tuple(float(r[k]) for k in ("qw", "qx", "qy", "qz"))
            for r in csv.DictReader(open(path))}


class Tally:
    def __init__(self):
        self.solved, self.wrong, self.t, self.bore2, self.roll2 = 0, 0, [], [], []

    def add(self, q, truth):
        self.solved += 1
        e = error_vector(q, truth)
        if math.sqrt(sum(c * c for c in e)) > math.radians(0.1):
            self.wrong += 1
        else:
            self.bore2.append(e[0] ** 2 + e[1] ** 2)
            self.roll2.append(e[2] ** 2)

    def row(self, name, n, db_bytes):
        rms = lambda v: math.sqrt(sum(v) / len(v)) * 206264.8 if v else float("nan")
        return (f"| {name} | {self.solved} ({100.0 * self.solved / n:.1f} %) | {self.wrong} | "
                f"{rms(self.bore2):.2f} | {rms(self.roll2):.1f} | {pct(self.t, 0.5) / 1000:.3f} ms | "
                f"{pct(self.t, 0.99) / 1000:.3f} ms | {db_bytes / 1e6:.2f} MB |")


def ours(path, truth):
    t = Tally()
    for r in csv.DictReader(open(path)):
        t.t.append(float(r["time_us"]))
        if r["solved"] == "1":
            t.add(tuple(float(r[k]) for k in ("qw", "qx", "qy", "qz")), truth[r["field"]])
    return t


def main():
    case, lis_csv = sys.argv[1], sys.argv[2]
    track_csv = sys.argv[3] if len(sys.argv) > 3 else None
    prior_deg = float(sys.argv[4]) if len(sys.argv) > 4 else None
    truth = read_q(os.path.join(case, "truth.csv"))
    db_path = os.path.join(case, "tetra3rs-15deg.db")
    if os.path.exists(db_path):
        db = tetra3rs.SolverDatabase.load_from_file(db_path)
    else:
        db = tetra3rs.SolverDatabase.generate_from_gaia(max_fov_deg=15.0, epoch_proper_motion_year=2025.0)
        db.save_to_file(db_path)
    names = sorted(f[:-4] for f in os.listdir(os.path.join(case, "fields")) if f.endswith(".csv"))
    priors = read_q(os.path.join(case, "prior.csv")) if track_csv else {}
    t3_lis, t3_track = Tally(), Tally()
    for name in names:
        # tetra3rs: origin at the image centre, +x right, +y down (ours: column, row from
        # the top-left pixel's centre), so the principal point moves to 0.
        pts = [tetra3rs.Centroid(float(r["x_px"]) - 511.5, float(r["y_px"]) - 511.5, float(r["flux_e"]))
               for r in csv.DictReader(open(os.path.join(case, "fields", name + ".csv")))]
        runs = [(t3_lis, {})]
        if track_csv:
            runs.append((t3_track, {"attitude_hint": list(priors[name]),
                                    "hint_uncertainty_deg": prior_deg, "strict_hint": True}))
        for tally, extra in runs:
            res = db.solve_from_centroids(pts, fov_estimate_deg=15.0, image_width=1024,
                                          image_height=1024, **extra)
            tally.t.append(res.solve_time_ms * 1000.0)
            if isinstance(res, tetra3rs.SolveResult) and bool(res):
                tally.add(tuple(float(c) for c in res.quaternion), truth[name])
    n = len(names)
    ours_db, t3_db = 584404, os.path.getsize(db_path)
    print(f"{n} fields from {case}")
    print("| solver, mode | solved | wrong | boresight RMS, arcsec | roll RMS, arcsec | median time per field | p99 time per field | database |")
    print("|---|---|---|---|---|---|---|---|")
    print(ours(lis_csv, truth).row("startrack, lost in space", n, ours_db))
    print(t3_lis.row("tetra3rs, lost in space", n, t3_db))
    if track_csv:
        print(ours(track_csv, truth).row(f"startrack, tracking (prior {prior_deg} deg off)", n, ours_db))
        print(t3_track.row(f"tetra3rs, tracking (prior {prior_deg} deg off)", n, t3_db))


if __name__ == "__main__":
    main()
