"""Fuzz every reader of outside data: generated and mutated files must either read into valid data or be
refused with the reader's own error (IngestError / InputError) naming the file; any other exception is
a crash. A reader is one entry in READERS (a strategy for the files and a function that reads them).

The default run (`python -m pytest -q`) runs a small derandomised profile (CI_EXAMPLES per reader, a
few seconds); `python -m pytest -m fuzz tests/test_fuzz.py` runs FULL_EXAMPLES cases in all (or
GSLAM_FUZZ_EXAMPLES), randomised; docs/RELIABILITY.md records its counts.
"""

from __future__ import annotations

import gzip
import io
import math
import os
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ingest import IngestError, ingest
from mcaplog import channels as ch
from pipelines.errors import InputError
from pipelines.run.input_log import InputLog

CI_EXAMPLES = 25
FULL_EXAMPLES = int(os.environ.get("GSLAM_FUZZ_EXAMPLES", 10_000))
COUNTS: dict[str, dict[str, int]] = {}
"""Per reader: cases run, refused with a clear error, read; printed at the end of the session."""

Files = dict[str, bytes]


@dataclass
class Reader:
    name: str
    files: Callable[[dict[str, Files]], st.SearchStrategy[Files]]
    """A strategy for the files of one case (it may start from the valid `seeds`)."""
    read: Callable[[Path], None]
    """Read the case's directory; raise only the reader's own error."""


# ---- tokens and lines -----------------------------------------------------------------------------
GOOD = st.sampled_from(["0", "1.5", "5.0", "80.0", "81.9", "12.25", "1e-3", "3"])
BAD = st.sampled_from(["", "nan", "inf", "-inf", "-1.5", "abc", "1e400", "0x10", "1,2", " ", "\x00", "é", "--", "+"])
TOKEN = st.one_of(GOOD, GOOD, GOOD, BAD, st.floats().map(repr), st.integers(-(10**20), 10**20).map(str))


def _row(n_cols: int, t: float) -> st.SearchStrategy[str]:
    def corrupt(tokens: list[str], edits: list[tuple[int, str]]) -> str:
        for i, tok in edits:
            if tokens:
                tokens[i % len(tokens)] = tok
        return ",".join(tokens)

    cols = st.sampled_from([n_cols, n_cols, n_cols, n_cols - 1, n_cols + 1, 1, 0])
    return st.builds(
        corrupt,
        cols.flatmap(lambda n: st.just([f"{t:.3f}"] + ["5.0"] * max(n - 1, 0))),
        st.one_of(st.just([]), st.just([]), st.lists(st.tuples(st.integers(0, 400), TOKEN), max_size=3)),
    )


def _csv(n_cols: int, max_rows: int = 4) -> st.SearchStrategy[bytes]:
    rows = st.lists(st.integers(0, 3), max_size=max_rows).flatmap(
        lambda ks: st.tuples(*[_row(n_cols, 1.0 + 0.2 * i + 0.01 * k) for i, k in enumerate(ks)])
    )
    text = rows.map(lambda r: "\n".join(r) + "\n")
    raw = st.binary(max_size=200)
    return st.one_of(text.map(str.encode), text.map(str.encode), raw)


# ---- Sydney text ----------------------------------------------------------------------------------
def sydney_text_files(seeds: dict[str, Files]) -> st.SearchStrategy[Files]:
    names = {
        "DRS.txt": _csv(3),
        "GPS.txt": _csv(3),
        "LASER.txt": _csv(362),
        "INTENSITY.txt": _csv(362),
        "BEACONS.txt": _csv(2),
        "TRUTH.txt": _csv(4),
    }
    present = st.fixed_dictionaries({}, optional=names)
    return st.one_of(present, present.map(lambda d: {**seeds["sydney-text"], **d}))


def read_ingest(fmt: str) -> Callable[[Path], None]:
    def read(d: Path) -> None:
        out = d.parent / "out.mcap"
        try:
            report = ingest(d, out, fmt)
        except IngestError:
            assert not out.exists(), "a refused ingest left a file at the output path"
            raise
        assert out.exists() and report.counts
        if ch.LASER not in report.counts:
            return
        try:  # what was written reads back as valid scans
            events = list(InputLog(out).events())
        except InputError as e:
            raise AssertionError(f"an ingested log is refused by process: {e}") from None
        for ev in events:
            ranges = getattr(ev, "ranges_m", None)
            if ranges is not None:
                assert not np.isnan(ranges).any() and (ranges >= 0).all()
                assert math.isfinite(ev.t_s)

    return read


# ---- Sydney MATLAB --------------------------------------------------------------------------------
def _mat_bytes(variables: dict[str, np.ndarray]) -> bytes:
    from scipy.io import savemat

    buf = io.BytesIO()
    savemat(buf, variables)
    return buf.getvalue()


ARRAY = st.one_of(
    st.integers(0, 6).flatmap(lambda n: st.lists(st.floats(width=32), min_size=n, max_size=n)).map(np.array),
    st.sampled_from([np.zeros((0,)), np.zeros((2, 361)), np.full((3, 361), 81.9), np.array(["text"]), np.eye(3)]),
    st.integers(1, 4).map(lambda k: np.cumsum(np.full(k, 0.2))),
)


def sydney_mat_files(seeds: dict[str, Files]) -> st.SearchStrategy[Files]:
    carpark = ["Time_VS", "Velocity", "Steering", "TimeGPS", "GPSLon", "GPSLat", "Laser", "TimeLaser", "Intensity"]
    variables = st.fixed_dictionaries({}, optional=dict.fromkeys(carpark, ARRAY))
    generated = variables.map(lambda v: {"data_set.mat": _mat_bytes(v)})
    valid = seeds["sydney-mat-variables"]
    varied = st.fixed_dictionaries(
        {}, optional={k: st.one_of(st.just(v), st.just(v), st.just(v), ARRAY) for k, v in valid.items()}
    ).map(lambda v: {"data_set.mat": _mat_bytes(v)})
    victoria = st.fixed_dictionaries(
        {"aa3_dr.mat": st.fixed_dictionaries({}, optional=dict.fromkeys(["time", "speed", "steering"], ARRAY))},
        optional={
            "aa3_gpsx.mat": st.fixed_dictionaries({}, optional=dict.fromkeys(["timeGps", "Lo_m", "La_m"], ARRAY)),
            "aa3_lsr2.mat": st.fixed_dictionaries({}, optional=dict.fromkeys(["LASER", "TLsr"], ARRAY)),
        },
    ).map(lambda files: {name: _mat_bytes(v) for name, v in files.items()})
    damaged = _mutated(st.just(seeds["sydney-mat"]["data_set.mat"])).map(lambda b: {"data_set.mat": b})
    return st.one_of(varied, varied, generated, victoria, damaged)


# ---- CARMEN ---------------------------------------------------------------------------------------
def _carmen_line(i: int) -> st.SearchStrategy[str]:
    t = f"{10 + 0.1 * i:.3f}"
    flaser = " ".join(["FLASER", "4", "1.0", "2.0", "81.9", "3.5", "0 0 0", "0.1 0.2 0.05", t, "host", t])
    odom = " ".join(["ODOM", "0.1", "0.2", "0.05", "0.3", "0.0", "0.0", t, "host", t])
    base = st.sampled_from([flaser, flaser, odom, "PARAM robot_x 1", "# comment", ""])

    def corrupt(line: str, edits: list[tuple[int, str]], cut: int) -> str:
        parts = line.split(" ")
        for k, tok in edits:
            parts[k % len(parts)] = tok
        return " ".join(parts[: len(parts) - cut])

    return st.builds(corrupt, base, st.lists(st.tuples(st.integers(0, 30), TOKEN), max_size=2), st.integers(0, 3))


def carmen_files(seeds: dict[str, Files]) -> st.SearchStrategy[Files]:
    lines = st.lists(st.integers(0, 5), max_size=8).flatmap(lambda ks: st.tuples(*[_carmen_line(i) for i in ks]))
    text = lines.map(lambda ls: ("\n".join(ls) + "\n").encode())
    body = st.one_of(text, text, text.map(gzip.compress), _mutated(st.just(gzip.compress(b"FLASER 1 1.0\n" * 20))))
    relations = st.one_of(
        st.just(b"10.0 10.2 0.1 0 0 0 0 0.01\n"),
        st.lists(st.lists(TOKEN, max_size=9).map(" ".join), max_size=3).map(lambda ls: "\n".join(ls).encode()),
    )
    log = st.tuples(st.sampled_from(["x.clf", "x.log", "x.clf.gz"]), body)
    return st.one_of(
        log.map(lambda nb: {nb[0]: nb[1]}),
        st.tuples(log, relations).map(lambda p: {p[0][0]: p[0][1], "x.relations": p[1]}),
    )


# ---- MCAP (input and result) ----------------------------------------------------------------------
def _mutated(valid: st.SearchStrategy[bytes]) -> st.SearchStrategy[bytes]:
    """Bytes of a valid file with a few bytes changed, a cut, or a slice repeated."""

    def flip(b: bytes, edits: list[tuple[int, int]]) -> bytes:
        a = bytearray(b)
        for pos, val in edits:
            a[pos % len(a)] = val
        return bytes(a)

    flips = st.tuples(valid, st.lists(st.tuples(st.integers(0, 1 << 30), st.integers(0, 255)), min_size=1, max_size=8))
    cuts = st.tuples(valid, st.floats(0, 1)).map(lambda p: p[0][: int(len(p[0]) * p[1])])
    splices = st.tuples(valid, st.integers(0, 1 << 30), st.integers(1, 64)).map(
        lambda p: p[0][: p[1] % len(p[0])] + p[0][p[1] % len(p[0]) :][: p[2]] + p[0][p[1] % len(p[0]) :]
    )
    return st.one_of(flips.map(lambda p: flip(*p)), cuts, splices)


def mcap_input_files(seeds: dict[str, Files]) -> st.SearchStrategy[Files]:
    which = st.sampled_from(["sydney", "carmen"])
    return which.flatmap(lambda k: _mutated(st.just(seeds["mcap"][k]))).map(lambda b: {"in.mcap": b})


def read_mcap_input(d: Path) -> None:
    from pipelines.evaluation.mcap_info import mcap_info
    from pipelines.run.input_log import InputLog

    path = d / "in.mcap"
    try:
        mcap_info(path)
    except InputError:
        pass
    log = InputLog(path)
    for ev in log.events():
        if hasattr(ev, "ranges_m"):
            assert len(ev.ranges_m) == log.geometry.beam_count
    log.gps_array()


def mcap_result_files(seeds: dict[str, Files]) -> st.SearchStrategy[Files]:
    return _mutated(st.just(seeds["mcap"]["result"])).map(lambda b: {"result.mcap": b})


def read_mcap_result(d: Path) -> None:
    from pipelines.evaluation.evaluate import read_result

    res = read_result(d / "result.mcap")
    assert len(res.trajectory) == len(res.t_s)


READERS = [
    Reader("sydney-text", sydney_text_files, read_ingest("sydney-text")),
    Reader("sydney-mat", sydney_mat_files, read_ingest("sydney-mat")),
    Reader("carmen", carmen_files, read_ingest("carmen")),
    Reader("mcap-input", mcap_input_files, read_mcap_input),
    Reader("mcap-result", mcap_result_files, read_mcap_result),
]


# ---- valid seeds ----------------------------------------------------------------------------------
@pytest.fixture(scope="session")
def seeds(tmp_path_factory) -> dict[str, Files]:
    """Small valid files of each kind, for the strategies to start from and mutate."""
    from pipelines.process import process
    from pipelines.run.runner import RunConfig

    d = tmp_path_factory.mktemp("fuzz-seeds")
    ranges = ",".join(["5.0"] * 361)
    text = {
        "DRS.txt": "".join(f"{1 + 0.025 * i:.3f},2.0,0.05\n" for i in range(40)),
        "GPS.txt": "".join(f"{1 + 0.2 * i:.3f},{0.4 * i:.3f},0.0\n" for i in range(5)),
        "LASER.txt": "".join(f"{1.01 + 0.2 * i:.3f},{ranges}\n" for i in range(4)),
    }
    (d / "syd").mkdir()
    for name, body in text.items():
        (d / "syd" / name).write_text(body)
    ingest(d / "syd", d / "syd.mcap")
    carmen = "".join(
        f"FLASER 4 1.0 2.0 81.9 3.5 0 0 0 {0.1 * i:.2f} 0 0 {10 + 0.2 * i:.2f} host {10 + 0.2 * i:.2f}\n"
        for i in range(5)
    )
    (d / "c.clf").write_text(carmen)
    ingest(d / "c.clf", d / "c.mcap")
    process(d / "syd.mcap", d / "result.mcap", None, RunConfig())
    laser = np.full((3, 361), 5.0)
    mat = {"Time_VS": np.arange(10) * 0.1, "Velocity": np.ones(10), "Steering": np.zeros(10)}
    mat |= {"TimeGPS": np.arange(3) * 0.2, "GPSLon": np.zeros(3), "GPSLat": np.zeros(3)}
    mat |= {"Laser": laser, "TimeLaser": np.arange(3) * 0.2 + 0.05}
    return {
        "sydney-text": {k: v.encode() for k, v in text.items()},
        "sydney-mat": {"data_set.mat": _mat_bytes(mat)},
        "sydney-mat-variables": mat,
        "mcap": {
            k: (d / f"{k0}.mcap").read_bytes() for k, k0 in (("sydney", "syd"), ("carmen", "c"), ("result", "result"))
        },
    }


# ---- the property ---------------------------------------------------------------------------------
def fuzz(reader: Reader, seeds: dict[str, Files], examples: int, derandomize: bool) -> None:
    counts = COUNTS.setdefault(reader.name, {"cases": 0, "refused": 0, "read": 0})

    @settings(
        max_examples=examples,
        deadline=None,
        derandomize=derandomize,
        database=None,
        suppress_health_check=list(HealthCheck),
    )
    @given(files=reader.files(seeds))
    def case(files: Files) -> None:
        with tempfile.TemporaryDirectory(prefix="gslam-fuzz-") as tmp:
            d = Path(tmp) / "case"
            d.mkdir()
            for name, data in files.items():
                (d / name).write_bytes(data)
            counts["cases"] += 1
            try:
                reader.read(d)
            except (IngestError, InputError) as e:
                message = str(e)
                assert "\n" not in message.strip() and str(d) in message, message  # one line, names the file
                counts["refused"] += 1
            else:
                counts["read"] += 1

    case()


@pytest.mark.parametrize("reader", READERS, ids=lambda r: r.name)
def test_fuzz_readers_ci_profile(reader, seeds):
    fuzz(reader, seeds, CI_EXAMPLES, derandomize=True)


@pytest.mark.fuzz
@pytest.mark.parametrize("reader", READERS, ids=lambda r: r.name)
def test_fuzz_readers_full_profile(reader, seeds):
    fuzz(reader, seeds, math.ceil(FULL_EXAMPLES / len(READERS)), derandomize=False)
