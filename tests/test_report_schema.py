"""REPORT.json and MODEL.json as the commands write them hold to the schemas the package ships, and
docs/report-format.md documents every key the schemas have."""

from __future__ import annotations

import copy
import json
import re
from pathlib import Path

import pytest
from schema_check import validate_model, validate_report, violations

from warpbridge.bridge.cli import main
from warpbridge.bridge.commands.schemas import SCHEMAS, load_schema
from warpbridge.model.effect_registry import EFFECT_FIELDS, EFFECT_NAMES
from warpbridge.model.model_error import FEATURE_SETS

DOC = Path(__file__).resolve().parent.parent / "docs" / "report-format.md"

pytestmark = pytest.mark.slow  # the module's fixture identifies a model and runs two diagnoses


def run(*args) -> None:
    assert main([str(a) for a in args]) == 0, args


@pytest.fixture(scope="module")
def written(tmp_path_factory) -> dict[str, dict]:
    """identify (with a check log) on a small simulated bench log, then two diagnoses: a field log with a delay
    and a drift under varying airspeed (with --sensitivity and --out-model), and one with no effect."""
    d = tmp_path_factory.mktemp("schema")
    run("simulate", "-o", d / "bench.csv", "--duration", 30, "--rate", 200, "--seed", 1)
    run("simulate", "-o", d / "check.csv", "--duration", 15, "--rate", 200, "--excitation", "multisine", "--seed", 2)
    run("identify", d / "bench.csv", "--check", d / "check.csv", "-o", d / "model.json", "--quiet", "--maxiter", 60,
        "--max-delay", 0.1)
    run("simulate", "-o", d / "field.csv", "--duration", 20, "--rate", 200, "--seed", 3, "--airspeed", "8:16",
        "--effects", "delay=0.04,drift=0.01")
    run("diagnose", d / "field.csv", "--model", d / "model.json", "--report", d / "report.json", "--out-model",
        d / "augmented.json", "--sensitivity", "--quiet")
    run("simulate", "-o", d / "none.csv", "--duration", 20, "--rate", 200, "--seed", 4)
    run("diagnose", d / "none.csv", "--model", d / "model.json", "--report", d / "report_none.json", "--quiet")
    return {p.stem: json.loads(p.read_text()) for p in d.glob("*.json")}


def test_the_schemas_are_valid_draft_2020_12_schemas():
    for name in SCHEMAS:
        schema = load_schema(name)
        assert schema["$schema"] == "https://json-schema.org/draft/2020-12/schema"
        assert violations({}, name)  # an empty object is not a report nor a model


def test_identify_and_diagnose_write_models_the_schema_accepts(written):
    model, augmented = written["model"], written["augmented"]
    validate_model(model)
    validate_model(augmented)
    assert model["fit"]["check"]["log"] == "check.csv"  # the optional parts were there to be checked
    assert set(augmented["effects"]) == set(written["report"]["verdict"])


def test_diagnose_writes_reports_the_schema_accepts(written):
    rep, none = written["report"], written["report_none"]
    validate_report(rep)
    validate_report(none)
    # the documents exercised the schema's branches: a verdict with alternatives and an augmented model, and
    # a verdict of nothing judged against a check log's known error
    assert rep["verdict"] and rep["alternatives"] and rep["out_model"] == "augmented.json"
    assert "airspeed" in rep["where"]
    assert none["verdict"] == [] and none["model_error_from_check"] is not None and "out_model" not in none


# parts of reports diagnose wrote that the two diagnoses above do not produce (a bend of the measured-data
# benchmark, simulated field logs with an aero load, a slew limit, a two-stage sensor lag), numbers rounded and
# reasons cut short
WRITTEN_PARTS = {
    "left_over": {"heldout_rms_deg": 0.6256, "floor_deg": 0.05166, "block_s": [18.04, 20.0], "share_of_excess": 0.5621,
                  "mostly": True, "block_peak_speed_mm_s": 2.271, "train_peak_speed_mm_s": 5.326,
                  "block_travel_mm": [4.418, 5.64], "train_travel_mm": [3.777, 6.679],
                  "block_peak_airspeed_m_s": 18.0, "train_peak_airspeed_m_s": 15.24, "beyond_training": ["airspeed"]},
    "dropped": [{"effect": "pretension", "reason": "its held-out gain grows faster than the dynamic pressure",
                 "gain_by_airspeed": {"q_slow_kpa": 0.06572, "q_fast_kpa": 0.154, "gain_slow_ms": 0.09377,
                                      "gain_fast_ms": 0.9182, "fast_over_slow": 9.792}}],
    "kept_unnamed": {"friction": {"fitted": {"capstan_pull_ratio": 0.008467, "capstan_release_ratio": 0.08277,
                                             "capstan_zero_mm": -61.81},
                                  "band_factor": 1.289, "compliance_factor": 1.167, "stretch_share": 0.6073,
                                  "reason": "the friction band widened (x1.29) with the rig's compliance"}},
    "bound_hits": [{"effect": "sensor_lag", "parameter": "sensor_stage_ratio", "bound": "upper", "limit": 1.0,
                    "value": 1.0, "meaning": "sensor_lag: sensor_stage_ratio sits at the upper bound of its search"}],
    "band_gain_by_airspeed": [{"effect": "backlash", "q_slow_kpa": 0.05821, "q_fast_kpa": 0.1322,
                               "gain_slow_ms": 0.02437, "gain_fast_ms": 0.03529, "fast_over_slow": 1.448}],
    "model_error_carried": {"nominal": {"bench_gain_ms": 0.0468, "field_gain_ms": -1.236, "se_ms": 0.9414,
                                        "p_value": 0.103}, "short": False, "raised_by_ms": 0.0,
                            "known_error_deg": 0.7935},
}


@pytest.mark.parametrize("key", sorted(WRITTEN_PARTS))
def test_the_parts_other_logs_give_are_accepted(written, key):
    doc = copy.deepcopy(written["report"])
    doc[key] = WRITTEN_PARTS[key]
    validate_report(doc)


def _broken(doc: dict, edit) -> dict:
    doc = copy.deepcopy(doc)
    edit(doc)
    return doc


@pytest.mark.parametrize("what, edit", [
    ("missing verdict", lambda r: r.pop("verdict")),
    ("missing shrinkage", lambda r: r.pop("shrinkage")),
    ("an effect not in the vocabulary", lambda r: r["verdict"].append("wobble")),
    ("an effect object of an unknown effect", lambda r: r["effects"].update(wobble={"wobble_s": 1.0})),
    ("a parameter the effect has not", lambda r: r["effects"].update(delay={"delay_ms": 40.0})),
    ("another format version", lambda r: r.update(format="warpbridge-diagnosis/2")),
    ("a candidate of an unknown effect", lambda r: r["candidates"][0].update(effect="wobble")),
    ("a candidate tried without its rounds", lambda r: r["candidates"][0].pop("rounds")),
    ("a count that is not an integer", lambda r: r.update(samples=12.5)),
    ("a dominant dimension that does not exist", lambda r: r["where"].update(dominant="colour")),
    ("a bound that is neither edge", lambda r: r.update(bound_hits=[dict(WRITTEN_PARTS["bound_hits"][0],
                                                                             bound="middle")])),
    ("a left-over block of three ends", lambda r: r.update(left_over=dict(WRITTEN_PARTS["left_over"],
                                                                           block_s=[1.0, 2.0, 3.0]))),
])
def test_a_broken_report_is_rejected(written, what, edit):
    validate_report(written["report"])
    bad = _broken(written["report"], edit)
    assert violations(bad, "report"), what
    with pytest.raises(AssertionError, match="not a valid report"):
        validate_report(bad)


@pytest.mark.parametrize("what, edit", [
    ("missing params", lambda m: m.pop("params")),
    ("five sign weights", lambda m: m["params"].update(b=m["params"]["b"][:5])),
    ("an unknown effect", lambda m: m["effects"].update(wobble={"wobble_s": 1.0})),
    ("another format version", lambda m: m.update(format="warpbridge-model/2")),
    ("an unknown feature set", lambda m: m["model_error"].update(sets=["colour"])),
])
def test_a_broken_model_is_rejected(written, what, edit):
    bad = _broken(written["model"], edit)
    assert violations(bad, "model"), what


@pytest.mark.parametrize("name", sorted(SCHEMAS))
def test_the_schemas_effect_vocabulary_is_the_codes(name):
    defs = load_schema(name)["$defs"]
    assert defs["effect_name"]["enum"] == list(EFFECT_NAMES)
    assert list(defs["effects"]["properties"]) == list(EFFECT_FIELDS)  # the diagnosis's and the rig's effects
    for effect, (fields, _, _) in EFFECT_FIELDS.items():
        assert list(defs[f"params_{effect}"]["properties"]) == list(fields), effect


def test_the_model_schemas_feature_sets_are_the_codes():
    sets = load_schema("model")["properties"]["model_error"]["properties"]["sets"]["items"]["enum"]
    assert sets == list(FEATURE_SETS)


@pytest.mark.parametrize("name", sorted(SCHEMAS))
def test_the_doc_documents_every_top_level_key_of_the_schema(name):
    text = DOC.read_text(encoding="utf-8")
    documented = set(re.findall(r"^\| `([a-z_0-9]+)` \|", text, flags=re.M))
    keys = set(load_schema(name)["properties"])
    assert keys <= documented, f"docs/report-format.md lacks a row for {sorted(keys - documented)}"
    assert load_schema(name)["properties"]["format"]["const"] in text


def _property_names(node: object) -> set[str]:
    """Every key any object of a schema lists under ``properties``, at any depth."""
    if isinstance(node, list):
        return set().union(*map(_property_names, node)) if node else set()
    if not isinstance(node, dict):
        return set()
    names = set(node["properties"]) if isinstance(node.get("properties"), dict) else set()
    return names.union(*map(_property_names, node.values()))


@pytest.mark.parametrize("name", sorted(SCHEMAS))
def test_the_doc_names_every_key_the_schema_has_at_any_depth(name):
    text = DOC.read_text(encoding="utf-8")
    missing = sorted(k for k in _property_names(load_schema(name)) if f"`{k}`" not in text and f'"{k}"' not in text)
    assert not missing, f"docs/report-format.md never names {missing}"


def test_the_doc_names_every_effect_parameter():
    text = DOC.read_text(encoding="utf-8")
    missing = [f for fields, _, _ in EFFECT_FIELDS.values() for f in fields if f"`{f}`" not in text]
    assert not missing
