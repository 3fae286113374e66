"""Two runs of the blind diagnosis benchmark on the same cases: another code's results against this code's.

    python benchmarks/blind_compare.py --against SOURCES [--sources SOURCES] [--seed 0,1] [--family F,...]
                                       [--cache DIR]

SOURCES names a results folder of ``bench_diagnose_blind.py``'s cache: the source hash it is named by (12 hex
digits, as ``--report-only`` prints it under "computed on this code's sources") or the folder itself.
``--sources`` defaults to this code's. Both runs are scored the same way (each family held out, its decision
chosen on the other families of the same run), beside the shipped default decision and the count of correct
decisions over the whole decision grid (the finest measure: a change that moves no verdict under the default
can still move dozens of decisions); then every case whose verdict changed and every case whose count of
correct decisions moved. Run the benchmark on both codes first (a change to the diagnosis changes the hash,
so the old code's results stay in their own folder).
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import blind_lofo  # noqa: E402
from bench_diagnose_blind import (  # noqa: E402
    DIAG_SOURCES,
    FAMILIES,
    MAGNITUDE,
    cached_results,
    case_list,
    default_cache,
    results_dir,
    source_hash,
)


def folder(spec: str, cache: Path, magnitude: tuple[float, float] = MAGNITUDE) -> Path:
    """The results folder ``spec`` names: a folder, or the source hash of one at the benchmark's own sizes (or at
    the effect sizes ``magnitude``)."""
    p = Path(spec).expanduser()
    if p.is_dir():
        return p
    if not re.fullmatch(r"[0-9a-f]{12}", spec):
        sys.exit(f"{spec!r} is neither a results folder nor a 12-digit source hash")
    here = results_dir(cache, magnitude=magnitude)
    p = here.with_name(here.name.replace(source_hash(DIAG_SOURCES), spec))
    if not p.is_dir():
        known = sorted(d.name for d in here.parent.iterdir()) if here.parent.is_dir() else []
        sys.exit(f"no results of sources {spec} under {here.parent} (there: {', '.join(known) or 'none'})")
    return p


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--against", required=True, help="the other run: a source hash or a results folder")
    ap.add_argument("--sources", default="", help="this run (default: this code's sources)")
    ap.add_argument("--seed", default="0,1", help="seeds (default 0,1)")
    ap.add_argument("--family", default=",".join(FAMILIES), help="families (default: all)")
    ap.add_argument("--cache", type=Path, default=default_cache(), help="the benchmark's cache folder")
    args = ap.parse_args()
    families = [f.strip() for f in args.family.split(",") if f.strip()]
    bad = [f for f in families if f not in FAMILIES]
    if bad:
        sys.exit(f"unknown family {', '.join(bad)} (known: {', '.join(FAMILIES)})")
    try:
        seeds = [int(s) for s in args.seed.split(",") if s.strip()]
    except ValueError:
        sys.exit(f"--seed takes integers separated by commas (got {args.seed!r})")
    shape = argparse.Namespace(plants=3, pairs=3, nones=2, singles_only=False)
    cases = case_list(seeds, families, shape)
    old_dir = folder(args.against, args.cache)
    new_dir = folder(args.sources, args.cache) if args.sources else results_dir(args.cache)
    before, _ = cached_results(cases, old_dir)
    after, missing = cached_results(cases, new_dir)
    if not before or not after:
        sys.exit(f"no cached results of seeds {args.seed} in {old_dir if not before else new_dir}")
    default = after[0]["default_decision"]
    if any(default not in r["by_decision"] for r in before):
        sys.exit(f"the other run has no verdicts under this code's default decision {default}: not comparable")
    if before[0]["default_decision"] != default:
        print(f"note: the shipped default decision differs ({before[0]['default_decision']} before); both runs are "
              f"scored under this code's ({default})")
    print(f"blind benchmark, seeds {args.seed}, {len(cases)} cases drawn: {old_dir.name} ({len(before)} cached) "
          f"against {new_dir.name} ({len(after)} cached)\n")
    print(blind_lofo.comparison_table(before, after, default, old_dir.name.rsplit("-", 1)[-1],
                                      new_dir.name.rsplit("-", 1)[-1]))


if __name__ == "__main__":
    main()
