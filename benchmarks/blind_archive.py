"""The blind benchmark's results kept with the code: one compressed file per results folder, in the repository.

    python benchmarks/blind_archive.py pack [--sources SOURCES] [--seed 0,1] [--plants 3] [--singles-only]
                                            [--magnitude 2.5,15] [--rate 500] [--duration 60]
                                            [--partial]
                                            [--cache DIR]
    python benchmarks/blind_archive.py unpack [--cache DIR]
    python benchmarks/blind_archive.py list

``bench_diagnose_blind.py`` keeps each case's result in a cache folder named by its settings and the hash of
the diagnosis's sources. A cache does not travel with a checkout, and computing seeds 0-1 again takes hours;
so the results docs/results.md's tables come from are kept in ``benchmarks/results/`` (about 400 kB for seeds 0-1's
468 cases, compressed). ``pack`` writes the cached folder of ``--sources`` (default: this code's) to
``benchmarks/results/<folder>.jsonl.gz``, every case of ``--seed`` required (a probe run of the
benchmark's ``--plants``, ``--singles-only``, ``--magnitude``, ``--rate`` and ``--duration`` is packed with
the same options), or with ``--partial`` the cases there are, for a run longer than a session: the next one
unpacks and the run goes on where it stopped. Packing keeps every case the archive already holds (a cached
result replaces its archived one). It also adds the bench models of the packed plants to
``benchmarks/results/bench-models.jsonl.gz`` (3 kB each; identifying seeds 0-1's 36 plants again took 658 s
on one core).
``unpack`` puts every archived result and bench model in the cache where there is none, so that
``--report-only`` and ``blind_compare.py --against SOURCES`` work without the run, and says where a cached
result differs from the archived one in a verdict (a reproducibility check after a run of the same code). The
archive is the benchmark's output, not an input of it: a run never reads it, and computes every case it has no
cached result for (a bench model is found by its bench log's key, which names the identification's sources,
so an unpacked one is only used by the code that identified it). Keep the archives docs/results.md cites; git
keeps the older ones.
"""

from __future__ import annotations

import argparse
import gzip
import json
import re
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from bench_diagnose_blind import (  # noqa: E402
    DIAG_SOURCES,
    FAMILIES,
    FIELD_S,
    MAGNITUDE,
    NONES,
    PAIRS,
    PLANTS,
    RATE,
    case_list,
    default_cache,
    results_dir,
    source_hash,
)
from blind_compare import folder  # noqa: E402

ARCHIVE = HERE / "results"
SUFFIX = ".jsonl.gz"
MODELS = ARCHIVE / f"bench-models{SUFFIX}"  # the bench models the results were diagnosed with
MODEL_FILE = re.compile(r"^(.+-s\d+-\d+)-[0-9a-f]{16}\.json$")


def pack(res_dir: Path, cases: list[tuple], out_dir: Path = ARCHIVE,
         partial: bool = False) -> tuple[Path, int, int]:
    """Write every case of ``cases`` from ``res_dir`` to ``out_dir/<res_dir's name>.jsonl.gz`` (one JSON line
    per case, sorted by file name, gzip without a time stamp: the same results give the same bytes); (the
    archive, the cases it holds, how many of ``cases`` it lacks). A case the cache lacks is taken from that
    archive when it already holds it (a cached result wins), so packing never drops an archived case. Every
    case must be there, unless ``partial`` (a run that goes on in a later session: at least one case)."""
    if not cases:
        raise ValueError("no cases asked for")
    out = out_dir / f"{res_dir.name}{SUFFIX}"
    archived = dict(read(out)) if out.is_file() else {}
    rows, missing = [], []
    for c in cases:
        name = case_file(c)
        f = res_dir / name
        if f.is_file():
            rows.append((name, json.loads(f.read_text())))
        elif name in archived:
            rows.append((name, archived[name]))
        else:
            missing.append(c)
    if (missing and not partial) or not rows:
        raise ValueError(f"{len(missing)} of {len(cases)} cases have no result in {res_dir} (the first: "
                         f"{'/'.join(map(str, missing[0][:4]))}); finish the run before packing it"
                         + ("" if rows else ", or run one case of it at least"))
    keep = {name for name, _ in rows}
    rows += [(name, r) for name, r in archived.items() if name not in keep]  # cases of other seeds it holds
    write_rows(out, sorted(rows))
    return out, len(rows), len(missing)


def case_file(case: tuple) -> str:
    """The result file of a case (family, seed, plant index, case number, ...)."""
    return f"{case[0]}-s{case[1]}-p{case[2]}-c{case[3]}.json"


def write_rows(out: Path, rows: list[tuple[str, dict | str]]) -> None:
    """(file name, content) rows as gzipped JSON lines with no time stamp, replacing ``out`` atomically."""
    out.parent.mkdir(parents=True, exist_ok=True)
    text = "".join(json.dumps({"file": name, "result": r}, sort_keys=True) + "\n" for name, r in rows)
    tmp = out.with_name(out.name + ".part")
    # the header names the archive, not the temporary file (so the same results give the same bytes)
    with open(tmp, "wb") as fh, gzip.GzipFile(out.name, "wb", 9, fh, mtime=0) as gz:
        gz.write(text.encode())
    tmp.replace(out)


def pack_models(models_dir: Path, plants: set[str], out: Path | None = None) -> tuple[Path, int]:
    """Add the cached bench models of ``plants`` (``<plant>-<key>.json``; the key names the bench log and the
    identification's sources) to the models archive, keeping what it holds; (the archive, models in it)."""
    out = out or MODELS
    have = dict(read(out)) if out.is_file() else {}
    for f in sorted(models_dir.glob("*.json")) if models_dir.is_dir() else []:
        m = MODEL_FILE.match(f.name)
        if m and m.group(1) in plants:
            have[f.name] = f.read_text()  # its bytes, as identify wrote them
    if have:
        write_rows(out, sorted(have.items()))
    return out, len(have)


def unpack_models(archive: Path, models_dir: Path) -> int:
    """Write the archived bench models the cache lacks; the count written (``identified_model`` then finds a
    plant's model by its bench log's key instead of identifying it again)."""
    models_dir.mkdir(parents=True, exist_ok=True)
    return sum(write_new(models_dir / name, model) for name, model in read(archive))


def write_new(f: Path, text: str) -> bool:
    """Write ``text`` to ``f`` (through a temporary file) unless ``f`` exists; whether it wrote."""
    if f.is_file():
        return False
    tmp = f.with_suffix(".part")
    tmp.write_text(text)
    tmp.replace(f)
    return True


def read(archive: Path) -> list[tuple[str, dict | str]]:
    """(file name, content) per archived row: a case's result, or a bench model's text."""
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
        if write_new(f, json.dumps(result)):
            written += 1
            continue
        kept += 1
        if verdicts(json.loads(f.read_text())) != verdicts(result):
            differ.append(name)
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
    ap.add_argument("--rate", type=float, default=RATE, help=f"pack: the run's --rate (default {RATE:g})")
    ap.add_argument("--duration", type=float, default=FIELD_S,
                    help=f"pack: the run's --duration (default {FIELD_S:g})")
    ap.add_argument("--partial", action="store_true", help="pack: the cases there are (a run that a later session "
                                                           "goes on with after unpack)")
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
        res_dir = results_dir(a.cache, a.duration, a.rate, magnitude=sizes)
        if re.fullmatch(r"[0-9a-f]{12}", a.sources):  # the folder of those sources at these settings
            res_dir = res_dir.with_name(res_dir.name.replace(source_hash(DIAG_SOURCES), a.sources))
        elif a.sources:
            res_dir = folder(a.sources, a.cache, sizes)
        cases = case_list(seeds, list(FAMILIES), shape)
        try:
            out, held, lacking = pack(res_dir, cases, ARCHIVE, a.partial)
        except ValueError as e:
            sys.exit(str(e))
        print(f"{out.relative_to(HERE.parent)}: {held} cases, {out.stat().st_size / 1e3:.0f} kB"
              + (f"; partial: {len(cases) - lacking} of the {len(cases)} cases of seeds {a.seed}" if lacking else ""))
        plants = {f"{c[0]}-s{c[1]}-{c[2]}" for c in cases}
        m_out, n_models = pack_models(a.cache / "models", plants, MODELS)
        if n_models:
            print(f"{m_out.relative_to(HERE.parent)}: {n_models} bench models")
        return 0
    archives = sorted(x for x in ARCHIVE.glob(f"*{SUFFIX}") if x != MODELS)
    if not archives:
        print(f"no archives in {ARCHIVE.relative_to(HERE.parent)}")
        return 0
    bad = 0
    for arc in archives:
        if a.what == "list":
            rows = read(arc)
            seeds = sorted({r["seed"] for _, r in rows})
            print(f"{arc.name}: {len(rows)} cases, " + ", ".join(
                f"seed {s} {sum(r['seed'] == s for _, r in rows)}" for s in seeds))
            continue
        written, kept, differ = unpack(arc, a.cache / "results")
        print(f"{arc.name}: {written} written to the cache, {kept} already there"
              + (f", {len(differ)} of them with other verdicts: {', '.join(differ[:10])}" if differ else ""))
        bad += len(differ)
    if MODELS.is_file():
        if a.what == "list":
            print(f"{MODELS.name}: {len(read(MODELS))} bench models")
        else:
            print(f"{MODELS.name}: {unpack_models(MODELS, a.cache / 'models')} bench models written to the cache")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
