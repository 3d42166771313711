"""Fuzz the logged-data CSV reader for a while; report any failure other than DataFileError.

Usage::

    python tools/fuzz_csv.py [--seconds 60] [--artifacts DIR] [--engine auto|atheris|hypothesis]

Every input is written to a scratch file and given to `sysid.data.read_csv`. The
contract: it returns a valid `Dataset` (at least 3 samples, finite values, strictly
increasing time, ts_s > 0) or raises `DataFileError`. Anything else counts as a crash:
another exception, a warning (warnings are errors here) or a `Dataset` that breaks
those invariants.

Engines:

* ``atheris`` (coverage-guided libFuzzer, if ``pip install atheris`` works; it is not a
  dependency of the project or its tests). Seeded with the head of the shipped data
  file and a few tricky files. A crash is written to ``DIR/crash-<sha1>`` by libFuzzer,
  which prints the traceback and stops with a non-zero exit code.
* ``hypothesis`` (fallback): random and structured CSV-like inputs, batch after batch
  until the time is up.

Exit code 0: no crash in the time given; 1: a crash (the input is saved/printed).
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
SHIPPED_CSV = REPO / "data" / "cz_heater_experiment.csv"

#: Hand-written seeds: the contract's edge cases (quoting, line ends, specials, BOM).
SEEDS: tuple[bytes, ...] = (
    b"time_s,triac_pct,power_kw\n0,45,45\n2,45,45.1\n4,46,46.3\n",
    b"\xef\xbb\xbftime_s,triac_pct,power_kw\r\n0,1,2\r\n2,1,2\r\n4,1,2\r\n",
    b'time_s,triac_pct,power_kw\n"0",1e308,-1e308\n2,nan,inf\n4,1_0,0x10\n',
    b"time_s,power_kw,triac_pct,extra\n0,1,2,3\n2,1,2,3\n",
    b"time_s,triac_pct,power_kw\r0,1,2\r2,1,2\r4,1,2\r",
)


class ContractBrokenError(AssertionError):
    """read_csv returned a Dataset that breaks the documented invariants."""


def check_one(path: Path, data: bytes) -> None:
    """Run read_csv on ``data``; raise anything but DataFileError (or ContractBrokenError)."""
    from sysid.data import read_csv
    from sysid.errors import DataFileError

    path.write_bytes(data)
    try:
        ds = read_csv(path)
    except DataFileError:
        return
    n = ds.n_samples
    ok = (
        n >= 3
        and all(arr.shape == (n,) and bool(np.all(np.isfinite(arr)))
                for arr in (ds.time_s, ds.triac_pct, ds.power_kw))
        and bool(np.all(np.diff(ds.time_s) > 0))
        and math.isfinite(ds.ts_s) and ds.ts_s > 0
    )
    if not ok:
        raise ContractBrokenError(f"read_csv returned an invalid Dataset for {data[:200]!r}")


def _seed_corpus(directory: Path) -> None:
    head = b""
    if SHIPPED_CSV.is_file():
        with open(SHIPPED_CSV, "rb") as fh:
            head = b"".join(fh.readline() for _ in range(20))
    for i, seed in enumerate((*SEEDS, head)):
        if seed:
            (directory / f"seed-{i}").write_bytes(seed)


def run_atheris(seconds: float, artifacts: Path, scratch: Path) -> int:
    """Fuzz with atheris/libFuzzer for ``seconds``; libFuzzer exits the process."""
    import atheris

    with atheris.instrument_imports():
        import sysid.data  # noqa: F401  (instrumented for coverage feedback)
    target = scratch / "input.csv"

    def one_input(data: bytes) -> None:
        check_one(target, data)

    corpus = scratch / "corpus"
    corpus.mkdir()
    _seed_corpus(corpus)
    argv = [sys.argv[0], str(corpus), f"-max_total_time={max(1, round(seconds))}",
            "-max_len=4096", "-timeout=20", "-rss_limit_mb=2048",
            f"-artifact_prefix={artifacts}/", "-print_final_stats=1"]
    print(f"fuzz_csv: atheris for {seconds:g} s; crashes go to {artifacts}/", file=sys.stderr)
    atheris.Setup(argv, one_input)
    atheris.Fuzz()
    return 0  # not reached: libFuzzer exits with 0 (time up) or non-zero (crash)


def run_hypothesis(seconds: float, artifacts: Path, scratch: Path) -> int:
    """Fuzz with hypothesis in batches until ``seconds`` are used up."""
    from hypothesis import HealthCheck, given, settings
    from hypothesis import strategies as st

    target = scratch / "input.csv"
    cells = st.one_of(st.floats().map(repr), st.text(max_size=6),
                      st.sampled_from(["", "nan", "1e308", "-1e308", "\r", "\x00", '"1"']))
    rows = st.lists(st.lists(cells, max_size=5).map(",".join), max_size=12)
    texts = st.builds(lambda h, r, nl: (h + nl + nl.join(r)).encode("utf-8", "surrogatepass"),
                      st.sampled_from(["time_s,triac_pct,power_kw", "time_s,power_kw", ""]),
                      rows, st.sampled_from(["\n", "\r\n", "\r"]))
    inputs = st.one_of(st.binary(max_size=500), texts, st.sampled_from(SEEDS))
    n_runs = 0

    @settings(max_examples=2000, deadline=None, database=None,
              suppress_health_check=list(HealthCheck))
    @given(data=inputs)
    def batch(data: bytes) -> None:
        nonlocal n_runs
        n_runs += 1
        try:
            check_one(target, data)
        except BaseException:
            (artifacts / f"crash-{n_runs}").write_bytes(data)
            raise

    print(f"fuzz_csv: hypothesis for {seconds:g} s; crashes go to {artifacts}/",
          file=sys.stderr)
    t_end = time.monotonic() + seconds
    while time.monotonic() < t_end:
        try:
            batch()
        except Exception as exc:  # report, do not hide: this is the tool's purpose
            print(f"fuzz_csv: CRASH after {n_runs} inputs: {type(exc).__name__}: {exc}",
                  file=sys.stderr)
            return 1
    print(f"fuzz_csv: done, {n_runs} inputs, no crash", file=sys.stderr)
    return 0


def main(argv: list[str] | None = None) -> int:
    """Parse options and fuzz."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0, help="how long to fuzz [s]")
    parser.add_argument("--artifacts", type=Path, default=None,
                        help="where crashing inputs are saved (default: a temporary directory)")
    parser.add_argument("--engine", choices=("auto", "atheris", "hypothesis"), default="auto")
    args = parser.parse_args(argv)
    warnings.simplefilter("error")       # a reader that only warns on bad input is a crash
    artifacts = args.artifacts or Path(tempfile.mkdtemp(prefix="fuzz_csv-artifacts-"))
    artifacts.mkdir(parents=True, exist_ok=True)
    engine = args.engine
    if engine == "auto":
        try:
            import atheris  # noqa: F401
            engine = "atheris"
        except ImportError:
            engine = "hypothesis"
    with tempfile.TemporaryDirectory(prefix="fuzz_csv-") as tmp:
        scratch = Path(tmp)
        if engine == "atheris":
            return run_atheris(args.seconds, artifacts, scratch)
        return run_hypothesis(args.seconds, artifacts, scratch)


if __name__ == "__main__":
    sys.exit(main())
