"""More real night-sky images, solved by `startrack solve-image`, tetra3rs and cedar-solve
(ESA tetra3's maintained fork) with the field of view told to 10 %.

Usage:
    python3 -m venv /tmp/t3 && /tmp/t3/bin/pip install tetra3rs==0.14.0 cedar-solve==0.5.1 pillow
    cargo build --release -p startrack-host --bin startrack
    /tmp/t3/bin/python host-tests/scripts/realsky_more.py target/release/startrack \
        host-tests/data/realsky-more.csv ROOT WORK host-tests/figures/realsky-more.csv

The images are not in the repository (their licences, docs/attitude.md): MANIFEST
(`host-tests/data/realsky-more.csv`) names each image as `set,image,fov_deg`, the path
relative to ROOT/<set>/ (a clone of the set's repository at the commit the doc gives) and the
nominal horizontal field of view. Every solver is told that field and that it is known to
10 %:

- `startrack solve-image IMAGES --fov-deg F --fov-max-error 0.1 --out WORK/<set>-<F>-<folder>`,
  one run per set, field and image folder, the images as they are;
- tetra3rs 0.14.0 end to end: its own centroids (defaults) on the image as luminance, its own
  database generated from the Gaia + Hipparcos catalog it ships for F -15 % to +15 %
  (cached in WORK), `fov_estimate_deg` F, `fov_max_error_deg` 0.1 F;
- tetra3rs from startrack's detections (`<stem>.detections.csv`, the 50 brightest, relative
  to the image centre), the same database and estimate: the same stars identified by an
  independent solver;
- cedar-solve 0.5.1 end to end: `tetra3.get_centroids_from_image` (defaults) on the image as
  luminance, the first 30 centroids, its default database (10 to 30 degree fields, Hp 8), the
  same estimate and error, a 20 s timeout; images whose field is outside its database are not
  run (empty).

startrack's WCS of each solved image (`<stem>.wcs`, read here: TAN, CD inverted) maps its
matched stars' catalog RA and Dec to their measured pixels within `st_wcs_rms_px` (RMS).
Roll is tetra3's definition in all three (startrack's `roll_tetra3_deg`; tetra3rs's from its
ICRS-to-camera matrix as in `tetra3rs_realsky.py`; cedar-solve's own `Roll`). OUT_CSV has per
image each solver's solution and startrack's boresight and roll differences from each
solver that solved it (arcsec).
"""

import csv
import math
import subprocess
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np
import tetra3rs
from PIL import Image
from tetra3rs_realsky import unit, write_csv  # this folder is on the path of a script run

SOLVERS = ("st", "t3rs", "t3st", "cs")
OTHERS = ("t3rs", "t3st", "cs")


def luminance(path):
    return np.asarray(Image.open(path).convert("L"), dtype=np.float32)


def sep_arcsec(a, b):
    return math.degrees(math.atan2(np.linalg.norm(np.cross(a, b)), a @ b)) * 3600


def out_dir(work, m):
    """startrack's output folder for the image of manifest row `m`: one per set, field and
    image folder (the default catalog is built per field; stems repeat across folders)."""
    folder = str(Path(m["image"]).parent).replace("/", "_")
    return work / f"{m['set']}-{m['fov_deg']}-{folder}"


def run_startrack(exe, manifest, root, work):
    """startrack's solutions.csv rows by (set, image), one run per output folder."""
    groups = defaultdict(list)
    for m in manifest:
        groups[(out_dir(work, m), m["fov_deg"])].append(m)
    out = {}
    for (d, fov), ms in groups.items():
        paths = [str(root / m["set"] / m["image"]) for m in ms]
        subprocess.run([exe, "solve-image", *paths, "--fov-deg", fov, "--fov-max-error", "0.1",
                        "--out", str(d)], check=False)
        rows = {r["image"]: r for r in csv.DictReader(open(d / "solutions.csv"))}
        for m in ms:
            out[(m["set"], m["image"])] = rows.get(Path(m["image"]).stem)
    return out


def fits_header(path):
    """The primary header's `KEY = value` cards of a FITS file, values as text."""
    raw = Path(path).read_bytes()
    head = {}
    for off in range(0, len(raw), 80):
        card = raw[off:off + 80].decode("ascii")
        if card[:8].strip() == "END":
            break
        if card[8:10] == "= ":
            head[card[:8].strip()] = card[10:].split("/")[0].strip().strip("'").strip()
    return head


def wcs_rms_px(wcs_path, stars_path):
    """RMS over the matched stars of the distance between the measured pixel and the catalog
    RA and Dec mapped through the TAN WCS (gnomonic, CD inverted), px; None without a
    plain TAN WCS."""
    h = fits_header(wcs_path)
    if h.get("CTYPE1") != "RA---TAN":
        return None
    crpix = float(h["CRPIX1"]), float(h["CRPIX2"])
    a0, d0 = math.radians(float(h["CRVAL1"])), math.radians(float(h["CRVAL2"]))
    cd = np.array([[float(h["CD1_1"]), float(h["CD1_2"])], [float(h["CD2_1"]), float(h["CD2_2"])]])
    inv = np.linalg.inv(cd)
    sum2, n = 0.0, 0
    for r in csv.DictReader(open(stars_path)):
        a, d = math.radians(float(r["ra_deg"])), math.radians(float(r["dec_deg"]))
        cosc = math.sin(d0) * math.sin(d) + math.cos(d0) * math.cos(d) * math.cos(a - a0)
        xi = math.degrees(math.cos(d) * math.sin(a - a0) / cosc)
        eta = math.degrees((math.cos(d0) * math.sin(d)
                            - math.sin(d0) * math.cos(d) * math.cos(a - a0)) / cosc)
        u, v = inv @ np.array([xi, eta])
        px, py = u + crpix[0] - 1.0, v + crpix[1] - 1.0
        sum2 += (px - float(r["x_px"])) ** 2 + (py - float(r["y_px"])) ** 2
        n += 1
    return math.sqrt(sum2 / n) if n else None


def tetra3rs_db(fov, work):
    path = work / f"tetra3rs-{fov:g}.bin"
    if path.exists():
        return tetra3rs.SolverDatabase.load_from_file(str(path))
    db = tetra3rs.SolverDatabase.generate_from_gaia(max_fov_deg=fov * 1.15, min_fov_deg=fov * 0.85)
    db.save_to_file(str(path))
    return db


def solve_tetra3rs(img, fov, work, centroids=None):
    db = tetra3rs_db(fov, work)
    if centroids is None:
        centroids = tetra3rs.extract_centroids(img).centroids
    r = db.solve_from_centroids(centroids, fov_estimate_deg=fov, image_shape=img.shape,
                                fov_max_error_deg=0.1 * fov)
    if not r or r.parity_flip:
        return None
    rm = np.array(r.rotation_matrix_icrs_to_camera)
    roll = math.degrees(math.atan2(-rm[0][2], -rm[1][2])) % 360.0
    return dict(ra=r.ra_deg, dec=r.dec_deg, roll=roll, fov=r.fov_deg, matched=r.num_matches,
                rmse=r.rmse_arcsec)


_T3 = None


def solve_cedar(img, fov):
    global _T3
    import tetra3
    if _T3 is None:
        _T3 = tetra3.Tetra3(load_database="default_database")
    p = _T3.database_properties
    if not (p["min_fov"] <= fov * 1.1 and fov * 0.9 <= p["max_fov"]):
        return "out"
    c = tetra3.get_centroids_from_image(img)
    if len(c) < 4:
        return None
    s = _T3.solve_from_centroids(c[:30], img.shape, fov_estimate=fov, fov_max_error=0.1 * fov,
                                 solve_timeout=20000, distortion=0)
    if s.get("RA") is None:
        return None
    return dict(ra=s["RA"], dec=s["Dec"], roll=s["Roll"] % 360.0, fov=s["FOV"],
                matched=s["Matches"], rmse=s["RMSE"])


def main():
    exe, manifest_path, root, work, out_csv = sys.argv[1:6]
    root, work = Path(root), Path(work)
    work.mkdir(parents=True, exist_ok=True)
    manifest = list(csv.DictReader(l for l in open(manifest_path) if not l.startswith("#")))
    ours = run_startrack(exe, manifest, root, work)
    rows = []
    for m in manifest:
        path = root / m["set"] / m["image"]
        fov = float(m["fov_deg"])
        img = luminance(path)
        row = {"set": m["set"], "image": m["image"], "nominal_fov_deg": m["fov_deg"]}
        sols = {}
        o = ours.get((m["set"], m["image"]))
        if o and o["solved"] == "1":
            sols["st"] = dict(ra=float(o["ra_deg"]), dec=float(o["dec_deg"]),
                              roll=float(o["roll_deg"]), fov=float(o["fov_deg"]),
                              matched=int(o["matched"]), rmse=float(o["rmse_arcsec"]))
        if "st" in sols:
            d = out_dir(work, m)
            rms = wcs_rms_px(d / f"{path.stem}.wcs", d / f"{path.stem}.stars.csv")
            row["st_wcs_rms_px"] = f"{rms:.3f}" if rms is not None else ""
        t = solve_tetra3rs(img, fov, work)
        if t:
            sols["t3rs"] = t
        # tetra3rs from startrack's own detections (brightest first, relative to the image
        # centre): the same stars identified independently.
        det = out_dir(work, m) / f"{path.stem}.detections.csv"
        if det.exists():
            h, w = img.shape
            xy = np.array([[float(d["x_px"]) - (w - 1) / 2, float(d["y_px"]) - (h - 1) / 2]
                           for d in csv.DictReader(open(det))]).reshape(-1, 2)
            t = solve_tetra3rs(img, fov, work, xy[:50]) if len(xy) >= 4 else None
            if t:
                sols["t3st"] = t
        c = solve_cedar(img, fov)
        row["cs_run"] = 0 if c == "out" else 1
        if isinstance(c, dict):
            sols["cs"] = c
        for k in SOLVERS:
            row[f"{k}_solved"] = int(k in sols)
            if k in sols:
                s = sols[k]
                row.update({f"{k}_ra_deg": f"{s['ra']:.6f}", f"{k}_dec_deg": f"{s['dec']:.6f}",
                            f"{k}_roll_deg": f"{s['roll']:.6f}", f"{k}_fov_deg": f"{s['fov']:.5f}",
                            f"{k}_matched": s["matched"], f"{k}_rmse_arcsec": f"{s['rmse']:.2f}"})
        if "st" in sols:
            a = unit(sols["st"]["ra"], sols["st"]["dec"])
            for k in OTHERS:
                if k in sols:
                    b = unit(sols[k]["ra"], sols[k]["dec"])
                    droll = (sols["st"]["roll"] - sols[k]["roll"] + 180) % 360 - 180
                    row[f"{k}_boresight_diff_arcsec"] = f"{sep_arcsec(a, b):.2f}"
                    row[f"{k}_roll_diff_arcsec"] = f"{droll * 3600:.1f}"
        rows.append(row)
        print(row, flush=True)
    fields = ["set", "image", "nominal_fov_deg"]
    for k in SOLVERS:
        if k == "cs":
            fields.append("cs_run")
        fields += [f"{k}_{f}" for f in ("solved", "ra_deg", "dec_deg", "roll_deg", "fov_deg",
                                         "matched", "rmse_arcsec")]
    fields.insert(fields.index("st_rmse_arcsec") + 1, "st_wcs_rms_px")
    for k in OTHERS:
        fields += [f"{k}_boresight_diff_arcsec", f"{k}_roll_diff_arcsec"]
    write_csv(out_csv, "host-tests/scripts/realsky_more.py over host-tests/data/realsky-more.csv; "
              "tetra3rs " + tetra3rs.__version__ + ", cedar-solve 0.5.1", fields, rows)


if __name__ == "__main__":
    main()
