"""The blind benchmark's results archive: packed whole and byte for byte the same, unpacked without overwriting."""

import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import blind_archive  # noqa: E402
from plants import EFFECTS  # noqa: E402

CASES = [("dahl", 0, 0, k, [], 0) for k in range(3)]


def result(k: int, verdict: list[str], grid: list[str] | None = None) -> dict:
    return {"family": "dahl", "seed": 0, "plant_index": 0, "case": k, "verdict": verdict, "sources": "abc",
            "by_decision": {"d1": {"verdict": verdict if grid is None else grid, "gap_closed": 0.9}}}


def folder(root: Path, name: str = "d60-r500-b40-0123456789ab") -> Path:
    d = root / name
    d.mkdir(parents=True)
    for k in range(3):
        (d / f"dahl-s0-p0-c{k}.json").write_text(json.dumps(result(k, ["drift"] if k else [])))
    return d


def test_a_packed_folder_unpacks_to_the_same_results(tmp_path):
    src = folder(tmp_path / "a")
    arc, held, lacking = blind_archive.pack(src, CASES, tmp_path / "archive")
    assert (held, lacking) == (3, 0)
    assert arc.name == f"{src.name}.jsonl.gz"
    written, kept, differ = blind_archive.unpack(arc, tmp_path / "b")
    assert (written, kept, differ) == (3, 0, [])
    for f in src.iterdir():
        assert json.loads((tmp_path / "b" / src.name / f.name).read_text()) == json.loads(f.read_text())


def test_the_same_results_pack_to_the_same_bytes(tmp_path):
    one = blind_archive.pack(folder(tmp_path / "a"), CASES, tmp_path / "x")[0].read_bytes()
    two = blind_archive.pack(folder(tmp_path / "b"), CASES, tmp_path / "y")[0].read_bytes()
    assert one == two
    again = blind_archive.pack(folder(tmp_path / "c"), CASES, tmp_path / "x")[0].read_bytes()  # over the first
    assert again == one
    # the gzip header names the archive itself (as the archives packed before did), not a temporary file
    assert one[3] & 0x08 and one[10:one.index(b"\0", 10)] == b"d60-r500-b40-0123456789ab.jsonl"


def test_a_run_with_cases_missing_is_not_packed(tmp_path):
    src = folder(tmp_path / "a")
    (src / "dahl-s0-p0-c1.json").unlink()
    with pytest.raises(ValueError, match="1 of 3 cases have no result"):
        blind_archive.pack(src, CASES, tmp_path / "archive")
    assert not (tmp_path / "archive").exists()


def test_unpack_keeps_the_cached_result_and_names_a_verdict_that_differs(tmp_path):
    src = folder(tmp_path / "a")
    arc, _, _ = blind_archive.pack(src, CASES, tmp_path / "archive")
    dest = tmp_path / "cache" / src.name
    dest.mkdir(parents=True)
    (dest / "dahl-s0-p0-c1.json").write_text(json.dumps(result(1, ["drift"], grid=["drift", "pretension"])))
    (dest / "dahl-s0-p0-c2.json").write_text(json.dumps(result(2, ["drift"])))
    written, kept, differ = blind_archive.unpack(arc, tmp_path / "cache")
    assert (written, kept, differ) == (1, 2, ["dahl-s0-p0-c1.json"])
    kept_result = json.loads((dest / "dahl-s0-p0-c1.json").read_text())
    assert kept_result["by_decision"]["d1"]["verdict"] == ["drift", "pretension"]  # not overwritten


def test_a_probe_run_packs_with_its_own_shape(tmp_path, monkeypatch):
    """``pack --plants 1 --singles-only --magnitude 15,45`` finds the probe's folder and asks for its cases only."""
    asked = {}
    real_pack = blind_archive.pack

    def recording_pack(res_dir, cases, out_dir, partial):
        asked["dir"], asked["cases"] = res_dir, cases
        return real_pack(folder(tmp_path / "src"), CASES, tmp_path / "results")

    monkeypatch.setattr(blind_archive, "pack", recording_pack)
    monkeypatch.setattr(blind_archive, "MODELS", tmp_path / "results" / "bench-models.jsonl.gz")
    monkeypatch.setattr(blind_archive, "HERE", tmp_path / "benchmarks")  # the printed path is relative to it
    assert blind_archive.main(["pack", "--seed", "9", "--plants", "1", "--singles-only", "--magnitude", "15,45",
                               "--cache", str(tmp_path / "cache")]) == 0
    assert "-m15-45-" in asked["dir"].name
    assert len(asked["cases"]) == len(blind_archive.FAMILIES) * len(EFFECTS)  # every single effect, one plant
    assert all(len(c[4]) == 1 and c[1] == 9 and c[2] == 0 for c in asked["cases"])


@pytest.mark.parametrize("sizes", ["15", "15,x", "1,2,3"])
def test_pack_refuses_a_magnitude_that_is_not_two_numbers(tmp_path, sizes):
    with pytest.raises(SystemExit, match="two numbers"):
        blind_archive.main(["pack", "--magnitude", sizes, "--cache", str(tmp_path)])


def test_a_partial_run_packs_what_is_there_and_a_later_pack_keeps_it(tmp_path):
    """``--partial``: the cases there are; the next pack (the run gone on elsewhere) loses none of them."""
    src = folder(tmp_path / "a")
    (src / "dahl-s0-p0-c1.json").unlink()
    (src / "dahl-s0-p0-c2.json").unlink()
    arc, held, lacking = blind_archive.pack(src, CASES, tmp_path / "archive", partial=True)
    assert (held, lacking) == (1, 2) and [n for n, _ in blind_archive.read(arc)] == ["dahl-s0-p0-c0.json"]
    later = folder(tmp_path / "b", src.name)  # another machine's cache: the run's other cases
    (later / "dahl-s0-p0-c0.json").unlink()
    arc2, held2, lacking2 = blind_archive.pack(later, CASES, tmp_path / "archive")
    assert arc2 == arc and (held2, lacking2) == (3, 0)  # complete now: c0 from the archive, c1-c2 from the cache
    assert [n for n, _ in blind_archive.read(arc)] == [f"dahl-s0-p0-c{k}.json" for k in range(3)]


def test_a_partial_pack_of_nothing_is_refused(tmp_path):
    src = folder(tmp_path / "a")
    for f in src.iterdir():
        f.unlink()
    with pytest.raises(ValueError, match="run one case of it at least"):
        blind_archive.pack(src, CASES, tmp_path / "archive", partial=True)


def test_bench_models_of_the_packed_plants_travel_byte_for_byte(tmp_path):
    models = tmp_path / "cache" / "models"
    models.mkdir(parents=True)
    texts = {"dahl-s0-0-0123456789abcdef.json": '{"a": 1}\n', "dahl-s1-0-fedcba9876543210.json": '{"b": 2}',
             "sheath-s0-2-00000000000000aa.json": '{ "c":3 }'}
    for name, text in texts.items():
        (models / name).write_text(text)
    (models / "dahl-s0-0-ident.json.part").write_text("half")  # not a model file
    out = tmp_path / "archive" / "bench-models.jsonl.gz"
    _, n = blind_archive.pack_models(models, {"dahl-s0-0", "sheath-s0-2"}, out)
    assert n == 2
    _, n = blind_archive.pack_models(models, {"dahl-s1-0"}, out)  # added, the first two kept
    assert n == 3
    fresh = tmp_path / "elsewhere" / "models"
    assert blind_archive.unpack_models(out, fresh) == 3
    assert {f.name: f.read_text() for f in fresh.iterdir()} == texts
    (fresh / "dahl-s1-0-fedcba9876543210.json").write_text("identified here")
    assert blind_archive.unpack_models(out, fresh) == 0  # a cached model is not overwritten
    assert (fresh / "dahl-s1-0-fedcba9876543210.json").read_text() == "identified here"
