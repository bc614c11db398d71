"""tetra3rs on the shared real night-sky frames, side by side with `startrack solve-image`.

Usage:
    python3 -m venv /tmp/t3 && /tmp/t3/bin/pip install tetra3rs==0.14.0
    /tmp/t3/bin/python host-tests/scripts/tetra3rs_realsky.py REALSKY_DIR SOLUTIONS_CSV OUT_CSV

REALSKY_DIR holds the FITS frames (BITPIX 16, BZERO 32768, ESA tetra3 test data, credit ESA /
Gustav Pettersson, CC BY-SA 3.0 IGO); SOLUTIONS_CSV is `solve-image`'s `solutions.csv` for
them. tetra3rs runs end to end on its own: its own centroid extraction (defaults), its own
database generated from the Gaia + Hipparcos catalog it ships (FOV 10 to 13 degrees), lost in
space with the horizontal field of view 11.4 degrees. Its pixel convention is this
project's (x = column - (width - 1) / 2, y = row - (height - 1) / 2, +y down), checked on a
synthetic star before the run. Roll is compared in tetra3's definition (`roll_tetra3_deg`
of `startrack`), computed here from tetra3rs's ICRS-to-camera rotation matrix `R`:
`atan2(-R[0][2], -R[1][2])`.

OUT_CSV: image, both solutions (ra_deg, dec_deg, roll_deg, fov_deg, matched, rmse_arcsec),
the boresight difference (arcsec, great circle) and the roll difference (arcsec, wrapped to
+-180 degrees).
"""

import csv
import math
import sys
from pathlib import Path

import numpy as np
import tetra3rs

FOV_DEG = 11.4


def read_fits_u16(path):
    """The primary image of a simple FITS file (BITPIX 16, BZERO 32768, NAXIS 2)."""
    raw = Path(path).read_bytes()
    head = {}
    off = 0
    while True:
        block = raw[off:off + 2880].decode("ascii")
        off += 2880
        for i in range(36):
            card = block[80 * i:80 * i + 80]
            key = card[:8].strip()
            if key == "END":
                break
            if card[8:10] == "= ":
                head[key] = card[10:].split("/")[0].strip()
        else:
            continue
        break
    w, h = int(head["NAXIS1"]), int(head["NAXIS2"])
    assert int(head["BITPIX"]) == 16
    bzero = float(head.get("BZERO", 0))
    data = np.frombuffer(raw[off:off + 2 * w * h], dtype=">i2").astype(np.float64) + bzero
    return data.reshape(h, w)


def check_convention():
    img = np.full((64, 96), 1000.0)
    yy, xx = np.mgrid[0:64, 0:96]
    img += 5e4 * np.exp(-((xx - 30.0) ** 2 + (yy - 20.0) ** 2) / (2 * 1.2 ** 2))
    c = tetra3rs.extract_centroids(img.astype(np.float32)).centroids[0]
    assert abs(c.x - (30.0 - 47.5)) < 0.01 and abs(c.y - (20.0 - 31.5)) < 0.01, (c.x, c.y)


def unit(ra_deg, dec_deg):
    ra, dec = math.radians(ra_deg), math.radians(dec_deg)
    return np.array([math.cos(dec) * math.cos(ra), math.cos(dec) * math.sin(ra), math.sin(dec)])


def main():
    sky_dir, ours_csv, out_csv = sys.argv[1:4]
    check_convention()
    ours = {r["image"]: r for r in csv.DictReader(open(ours_csv))}
    db = tetra3rs.SolverDatabase.generate_from_gaia(max_fov_deg=13.0, min_fov_deg=10.0)
    rows = []
    for path in sorted(Path(sky_dir).glob("*.fits")):
        img = read_fits_u16(path)
        ext = tetra3rs.extract_centroids(img.astype(np.float32))
        r = db.solve_from_centroids(
            ext.centroids, fov_estimate_deg=FOV_DEG, image_shape=img.shape, fov_max_error_deg=1.2
        )
        name = path.stem
        o = ours.get(name)
        row = {"image": name}
        if r and not r.parity_flip:
            rm = np.array(r.rotation_matrix_icrs_to_camera)
            roll = math.degrees(math.atan2(-rm[0][2], -rm[1][2])) % 360.0
            row.update(t3_solved=1, t3_ra_deg=f"{r.ra_deg:.6f}", t3_dec_deg=f"{r.dec_deg:.6f}",
                       t3_roll_deg=f"{roll:.6f}", t3_fov_deg=f"{r.fov_deg:.5f}",
                       t3_matched=r.num_matches, t3_rmse_arcsec=f"{r.rmse_arcsec:.2f}")
        else:
            row.update(t3_solved=0)
        if o and o["solved"] == "1":
            row.update(st_solved=1, st_ra_deg=o["ra_deg"], st_dec_deg=o["dec_deg"],
                       st_roll_deg=o["roll_deg"], st_fov_deg=o["fov_deg"],
                       st_matched=o["matched"], st_rmse_arcsec=o["rmse_arcsec"])
        else:
            row.update(st_solved=0)
        if row["t3_solved"] and row["st_solved"]:
            a = unit(float(row["t3_ra_deg"]), float(row["t3_dec_deg"]))
            b = unit(float(row["st_ra_deg"]), float(row["st_dec_deg"]))
            sep = math.degrees(math.atan2(np.linalg.norm(np.cross(a, b)), a @ b)) * 3600
            droll = (float(row["st_roll_deg"]) - float(row["t3_roll_deg"]) + 180) % 360 - 180
            row.update(boresight_diff_arcsec=f"{sep:.2f}", roll_diff_arcsec=f"{droll * 3600:.1f}")
        rows.append(row)
        print(row, flush=True)
    fields = ["image", "st_solved", "st_ra_deg", "st_dec_deg", "st_roll_deg", "st_fov_deg",
              "st_matched", "st_rmse_arcsec", "t3_solved", "t3_ra_deg", "t3_dec_deg",
              "t3_roll_deg", "t3_fov_deg", "t3_matched", "t3_rmse_arcsec",
              "boresight_diff_arcsec", "roll_diff_arcsec"]
    write_csv(out_csv, "ESA tetra3 test data (github.com/esa/tetra3 test_data), credit ESA / "
              "Gustav Pettersson, CC BY-SA 3.0 IGO; tetra3rs " + tetra3rs.__version__ + "; "
              "host-tests/scripts/tetra3rs_realsky.py", fields, rows)


def write_csv(path, comment, fields, rows):
    """`rows` (dicts) under the header `fields`, after one `# comment` line."""
    with open(path, "w", newline="") as f:
        f.write("# " + comment + "\n")
        w = csv.DictWriter(f, fieldnames=fields, lineterminator="\n")
        w.writeheader()
        for row in rows:
            w.writerow(row)


if __name__ == "__main__":
    main()
