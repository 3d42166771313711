"""argparse ``type=`` converters shared by the sub-commands (not a sub-command itself).

Each converter raises `argparse.ArgumentTypeError` with what was expected and what was
given, which the parser turns into ``czmpc: error: ...`` and exit code 2.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, TypeVar

if TYPE_CHECKING:
    from czmpc.settings import MPCSettings
    from sysid.data import Dataset
    from sysid.historian import LoadedLog
    from sysid.model import HammersteinModel


#: The test-signal kinds of `sysid.design.KINDS`, here so that ``--help`` needs no numpy
#: (a test holds the two equal).
TEST_SIGNAL_KINDS = ("steps", "gbn", "mixed", "multilevel")

#: What a `checked` converter returns.
Value = TypeVar("Value")


def checked(parse: Callable[[str], Value], accept: Callable[[Value], bool],
            expected: str) -> Callable[[str], Value]:
    """Converter that parses a text and accepts only some of its values.

    Parameters
    ----------
    parse :
        Turns the text into a value; a `ValueError` means the text is not one.
    accept :
        True for the values that may be used.
    expected :
        What a usable text is, for the message: ``expected EXPECTED; got 'TEXT'``.

    Returns
    -------
    Callable[[str], Value]
        The converter; it raises `argparse.ArgumentTypeError` for a text it refuses.
    """

    def convert(text: str) -> Value:
        try:
            value = parse(text)
        except ValueError:
            pass
        else:
            if accept(value):
                return value
        raise argparse.ArgumentTypeError(f"expected {expected}; got {text!r}")

    return convert


def integer(minimum: int, what: str = "an integer") -> Callable[[str], int]:
    """Converter to an int >= ``minimum``."""
    return checked(int, lambda value: value >= minimum, f"{what} >= {minimum}")


def number(
    *, above: float | None = None, at_least: float | None = None, at_most: float | None = None,
    unit: str = "",
) -> Callable[[str], float]:
    """Converter to a finite float with optional bounds (``above`` is exclusive)."""
    bounds = " ".join(f"{op} {v:g}" for op, v in ((">", above), (">=", at_least), ("<=", at_most))
                      if v is not None)
    expected = " ".join(part for part in ("a finite number", bounds, unit and f"[{unit}]") if part)

    def accept(value: float) -> bool:
        return (math.isfinite(value)
                and (above is None or value > above)
                and (at_least is None or value >= at_least)
                and (at_most is None or value <= at_most))

    return checked(float, accept, expected)


#: A seed for the random number generators (any int >= 0).
seed = integer(0, "an integer seed")
positive_int = integer(1)
non_negative_int = integer(0)
finite_float = number()
positive_float = number(above=0.0)
non_negative_float = number(at_least=0.0)
#: A shortening factor for scenarios: times x FACTOR, 0 < FACTOR <= 1.
shortening_factor = number(above=0.0, at_most=1.0)
#: The seed of a designed test signal's random part (design-test, commission).
signal_seed = integer(0, "a seed")
#: A duration or time constant [s] (> 0).
seconds = number(above=0.0, unit="s")
#: A TRIAC input level [%], 0..100.
percent = number(at_least=0.0, at_most=100.0, unit="%")
#: A TRIAC input change [%] (> 0).
percent_step = number(above=0.0, unit="%")


#: The data contract's column names (docs/reference/data_file.rst).
CONTRACT_COLUMNS = ("time_s", "triac_pct", "power_kw")
#: The optional column a mapping may name too (`sysid.data.GRID_VOLTAGE_COLUMN`).
OPTIONAL_COLUMNS = ("grid_voltage_factor",)


def column_mapping(text: str) -> dict[str, str]:
    """Parse ``time_s=NAME,triac_pct=NAME,power_kw=NAME`` (all three, each once), with an
    optional ``grid_voltage_factor=NAME``."""
    mapping: dict[str, str] = {}
    for item in text.split(","):
        key, sep, name = (part.strip() for part in item.partition("="))
        if not sep or not key or not name:
            raise argparse.ArgumentTypeError(
                f"expected CONTRACT_NAME=FILE_NAME items separated by commas; got {item!r}"
            )
        if key not in CONTRACT_COLUMNS + OPTIONAL_COLUMNS:
            raise argparse.ArgumentTypeError(
                f"expected a contract name in {list(CONTRACT_COLUMNS + OPTIONAL_COLUMNS)}; "
                f"got {key!r}"
            )
        if key in mapping:
            raise argparse.ArgumentTypeError(f"{key!r} is mapped twice")
        mapping[key] = name
    missing = [key for key in CONTRACT_COLUMNS if key not in mapping]
    if missing:
        raise argparse.ArgumentTypeError(f"every contract name must be mapped; missing {missing}")
    return mapping


def add_log_options(parser: argparse.ArgumentParser) -> None:
    """Options to read a log of another rig: column names, sampling, units."""
    parser.add_argument(
        "--columns", metavar="time_s=NAME,triac_pct=NAME,power_kw=NAME", type=column_mapping,
        default=None,
        help="read a log of another rig: map each contract name to the file's column "
             "(other columns are ignored; add grid_voltage_factor=NAME to read the grid "
             "voltage / nominal from a column of another name: a column named "
             "grid_voltage_factor is read without it)",
    )
    parser.add_argument(
        "--ts-s", metavar="X", type=positive_float, default=None,
        help="nominal sampling time [s]; default: the median interval of the file (with "
             "jittered time stamps: the mean period over the record)",
    )
    parser.add_argument(
        "--sampling-rtol", metavar="R", type=non_negative_float, default=None,
        help="intervals within R x Ts of a whole number of periods keep their logged "
             "times (default 0.01); larger jitter is handled by --resample",
    )
    parser.add_argument(
        "--sep", metavar="SEP", type=separator, default=None,
        help="CSV separator: ',', ';' or 'tab' (default: detected from the header line)",
    )
    parser.add_argument(
        "--decimal", metavar="MARK", choices=(".", ","), default=None,
        help="decimal mark of the numbers: '.' or ',' (default: ',' if the separator is "
             "not a comma and the values look like 12,5; else '.')",
    )
    parser.add_argument(
        "--time-format", metavar="FORMAT", default=None,
        help="format of the time stamps in Python's strptime codes, for stamps that are "
             "neither seconds nor ISO-8601, e.g. '%%d.%%m.%%Y %%H:%%M:%%S' for 25.10.2026 "
             "01:00:00 (%%z reads a UTC offset)",
    )
    parser.add_argument(
        "--gaps", choices=("refuse", "split", "fill"), default="refuse",
        help="missing values (NaN, empty cells) and gaps in time: 'refuse' (default) stops "
             "with the line; 'split' cuts the log into segments of complete samples "
             "(identify runs on the longest and says so); 'fill' interpolates runs of at most "
             "--fill-max missing samples linearly and splits at longer ones",
    )
    parser.add_argument(
        "--fill-max", metavar="N", type=positive_int, default=None,
        help="longest run of missing samples --gaps fill interpolates (default 5)",
    )
    parser.add_argument(
        "--resample", choices=("snap", "linear"), default="snap",
        help="irregular time stamps: 'snap' (default) moves samples whose interval is "
             "within 25 %% of a whole number of periods onto the grid t0 + k Ts (times "
             "within --sampling-rtol are kept as logged) and refuses larger jitter; "
             "'linear' interpolates the signals onto that grid",
    )
    parser.add_argument(
        "--input-unit", metavar="UNIT", default="%",
        help="unit of the input column (default: %%)",
    )
    parser.add_argument(
        "--output-unit", metavar="UNIT", default="kW",
        help="unit of the output column (default: kW)",
    )


def separator(text: str) -> str:
    """``,``, ``;``, ``tab`` (or a tab character) as the separator character."""
    value = {"tab": "\t", "\\t": "\t"}.get(text, text)
    if value not in (",", ";", "\t"):
        raise argparse.ArgumentTypeError(f"expected ',', ';' or 'tab'; got {text!r}")
    return value


def load_log(path: str | Path, args: argparse.Namespace) -> LoadedLog:
    """Read ``path`` (CSV or Parquet) with the options of `add_log_options`."""
    from sysid.data import DEFAULT_SAMPLING_RTOL
    from sysid.historian import DEFAULT_FILL_MAX_SAMPLES, LoadPolicy
    from sysid.historian import load_log as load

    rtol = DEFAULT_SAMPLING_RTOL if args.sampling_rtol is None else args.sampling_rtol
    policy = LoadPolicy(
        gaps=args.gaps, resample=args.resample, ts_s=args.ts_s, sampling_rtol=rtol,
        fill_max_samples=DEFAULT_FILL_MAX_SAMPLES if args.fill_max is None else args.fill_max)
    return load(path, columns=args.columns, policy=policy, sep=args.sep, decimal=args.decimal,
                input_unit=args.input_unit, output_unit=args.output_unit,
                time_format=args.time_format)


def read_log(path: str | Path, args: argparse.Namespace) -> Dataset:
    """Read ``path`` with the options of `add_log_options` (see `load_log`).

    A `czmpc run` log (open-loop test, dithered or plain MPC run) is recognised by its
    header and read by `czmpc.runtime.runlog.read_run_log`; what it is (closed-loop or
    not) is said on stderr. Any other log goes through the historian loader, and what it
    did (gaps split or filled, jitter snapped, ...) is said on stderr too.
    """
    from czmpc.runtime.runlog import describe_run_data, is_run_log, read_run_log

    if args.columns is None and is_run_log(path):
        data = read_run_log(path)
        print(f"czmpc: note: {describe_run_data(data)}", file=sys.stderr)
        return data
    loaded = load_log(path, args)
    if not loaded.report.is_plain_contract:
        print(f"czmpc: note: read {path}: {loaded.report.summary()}", file=sys.stderr)
    return loaded.data


def exact(value: float) -> str:
    """Shortest text of ``value`` that reads back to the same float (``45``, ``0.1``)."""
    short = f"{value:g}"
    return short if float(short) == value else repr(float(value))


def log_option_words(args: argparse.Namespace) -> list[str]:
    """The options of `add_log_options` as given, as command-line words (exact values)."""
    words: list[str] = []
    if args.columns is not None:
        words += ["--columns", ",".join(f"{k}={v}" for k, v in args.columns.items())]
    if args.ts_s is not None:
        words += ["--ts-s", exact(args.ts_s)]
    if args.sampling_rtol is not None:
        words += ["--sampling-rtol", exact(args.sampling_rtol)]
    if args.sep is not None:
        words += ["--sep", "tab" if args.sep == "\t" else args.sep]
    if args.decimal is not None:
        words += ["--decimal", args.decimal]
    if args.time_format is not None:
        words += ["--time-format", args.time_format]
    words += ["--gaps", args.gaps]
    if args.fill_max is not None:
        words += ["--fill-max", str(args.fill_max)]
    words += ["--resample", args.resample, "--input-unit", args.input_unit,
              "--output-unit", args.output_unit]
    return words


def file_or_shipped(text: str, what: str) -> Path:
    """``text`` as a file if it is one, else the shipped data file of that name.

    Raises
    ------
    OSError
        Neither exists (exit 2, naming ``what``).
    """
    from czmpc.shipped import shipped_path

    path = Path(text)
    if path.is_file():
        return path
    try:
        return shipped_path(text)
    except FileNotFoundError:
        raise OSError(f"{what} {text!r}: no such file, and no shipped {what} of that name") from None


def add_settings_options(parser: argparse.ArgumentParser) -> None:
    """``--settings FILE`` or ``--preset NAME`` (one of them) for the MPC's tuning."""
    group = parser.add_mutually_exclusive_group()
    group.add_argument(
        "--settings", metavar="SETTINGS.toml", type=Path, default=None,
        help="controller settings file (TOML): horizon, weights, TRIAC and rate limits, "
             "soft power limits, estimator noise, [reliability], [osqp]; keys it leaves out "
             "come from its 'preset' key and the model. Print a complete one with "
             "'czmpc settings --show'",
    )
    group.add_argument(
        "--preset", choices=("default", "aggressive", "smooth"), default="default",
        help="controller tuning without a file: 'default' (output weight 1, move weight "
             "0.1 1/kW^2, rate limit 5 %% of the model's input range per sample), "
             "'aggressive' (near-deadbeat, move weight 1e-4), 'smooth' (move weight 1, "
             "slower disturbance estimate) (default: default)",
    )


def settings_for(args: argparse.Namespace, model: HammersteinModel) -> MPCSettings:
    """The settings that `add_settings_options` asked for, for ``model``."""
    from czmpc.settings import MPCSettings
    from czmpc.settings_file import load_settings

    if args.settings is not None:
        return load_settings(args.settings, model)
    return MPCSettings.preset(args.preset, model)
