#!/usr/bin/env python3
"""The peer of `startrack calib frames`: astropy ccdproc's master bias, dark and flat made
from the same lab frames, and both tools' errors against the simulator's truth.

    startrack calib lab-set --out LAB --truth-dir TRUTH
    startrack calib frames LAB --out table.bin --report-dir REPORT
    python3 host-tests/scripts/ccdproc_peer.py LAB TRUTH REPORT

ccdproc works the way its documentation shows: each frame's over-scan level subtracted
(per output, `subtract_overscan` with a median), `combine` of the biases (median), darks
and flats bias-subtracted (`subtract_bias`) and combined (`average`, the flats with sigma clipping).
ccdproc knows no covered columns, gains or temperature laws, so the steps it lacks are done
the same way for both tools here: each dark is converted with `calib frames`' gains and
scaled by its covered pixels' median (ccdproc's `scale`), and the flat is normalised per
output. Compared (active area, hot and telegraph pixels left out): column bias (ADU RMS),
relative dark (RMS), flat (RMS). Needs: pip install ccdproc (astropy, numpy).
"""

import json
import warnings
import resource
import sys
import time
from pathlib import Path

import numpy as np
from astropy.io import fits
from astropy.nddata import CCDData
import ccdproc

OVERSCAN, COVERED = 8, 16


def main(lab, truth, report):
    warnings.simplefilter("ignore")  # astropy's DATE-OBS -> MJD-OBS notes, one per frame
    t0 = time.process_time()
    rep = json.loads((Path(report) / "report.json").read_text())
    gains = rep["gain_e_per_adu"]
    frames = {"BIAS": [], "DARK": [], "FLAT": []}
    for p in sorted(Path(lab).glob("*.fits")):
        h = fits.getheader(p)
        frames[h["IMAGETYP"].strip()].append(p)
    first = fits.getdata(frames["BIAS"][0])
    lines, width = first.shape
    half = width // 2
    active = slice(OVERSCAN + COVERED, width - OVERSCAN - COVERED)
    covered = np.r_[OVERSCAN:OVERSCAN + COVERED, width - OVERSCAN - COVERED:width - OVERSCAN]

    def load(p):
        ccd = CCDData.read(p, unit="adu")
        data = ccd.data.astype(np.float64)
        # ccdproc's over-scan subtraction, one output (half line) at a time.
        left = ccdproc.subtract_overscan(CCDData(data[:, :half], unit="adu"),
                                         overscan=CCDData(data[:, :OVERSCAN], unit="adu"),
                                         overscan_axis=1, median=True)
        right = ccdproc.subtract_overscan(CCDData(data[:, half:], unit="adu"),
                                          overscan=CCDData(data[:, width - OVERSCAN:], unit="adu"),
                                          overscan_axis=1, median=True)
        return CCDData(np.hstack([left.data, right.data]), unit="adu", meta=ccd.header)

    bias = ccdproc.combine([load(p) for p in frames["BIAS"]], method="median")
    gain_row = np.where(np.arange(width) < half, gains[0], gains[1])

    def dark_e(p):
        d = ccdproc.subtract_bias(load(p), bias)
        return CCDData(d.data * gain_row, unit="electron")

    darks = [dark_e(p) for p in frames["DARK"]]
    scales = [1.0 / np.median(d.data[:, covered]) for d in darks]
    # Weighted by each dark's signal, no clipping: with sigma_clip=True (ccdproc's usual
    # recipe) darks of very different signal clip each other and the error grows fivefold.
    dark = ccdproc.combine(darks, method="average",
                           scale=scales, weights=np.array([1.0 / s for s in scales]))
    flats = [ccdproc.subtract_bias(load(p), bias) for p in frames["FLAT"]]
    fl = ccdproc.combine(flats, method="average", sigma_clip=True,
                         scale=[1.0 / np.median(f.data[:, active]) for f in flats])
    flat = fl.data[: fits.getdata(Path(truth) / "flat.fits").shape[0], active]
    cpu_s = time.process_time() - t0
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024

    t_flat = fits.getdata(Path(truth) / "flat.fits").astype(np.float64)
    t_dark = fits.getdata(Path(truth) / "dark_rel.fits").astype(np.float64)
    t_cb = fits.getdata(Path(truth) / "column_bias.fits").astype(np.float64)[0]
    defects = fits.getdata(Path(truth) / "defects.fits") > 0
    rows = t_flat.shape[0]
    good = ~defects[:rows, active]
    cols = t_flat.shape[1]
    halves = np.arange(cols) < cols // 2

    def per_output(m):
        m = m.copy()
        for side in (halves, ~halves):
            m[:, side] /= m[:, side][good[:, side]].mean()
        return m

    def rms(a, b):
        return float(np.sqrt(np.mean((a - b)[good] ** 2)))

    ours_flat = fits.getdata(Path(report) / "flat.fits").astype(np.float64)
    ours_dark = fits.getdata(Path(report) / "dark_rel.fits").astype(np.float64)
    ours_bias = fits.getdata(Path(report) / "master_bias.fits").astype(np.float64)

    def column_bias(master):
        lvl = np.where(np.arange(width) < half,
                       np.median(master[:, :OVERSCAN], axis=1)[:, None],
                       np.median(master[:, width - OVERSCAN:], axis=1)[:, None])
        return (master - lvl).mean(axis=0)[active]

    cb_ccdproc = bias.data.mean(axis=0)[active]  # over-scan already subtracted per line
    out = {
        "column_bias_rms_adu": {"calib_frames": float(np.sqrt(np.mean((column_bias(ours_bias) - t_cb[active]) ** 2))),
                                "ccdproc": float(np.sqrt(np.mean((cb_ccdproc - t_cb[active]) ** 2)))},
        "dark_rel_rms": {"calib_frames": rms(ours_dark[:rows, active], t_dark[:rows, active]),
                         "ccdproc": rms(dark.data[:rows, active], t_dark[:rows, active])},
        "flat_rms": {"calib_frames": rms(per_output(ours_flat), t_flat),
                     "ccdproc": rms(per_output(flat), t_flat)},
        "ccdproc_cpu_s": round(cpu_s, 1),
        "ccdproc_peak_mb": round(peak_mb),
    }
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    if len(sys.argv) != 4:
        sys.exit(__doc__)
    main(*sys.argv[1:])
