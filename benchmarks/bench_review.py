"""Benchmark: ``warpbridge review`` on a long flight: read and join time per minute of flight, and the
alignment error of the join.

The long flight is the real ArduPlane SITL flight of tests/data stitched end to end ``--copies`` times
(each copy's DataFlash time stamps, and the cycle log's ``t`` and ``fc_t``, moved on by the flight's
length), so that it holds what the real one holds, message for message, for about ten minutes.

Times (medians of ``--repeats`` runs): reading the DataFlash log with our reader (pymavlink's DFReader,
asking only for the message types the review uses), against the baseline a user would write first, a
plain pass of pymavlink over every message (``recv_match()`` without a type, as ``mavlogdump`` reads);
reading the cycle log; joining; the analysis; the HTML report. Target: under 30 s for a
10-minute flight, all of it.

The real PX4 SIH flight of tests/data (``.ulg`` and cycle log) is timed the same way, its baseline being
pyulog reading every topic of the file (``ULog(path)``) against our reader asking for the topics the
review uses.

Alignment error: the join's residual (the cross-correlation's lag of the bridge's setpoint behind the
FC's aileron output, less the lag the stamps predict) on the real and the stitched flight; and on the
synthetic flight of tests/review_synth.py, whose true clock offset is known, the error of each method
(the stamps, and cross-correlation alone for a cycle log without them).

Run: python benchmarks/bench_review.py [--copies 14] [--repeats 3]
"""

from __future__ import annotations

import argparse
import csv
import struct
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from _common import median_time, table  # noqa: E402

DATA = Path(__file__).resolve().parents[1] / "tests" / "data"


def cycle_span(path: Path) -> float:
    with path.open() as fh:
        rows = list(csv.reader(fh))
    i = rows[0].index("t")
    return float(rows[-1][i]) - float(rows[1][i])


def stitch_bin(src: Path, dst: Path, copies: int, at_least_s: float) -> tuple[float, float]:
    """``copies`` copies of a DataFlash log end to end (the last, cut short, message of each dropped), each
    copy's TimeUS moved on by the shift (the log's span, or ``at_least_s``); (stitched span, shift) in s."""
    from pymavlink import DFReader

    df = DFReader.DFReader_binary(str(src))
    pos, end = [], 0  # byte offsets of every TimeUS field (a Q first field named TimeUS); end of the last message
    for mtype, fmt in df.formats.items():
        offs = [o for o in df.offsets[mtype][: df.counts[mtype]] if o + fmt.len <= df.data_len]  # whole ones
        if len(offs):
            end = max(end, int(offs[-1]) + fmt.len)
        if fmt.columns and fmt.columns[0] == "TimeUS" and fmt.format.startswith("Q"):
            pos.extend(o + 3 for o in offs)
    raw = bytearray(src.read_bytes()[:end])
    pos = np.array(sorted(p for p in pos if p + 8 <= end), dtype=np.int64)
    stamps = np.array([struct.unpack_from("<Q", raw, p)[0] for p in pos], dtype=np.int64)
    live = stamps[stamps > 0]
    span_us = max(int(live.max() - live.min()), int(at_least_s * 1e6)) + 1_000_000
    with dst.open("wb") as f:
        for k in range(copies):
            out = bytearray(raw)
            shifted = np.where(stamps > 0, stamps + k * span_us, 0)
            for p, v in zip(pos.tolist(), shifted.tolist(), strict=True):
                struct.pack_into("<Q", out, p, v)
            f.write(out)
    return copies * span_us * 1e-6, span_us * 1e-6


def stitch_cycles(src: Path, dst: Path, copies: int, span_s: float) -> None:
    with src.open() as fh:
        rows = list(csv.reader(fh))
    head, body = rows[0], rows[1:]
    it, ifc = head.index("t"), head.index("fc_t")
    with dst.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(head)
        for k in range(copies):
            for r in body:
                r = list(r)
                r[it] = f"{float(r[it]) + k * span_s:.6f}"
                if r[ifc] != "nan":
                    r[ifc] = f"{float(r[ifc]) + k * span_s:.6f}"
                w.writerow(r)


def plain_pass(path: Path) -> int:
    """The baseline: every message of the log through pymavlink, as mavlogdump reads it."""
    from pymavlink import mavutil

    m = mavutil.mavlink_connection(str(path))
    n = 0
    while m.recv_match() is not None:
        n += 1
    return n


def review_times(label: str, log: Path, cycles: Path, baseline, repeats: int, d: Path) -> tuple[list, list]:
    """One row of the timing table and one of the alignment table for a flight controller log and its cycle log."""
    from warpbridge.bridge.commands.fclog import read_fc_log
    from warpbridge.bridge.commands.logjoin import align, read_cycle_log
    from warpbridge.bridge.commands.review import review
    from warpbridge.bridge.commands.review_plots import write_html

    t_plain, _ = median_time(lambda: baseline(log), repeats=repeats, warmup=0)
    t_read, _ = median_time(lambda: read_fc_log(log), repeats=repeats, warmup=0)
    t_cyc, _ = median_time(lambda: read_cycle_log(cycles), repeats=repeats, warmup=0)
    fc, cl = read_fc_log(log), read_cycle_log(cycles)
    t_join, _ = median_time(lambda: align(cl, fc), repeats=repeats, warmup=0)
    t_an, _ = median_time(lambda: review(fc, cl), repeats=repeats, warmup=0)
    rv, fl, al = review(fc, cl)
    t0 = time.perf_counter()
    write_html(d / "r.html", rv, fl, fc, cl, al)
    t_html = time.perf_counter() - t0
    total = t_read + t_cyc + t_an + t_html
    f0, f1 = fc.span
    minutes = (f1 - f0) / 60.0
    row = [label, f"{f1 - f0:.0f}", f"{log.stat().st_size / 1e6:.1f}", f"{t_plain:.2f}", f"{t_read:.2f}",
           f"{t_plain / t_read:.1f}", f"{t_cyc:.2f}", f"{t_join:.3f}", f"{t_an:.2f}", f"{t_html:.2f}", f"{total:.1f}",
           f"{(t_read + t_cyc + t_join) / minutes:.2f}"]
    return row, [label, al.method, f"{al.offset_s:.4f}", "-", "-", f"{al.residual_s * 1e3:+.2f}",
                 f"{al.telemetry_lag_s * 1e3:+.1f}"]


def pyulog_pass(path: Path) -> int:
    """The baseline for a .ulg: pyulog reading every topic."""
    from pyulog import ULog

    return len(ULog(str(path)).data_list)


def synthetic_alignment_errors() -> list[list[object]]:
    import review_synth as rs

    from warpbridge.bridge.commands.logjoin import align, read_cycle_log

    rows = []
    with tempfile.TemporaryDirectory() as d:
        for seed in range(3):
            fc, cycle = rs.flight(duration=120.0, seed=seed)
            for stamps in (True, False):
                cl = read_cycle_log(rs.write_cycle_log(Path(d) / f"c{seed}{stamps}.csv", cycle, with_fc_t=stamps))
                al = align(cl, fc)
                # the true clock offset; the stamps cannot see the shortest transit (it lands in the offset),
                # cross-correlation folds in the mean age of the message a cycle uses
                truth = rs.OFFSET_S
                rows.append([f"synthetic seed {seed}", al.method, f"{al.offset_s:.4f}", f"{truth:.4f}",
                             f"{(al.offset_s - truth) * 1e3:+.2f}", f"{al.residual_s * 1e3:+.2f}", "-"])
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bin", default=str(DATA / "arduplane-flight.BIN"))
    ap.add_argument("--cycles", default=str(DATA / "arduplane-flight-cycles.csv"))
    ap.add_argument("--ulg", default=str(DATA / "px4-flight.ulg"))
    ap.add_argument("--ulg-cycles", default=str(DATA / "px4-flight-cycles.csv"))
    ap.add_argument("--copies", type=int, default=14, help="stitched copies of the flight (default 14)")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()

    rows, align_rows = [], []
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        for label, copies in (("ArduPlane flight", 1), (f"ArduPlane x{args.copies}", args.copies)):
            b, c = d / f"f{copies}.BIN", d / f"f{copies}.csv"
            _, one_s = stitch_bin(Path(args.bin), b, copies, cycle_span(Path(args.cycles)))
            stitch_cycles(Path(args.cycles), c, copies, one_s)
            row, arow = review_times(label, b, c, plain_pass, args.repeats, d)
            rows.append(row)
            align_rows.append(arow)
        row, arow = review_times("PX4 SIH flight", Path(args.ulg), Path(args.ulg_cycles), pyulog_pass, args.repeats, d)
        rows.append(row)
        align_rows.append(arow)
    print("Review of a flight (medians; s unless said; baseline: a plain pymavlink pass, or pyulog of every topic)")
    print(table(rows, ["flight", "flight s", "log MB", "baseline read", "our read", "x faster", "read cycles",
                       "join", "analysis", "html", "total", "read+join per min"]))
    print()
    align_rows += synthetic_alignment_errors()
    print("Alignment (offset: FC time = cycle t + offset; error against the known truth where there is one;")
    print("L_sp lag: the FC's logged L_sp behind the cycle log's, never negative when the offset is right)")
    print(table(align_rows, ["flight", "method", "offset s", "truth s", "error ms", "residual ms", "L_sp lag ms"]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
