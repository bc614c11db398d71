#!/usr/bin/env python3
"""tetra3rs and `startrack solve` lost in space on the same fields, with the focal length
told wrong and in sparse fields; writes the CSV docs/attitude.md's table is checked against.

    python3 -m venv /tmp/t3 && /tmp/t3/bin/pip install tetra3rs==0.14.0
    cargo build --release -p startrack-host --bin startrack
    /tmp/t3/bin/python host-tests/scripts/tetra3rs_scale_sparse.py target/release/startrack \
        /tmp/t3case host-tests/data/ident-tetra3rs.csv --fields 1000 --seed 23

One case of fields (`startrack catalog case`: 0.3 px, 10 % of the stars dropped, 3 false
stars, random attitudes) is solved four ways: as written; with `case.json`'s focal length
1 % long and 2 % short (both solvers are told the wrong focal length: tetra3rs through
`fov_estimate_deg`, from the same focal length); and sparse, each field cut to the stars
at least as bright as Hp 5.5 in observed flux (false stars included). tetra3rs uses its own
database for a 15 degree field, generated from the Gaia + Hipparcos catalog it ships
(cached in the work folder); its centroids are relative to the image centre. A solution is
wrong when its attitude is more than 0.1 degree from the truth; the boresight RMS error is
over the right solutions.
"""
import argparse
import csv
import json
import math
import os
import shutil
import subprocess

import tetra3rs

# Electrons of an Hp = 0 star in the written fields (startrack_sim::sky::field::FLUX_E_AT_MAG0).
FLUX_E_AT_MAG0 = 2.0e6


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


class Tally:
    def __init__(self):
        self.solved, self.wrong, self.bore2 = 0, 0, []

    def add(self, q, truth):
        self.solved += 1
        e = error_vector(q, truth)
        if math.sqrt(sum(c * c for c in e)) > math.radians(0.1):
            self.wrong += 1
        else:
            self.bore2.append(e[0] ** 2 + e[1] ** 2)

    def rms_arcsec(self):
        return math.sqrt(sum(self.bore2) / len(self.bore2)) * 206264.806 if self.bore2 else float("nan")


def read_q(path):
    return {r["field"]: tuple(float(r[k]) for k in ("qw", "qx", "qy", "qz"))
            for r in csv.DictReader(open(path))}


def make_case(src, dst, focal_scale=1.0, mag_limit=None):
    """A copy of case `src` with its focal length times `focal_scale` and its fields cut at
    `mag_limit`."""
    if os.path.exists(dst):
        shutil.rmtree(dst)
    os.makedirs(os.path.join(dst, "fields"))
    shutil.copy(os.path.join(src, "truth.csv"), dst)
    case = json.load(open(os.path.join(src, "case.json")))
    case["focal_length_px"] *= focal_scale
    json.dump(case, open(os.path.join(dst, "case.json"), "w"))
    min_flux = FLUX_E_AT_MAG0 * 10 ** (-0.4 * mag_limit) if mag_limit is not None else 0.0
    for name in os.listdir(os.path.join(src, "fields")):
        rows = list(csv.reader(open(os.path.join(src, "fields", name))))
        with open(os.path.join(dst, "fields", name), "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(rows[0])
            for r in rows[1:]:
                if float(r[2]) >= min_flux:
                    w.writerow(r)


def run_ours(startrack, case, truth):
    out = os.path.join(case, "ours.csv")
    subprocess.run([startrack, "solve", "--case", case, "--out", out], check=True,
                   stdout=subprocess.DEVNULL)
    t = Tally()
    for r in csv.DictReader(open(out)):
        if r["solved"] == "1":
            t.add(tuple(float(r[k]) for k in ("qw", "qx", "qy", "qz")), truth[r["field"]])
    return t


def run_tetra3rs(db, case, truth):
    focal = json.load(open(os.path.join(case, "case.json")))["focal_length_px"]
    fov_deg = math.degrees(2 * math.atan(512.0 / focal))
    t = Tally()
    for name in sorted(f[:-4] for f in os.listdir(os.path.join(case, "fields")) if f.endswith(".csv")):
        pts = [tetra3rs.Centroid(float(r["x_px"]) - 511.5, float(r["y_px"]) - 511.5, float(r["flux_e"]))
               for r in csv.DictReader(open(os.path.join(case, "fields", name + ".csv")))]
        if len(pts) < 3:
            continue
        res = db.solve_from_centroids(pts, fov_estimate_deg=fov_deg, image_width=1024, image_height=1024)
        if isinstance(res, tetra3rs.SolveResult) and bool(res):
            t.add(tuple(float(c) for c in res.quaternion), truth[name])
    return t


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("startrack")
    ap.add_argument("work")
    ap.add_argument("out_csv")
    ap.add_argument("--fields", type=int, default=1000)
    ap.add_argument("--seed", type=int, default=23)
    a = ap.parse_args()
    base = os.path.join(a.work, "nominal")
    os.makedirs(a.work, exist_ok=True)
    subprocess.run([a.startrack, "catalog", "case", "--out", base, "--fields", str(a.fields),
                    "--seed", str(a.seed)], check=True, stdout=subprocess.DEVNULL)
    truth = read_q(os.path.join(base, "truth.csv"))
    db_path = os.path.join(a.work, "tetra3rs-15deg.db")
    if os.path.exists(db_path):
        db = tetra3rs.SolverDatabase.load_from_file(db_path)
    else:
        db = tetra3rs.SolverDatabase.generate_from_gaia(max_fov_deg=15.0, epoch_proper_motion_year=2025.0)
        db.save_to_file(db_path)
    cases = [("nominal", 1.0, None), ("focal_plus_1pct", 1.01, None),
             ("focal_minus_2pct", 0.98, None), ("sparse_hp5.5", 1.0, 5.5)]
    rows = []
    for name, scale, mag in cases:
        case = os.path.join(a.work, name)
        if name != "nominal":
            make_case(base, case, scale, mag)
        for solver, run in (("startrack", lambda c: run_ours(a.startrack, c, truth)),
                            ("tetra3rs", lambda c: run_tetra3rs(db, c, truth))):
            t = run(case)
            rows.append((name, solver, a.fields, t.solved, t.wrong, t.rms_arcsec()))
            print(f"{name:18} {solver:10} {t.solved}/{a.fields} solved, {t.wrong} wrong, "
                  f"boresight RMS {t.rms_arcsec():.2f} arcsec", flush=True)
    with open(a.out_csv, "w", newline="") as f:
        f.write(f"# host-tests/scripts/tetra3rs_scale_sparse.py, {a.fields} fields, seed {a.seed}, tetra3rs 0.14.0\n")
        w = csv.writer(f)
        w.writerow(["case", "solver", "fields", "solved", "wrong", "boresight_rms_arcsec"])
        for r in rows:
            w.writerow([r[0], r[1], r[2], r[3], r[4], f"{r[5]:.2f}"])


if __name__ == "__main__":
    main()
