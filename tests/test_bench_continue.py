"""`gslam bench --suite continue`'s table: a log scored by relations and one scored by GPS (the Car Park, no
rotation) side by side, and each log's verdict taken on the seeds' means."""

from __future__ import annotations

from pipelines.bench.continuation import ContinueRun, continue_section

NAN = float("nan")


def _run(log: str, seed: int, whole: tuple, alone: tuple, continued: tuple, references: int) -> ContinueRun:
    start = {"how": "found", "found_at_scan": 20, "travel_m": 12.0}
    return ContinueRun(log, seed, 586, whole, alone, continued, references, start, 17, (4248, 4165), 167_000,
                       700_000, 0.01, 14.9)  # fmt: skip


def test_the_table_scores_relations_and_gps_and_judges_on_the_means():
    runs = [
        _run("intel", 0, (0.0171, 0.277), (0.0174, 0.271), (0.0178, 0.268), 1055),
        _run("intel", 1, (0.0175, 0.274), (0.0175, 0.269), (0.0170, 0.266), 1055),
        _run("carpark", 0, (0.234, NAN), (0.133, NAN), (0.250, NAN), 312),
        _run("carpark", 1, (0.186, NAN), (0.214, NAN), (0.163, NAN), 312),
    ]
    assert [r.reference for r in runs] == ["relations", "relations", "GPS fixes", "GPS fixes"]
    text = continue_section(runs, "gslam bench --suite continue", "a machine", "gslam")
    lines = text.splitlines()
    row = next(line for line in lines if line.startswith("| carpark | 0 |"))
    assert "| 312 GPS fixes | 0.2340; - | 0.1330; - | 0.2500; - |" in row
    assert "| 1055 relations | 0.0171; 0.277 |" in next(line for line in lines if line.startswith("| intel | 0 |"))
    # the means: intel continued 0.0174 against whole 0.0173 m (no), 0.267 against 0.2755 deg (yes)
    assert next(line for line in lines if line.startswith("| intel | 2 |")).endswith("| no; yes |")
    carpark = next(line for line in lines if line.startswith("| carpark | 2 |"))
    assert carpark.endswith("| yes; - |") and "0.2100; -" in carpark and "0.2065; -" in carpark
