"""Decodes the tracker's telemetry with the PyPI `spacepackets` package (an independent PUS
implementation): every packet's CRC-16, APID, service and subtype, and the star list's and the
housekeeping's and the attitude report's fields against what the Rust side wrote.

Usage: python3 link_python.py PACKETS_FILE EXPECTED_JSON (written by the test link_python.rs).
Exit 0 and one line "spacepackets decoded N packets" on success."""
import json
import struct
import sys

from spacepackets.ecss.tm import PusTm


def main() -> int:
    packets = [bytes.fromhex(l) for l in open(sys.argv[1]).read().split()]
    expected = json.load(open(sys.argv[2]))
    assert len(packets) == len(expected), (len(packets), len(expected))
    for raw, want in zip(packets, expected):
        tm = PusTm.unpack(raw, timestamp_len=8)  # verifies the CRC-16
        got = (tm.apid, tm.service, tm.subservice)
        assert got == (want["apid"], want["service"], want["subtype"]), (got, want)
        assert struct.unpack(">Q", tm.timestamp)[0] == want["time_us"], want
        data = tm.source_data
        assert data.hex() == want["data"], want
        if "stars" in want:
            # Star list format 2: frame, mode, format, count, then 33 bytes a star.
            frame, mode, fmt, count = struct.unpack(">IBBB", data[:7])
            assert (frame, mode, fmt, count) == (want["frame"], want["mode"], 2, len(want["stars"]))
            for k, star in enumerate(want["stars"]):
                fields = struct.unpack(">6fIBHH", data[7 + 33 * k : 7 + 33 * (k + 1)])
                for a, b in zip(fields[:6], star[:6]):
                    assert abs(a - b) <= 1e-6 * max(1.0, abs(b)), (fields, star)
                # flags (quality) and provenance, apart.
                assert fields[6:8] == tuple(star[6:8]), (fields, star)
                # psf_a in 0.001 px, chi2_dof in 0.01, rounded.
                assert fields[8] == round(star[8] * 1000), (fields, star)
                assert fields[9] == round(star[9] * 100), (fields, star)
        if "attitude" in want:
            a = want["attitude"]
            # Format 2: frame, status, used, matched, format, flags, CUC T-field (coarse,
            # fine), time bound, latency, q, 6 covariances, rate, 6 rate covariances, false
            # probability, mid-exposure counter.
            fields = struct.unpack(">IBBBBHIHII4d6f3f6ffQ", data)
            head = (a["frame"], a["status"], a["used"], a["matched"], a["format"], a["flags"])
            assert fields[:6] == head, fields
            assert fields[6:10] == (a["coarse"], a["fine"], a["bound_us"], a["latency_us"]), fields
            assert list(fields[10:14]) == a["q"], fields
            assert abs(fields[19] - a["cov_zz"]) <= 1e-6 * a["cov_zz"], fields
            for got, w in zip(fields[20:23], a["w"]):
                assert abs(got - w) <= 1e-6 * abs(w), fields
            assert abs(fields[28] - a["rate_cov_zz"]) <= 1e-6 * a["rate_cov_zz"], fields
            assert fields[30] == a["time_us"], fields
        if "housekeeping" in want:
            sid, mode, next_mode = struct.unpack(">HBB", data[:4])
            assert (sid, mode, next_mode) == (1, want["mode"], want["next_mode"]), data[:4]
            # uptime_us: the u64 before setup_faults u16, dark_ratio u16, status u8,
            # defects_pending u16, hits u16, masked u16, obstructions u8, hits_total u32 and
            # masked_total u32 at the end.
            assert struct.unpack(">Q", data[-28:-20])[0] == want["time_us"]
            # dark_ratio, status, defects_pending: no dark law and no defects in this run.
            assert struct.unpack(">HBH", data[-18:-13]) == (0, 0, 0), data[-18:-13]
            # hits, masked, obstructions and their totals: no bright object, no proton.
            assert struct.unpack(">HHBII", data[-13:]) == (0, 0, 0, 0, 0), data[-13:]
    print(f"spacepackets decoded {len(packets)} packets")
    return 0


if __name__ == "__main__":
    sys.exit(main())
