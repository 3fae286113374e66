"""The blind benchmark's results kept with the code: one compressed file per results folder, in the repository.

    python benchmarks/blind_archive.py pack [--sources SOURCES] [--seed 0,1] [--plants 3] [--singles-only]
                                            [--magnitude 2.5,15] [--cache DIR]
    python benchmarks/blind_archive.py unpack [--cache DIR]
    python benchmarks/blind_archive.py list

``bench_diagnose_blind.py`` keeps each case's result in a cache folder named by its settings and the hash of
the diagnosis's sources. A cache does not travel with a checkout, and computing seeds 0-1 again takes hours;
so the results the README's tables come from are kept in ``benchmarks/results/`` (about 400 kB for seeds 0-1's
468 cases, compressed). ``pack`` writes the cached folder of ``--sources`` (default: this code's) to
``benchmarks/results/<folder>.jsonl.gz``, every case of ``--seed`` required (a partial run is refused; a probe
run of the benchmark's ``--plants``, ``--singles-only`` and ``--magnitude`` is packed with the same options);
``unpack`` puts every archived result in the cache where that case has none, so that ``--report-only`` and
``blind_compare.py --against SOURCES`` work without the run, and says where a cached result differs from the
archived one in a verdict (a reproducibility check after a run of the same code). The archive is the
benchmark's output, not an input of it: a run never reads it, and computes every case it has no cached
result for. Keep the archives the README cites; git keeps the older ones.
"""

from __future__ import annotations

import argparse
import gzip
import json
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from bench_diagnose_blind import (  # noqa: E402
    FAMILIES,
    MAGNITUDE,
    NONES,
    PAIRS,
    PLANTS,
    cached_results,
    case_list,
    default_cache,
    results_dir,
)
from blind_compare import folder  # noqa: E402

ARCHIVE = HERE / "results"
SUFFIX = ".jsonl.gz"


def pack(res_dir: Path, cases: list[tuple], out_dir: Path = ARCHIVE) -> Path:
    """Write every case of ``cases`` from ``res_dir`` to ``out_dir/<res_dir's name>.jsonl.gz`` (one JSON line
    per case, sorted by file name, gzip without a time stamp: the same results give the same bytes)."""
    results, missing = cached_results(cases, res_dir)
    if missing:
        raise ValueError(f"{len(missing)} of {len(cases)} cases have no result in {res_dir} (the first: "
                         f"{'/'.join(map(str, missing[0][:4]))}); finish the run before packing it")
    rows = sorted((f"{c[0]}-s{c[1]}-p{c[2]}-c{c[3]}.json", r) for c, r in zip(cases, results, strict=True))
    out_dir.mkdir(parents=True, exist_ok=True)
    out = out_dir / f"{res_dir.name}{SUFFIX}"
    text = "".join(json.dumps({"file": name, "result": r}, sort_keys=True) + "\n" for name, r in rows)
    with open(out, "wb") as fh, gzip.GzipFile(fileobj=fh, mode="wb", compresslevel=9, mtime=0) as gz:
        gz.write(text.encode())
    return out


def read(archive: Path) -> list[tuple[str, dict]]:
    """(file name, result) per archived case."""
    with gzip.open(archive, "rt") as fh:
        rows = [json.loads(line) for line in fh if line.strip()]
    return [(row["file"], row["result"]) for row in rows]


def unpack(archive: Path, results_root: Path) -> tuple[int, int, list[str]]:
    """Put ``archive``'s results under ``results_root/<its folder>`` where a case has none; (written, already
    there, the cases already there whose verdict under any decision differs from the archived one)."""
    dest = results_root / archive.name[: -len(SUFFIX)]
    dest.mkdir(parents=True, exist_ok=True)
    written, kept, differ = 0, 0, []
    for name, result in read(archive):
        f = dest / name
        if f.is_file():
            kept += 1
            have = json.loads(f.read_text())
            if verdicts(have) != verdicts(result):
                differ.append(name)
            continue
        tmp = f.with_suffix(".part")
        tmp.write_text(json.dumps(result))
        tmp.replace(f)
        written += 1
    return written, kept, differ


def verdicts(result: dict) -> tuple:
    """The verdict under the shipped default and under every decision of the grid."""
    return (tuple(result["verdict"]),
            tuple(sorted((k, tuple(v["verdict"])) for k, v in result.get("by_decision", {}).items())))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("what", choices=("pack", "unpack", "list"))
    ap.add_argument("--sources", default="", help="pack: the results folder, or its 12-digit source hash "
                                                   "(default: this code's)")
    ap.add_argument("--seed", default="0,1", help="pack: the seeds whose every case must be there (default 0,1)")
    ap.add_argument("--plants", type=int, default=PLANTS, help=f"pack: plants per family and seed, as the run "
                                                               f"had (default {PLANTS})")
    ap.add_argument("--singles-only", action="store_true", help="pack: a run of the single-effect cases only")
    ap.add_argument("--magnitude", default="", help="pack: the run's --magnitude low,high (default: the "
                                                    "benchmark's own sizes)")
    ap.add_argument("--cache", type=Path, default=default_cache(), help="the benchmark's cache folder")
    a = ap.parse_args(argv)
    if a.what == "pack":
        seeds = [int(s) for s in a.seed.split(",") if s.strip()]
        shape = argparse.Namespace(plants=a.plants, pairs=PAIRS, nones=NONES, singles_only=a.singles_only)
        try:
            sizes = tuple(float(x) for x in a.magnitude.split(",")) if a.magnitude else MAGNITUDE
        except ValueError:
            sizes = ()
        if len(sizes) != 2:
            sys.exit(f"--magnitude takes two numbers, low,high (got {a.magnitude!r})")
        res_dir = folder(a.sources, a.cache, sizes) if a.sources else results_dir(a.cache, magnitude=sizes)
        try:
            out = pack(res_dir, case_list(seeds, list(FAMILIES), shape))
        except ValueError as e:
            sys.exit(str(e))
        print(f"{out.relative_to(HERE.parent)}: {len(read(out))} cases, {out.stat().st_size / 1e3:.0f} kB")
        return 0
    archives = sorted(ARCHIVE.glob(f"*{SUFFIX}"))
    if not archives:
        print(f"no archives in {ARCHIVE.relative_to(HERE.parent)}")
        return 0
    bad = 0
    for arc in archives:
        if a.what == "list":
            rows = read(arc)
            seeds = sorted({r["seed"] for _, r in rows})
            print(f"{arc.name}: {len(rows)} cases, seeds {','.join(map(str, seeds))}")
            continue
        written, kept, differ = unpack(arc, a.cache / "results")
        print(f"{arc.name}: {written} written to the cache, {kept} already there"
              + (f", {len(differ)} of them with other verdicts: {', '.join(differ[:10])}" if differ else ""))
        bad += len(differ)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
