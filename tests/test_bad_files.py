"""identify, predict and diagnose on malformed logs and models, through ``bridge.cli.main``: a clear
one-line error and a non-zero exit, never a traceback, and an existing output file never left
overwritten or half-written."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from warpbridge.bridge.cli import main
from warpbridge.model.boucwen import BoucWenParams
from warpbridge.model.modelfile import ModelFile

SENTINEL = "previous output, must survive a failed run\n"


@pytest.fixture(scope="module")
def good(tmp_path_factory):
    """A short simulated log and the paper's model as a MODEL.json."""
    d = tmp_path_factory.mktemp("good")
    log = d / "log.csv"
    assert main(["simulate", "-o", str(log), "--duration", "4", "--rate", "100"]) == 0
    model = d / "model.json"
    model.write_text(json.dumps(ModelFile(BoucWenParams.paper()).to_dict()))
    return log, model


def good_log_text(good) -> str:
    return good[0].read_text()


def bad_logs(good) -> dict[str, bytes | None]:
    text = good_log_text(good)
    header, *rows = text.splitlines()
    cols = header.split(",")
    return {
        "missing": None,
        "empty": b"",
        "header only": (header + "\n").encode(),
        "binary": bytes(range(256)) * 20,
        "no warp column": ("t,u\n" + "\n".join(f"{i * 0.01},{i * 0.1}" for i in range(200))).encode(),
        "text values": (header + "\n" + "\n".join(",".join("abc" for _ in cols) for _ in range(100))).encode(),
        "all NaN": (header + "\n" + "\n".join(",".join("nan" for _ in cols) for _ in range(300))).encode(),
        "one row": (header + "\n" + rows[0] + "\n").encode(),
        "time constant": (header + "\n" + "\n".join(
            ",".join(["0"] + r.split(",")[1:]) for r in rows)).encode(),
        "inf everywhere": (header + "\n" + "\n".join(",".join("inf" for _ in cols) for _ in range(300))).encode(),
        "json instead": b'{"format": "warpbridge-model/1"}',
    }


def bad_models(good) -> dict[str, bytes | None]:
    doc = json.loads(good[1].read_text())
    nan_params = json.loads(good[1].read_text())
    nan_params["params"]["A"] = float("nan")
    neg_n = json.loads(good[1].read_text())
    neg_n["params"]["n"] = -3
    short_b = json.loads(good[1].read_text())
    short_b["params"]["b"] = [1.0, 2.0]
    text = json.dumps(doc)
    return {
        "missing": None,
        "empty": b"",
        "not JSON": b"this is not json",
        "truncated": text[: len(text) // 2].encode(),
        "a list": b"[1, 2, 3]",
        "no format": json.dumps({k: v for k, v in doc.items() if k != "format"}).encode(),
        "future format": json.dumps(doc | {"format": "warpbridge-model/2"}).encode(),
        "no params": json.dumps({k: v for k, v in doc.items() if k != "params"}).encode(),
        "NaN parameter": json.dumps(nan_params).encode(),
        "negative n": json.dumps(neg_n).encode(),
        "b too short": json.dumps(short_b).encode(),
        "strings": json.dumps(doc | {"params": {k: "x" for k in doc["params"]}}).encode(),
        "binary": b"\xff\xfe\x00\x01" * 50,
        "deeply nested": b"[" * 100000,
    }


def write(path: Path, content: bytes | None) -> Path:
    if content is not None:
        path.write_bytes(content)
    return path


def run_refused(capsys, argv: list[str], outputs: list[Path]) -> str:
    """Run the CLI with existing output files; it must refuse cleanly and leave them intact."""
    for out in outputs:
        out.write_text(SENTINEL)
    rc = main(argv)
    cap = capsys.readouterr()
    assert rc != 0, argv
    assert "Traceback" not in cap.err + cap.out
    lines = [ln for ln in cap.err.splitlines() if ln.strip() and not ln.startswith(("WARNING", "INFO", "DEBUG"))]
    assert len(lines) == 1, cap.err
    assert lines[0].startswith(f"warpbridge {argv[0]}: error:"), lines[0]
    for out in outputs:
        assert out.read_text() == SENTINEL, out  # not overwritten, not half-written
        assert not [p for p in out.parent.iterdir() if p.name.startswith(out.name) and p != out]
    return lines[0]


def test_the_good_files_work(good, tmp_path):
    log, model = good
    assert main(["predict", str(log), "--model", str(model), "-o", str(tmp_path / "pred.csv")]) == 0
    head = (tmp_path / "pred.csv").read_text().splitlines()[0]
    assert head.startswith("t,warp_pred")


@pytest.mark.parametrize("case", ["missing", "empty", "header only", "binary", "no warp column", "text values",
                                  "all NaN", "one row", "time constant", "inf everywhere", "json instead"])
@pytest.mark.parametrize("command", ["identify", "predict", "diagnose"])
def test_malformed_log(good, tmp_path, capsys, command, case):
    if command == "predict" and case == "no warp column":
        pytest.skip("predict needs only t and u: a log without warp is a valid input")
    log = write(tmp_path / "in.csv", bad_logs(good)[case])
    out = tmp_path / "out.file"
    argv = {"identify": ["identify", str(log), "-o", str(out), "--maxiter", "2", "--quiet"],
            "predict": ["predict", str(log), "--model", str(good[1]), "-o", str(out)],
            "diagnose": ["diagnose", str(log), "--model", str(good[1]), "--report", str(out), "--quiet"]}[command]
    run_refused(capsys, argv, [out])


@pytest.mark.parametrize("case", ["missing", "empty", "not JSON", "truncated", "a list", "no format",
                                  "future format", "no params", "NaN parameter", "negative n", "b too short",
                                  "strings", "binary", "deeply nested"])
@pytest.mark.parametrize("command", ["predict", "diagnose"])
def test_malformed_model(good, tmp_path, capsys, command, case):
    model = write(tmp_path / "model.json", bad_models(good)[case])
    out = tmp_path / "out.file"
    argv = {"predict": ["predict", str(good[0]), "--model", str(model), "-o", str(out)],
            "diagnose": ["diagnose", str(good[0]), "--model", str(model), "--report", str(out), "--quiet"]}[command]
    run_refused(capsys, argv, [out])


def test_wing_columns_missing_from_a_plain_log(good, tmp_path, capsys):
    out = tmp_path / "pred.csv"
    line = run_refused(capsys, ["predict", str(good[0]), "--model", str(good[1]), "-o", str(out), "--wing", "left"],
                       [out])
    assert "left" in line


def test_log_is_a_directory(good, tmp_path, capsys):
    out = tmp_path / "pred.csv"
    run_refused(capsys, ["predict", str(tmp_path), "--model", str(good[1]), "-o", str(out)], [out])


def test_output_into_a_missing_folder_is_a_clean_error(good, tmp_path, capsys):
    out = tmp_path / "no" / "such" / "folder" / "pred.csv"
    rc = main(["predict", str(good[0]), "--model", str(good[1]), "-o", str(out)])
    cap = capsys.readouterr()
    assert "Traceback" not in cap.err
    if rc == 0:  # made the folder and wrote a complete file
        assert out.read_text().splitlines()[0].startswith("t,warp_pred")
    else:
        assert cap.err.strip().count("\n") == 0 and cap.err.startswith("warpbridge predict: error:")
