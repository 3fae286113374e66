"""Other draws of a blind-benchmark rig's bench input: draw 0 is the benchmark's own log, the others differ."""

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import bench_diagnose_blind as blind  # noqa: E402
import blind_bench_draws  # noqa: E402
from plants import draw_plants  # noqa: E402


def test_draw_zero_is_the_blind_benchmarks_bench_log_and_other_draws_are_new_realisations():
    plant = draw_plants(1, "bouc-wen", 1)[0]
    own = blind.bench_log(plant, 1, 0, 2.0, 200.0)
    logs = [blind_bench_draws.draw_bench_log(plant, 1, 0, d, 2.0, 200.0) for d in range(3)]
    assert np.array_equal(logs[0].u, own.u) and np.array_equal(logs[0].w, own.w)
    for a, b in ((0, 1), (0, 2), (1, 2)):
        assert logs[a].u.shape == logs[b].u.shape
        assert not np.allclose(logs[a].u, logs[b].u)
    again = blind_bench_draws.draw_bench_log(plant, 1, 0, 2, 2.0, 200.0)
    assert np.array_equal(again.u, logs[2].u) and np.array_equal(again.w, logs[2].w)
    for lg in logs:  # the same input process: inside the rig's tendon range
        assert plant.u_lo - 1e-9 <= lg.u.min() and lg.u.max() <= plant.u_hi + 1e-9


def test_the_summary_counts_each_models_verdicts():
    def res(tag, k, truth, verdict, misfit=None):
        return {"model": tag, "case": k, "truth": truth, "verdict": verdict, "known_error_deg": 0.1,
                "field_misfit_deg": misfit}
    rs = [res("draw0", 0, [], ["friction"], 0.2), res("draw0", 1, ["delay"], ["delay"]),
          res("draw0", 2, ["delay", "drift"], ["drift"]), res("draw1", 0, [], [], 0.12),
          res("draw1", 1, ["delay"], ["sensor_lag"]), res("draw1", 2, ["delay", "drift"], ["delay", "drift"])]
    rows = blind_bench_draws.summary_rows(rs, ["draw0", "draw1", "draw2"], {"draw0": "a", "draw1": "b"})
    assert rows == [["a", "0.100", "0.200 (2.00-2.00x)", "1/1", "0/1", "1/1", "1/3"],
                    ["b", "0.100", "0.120 (1.20-1.20x)", "0/1", "1/1", "0/1", "2/3"]]
