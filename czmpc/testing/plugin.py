"""The pytest plugin of czmpc (entry point ``pytest11: czmpc``): regression checks in tests.

With czmpc installed, every pytest session has the fixture ``czmpc_regress``::

    def test_my_controller_did_not_change(czmpc_regress):
        czmpc_regress.check("golden/")

``check`` re-runs the golden directory's cases (`czmpc.campaigns.regression.check_golden`)
and fails the test with the same table as ``czmpc regress check``: per failing case the
metric, golden value, tolerance, new value, the first divergence from the golden
trajectory, and a changed model or settings file as the likely cause. A relative
directory is taken from the folder of the test file. ``--czmpc-regress-report DIR``
writes the Markdown report and figures of every check into DIR/<golden dir name>.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import pytest

if TYPE_CHECKING:
    from czmpc.campaigns.regression import CheckReport

_REPORT_OPTION = "--czmpc-regress-report"


def pytest_addoption(parser: pytest.Parser) -> None:
    """Add ``--czmpc-regress-report DIR``."""
    group = parser.getgroup("czmpc", "czmpc controller regression checks")
    group.addoption(_REPORT_OPTION, metavar="DIR", default=None,
                    help="write report.md and figures of every czmpc_regress.check into DIR")


@dataclass(frozen=True)
class RegressChecker:
    """What the ``czmpc_regress`` fixture gives a test.

    Parameters
    ----------
    test_dir :
        Folder of the requesting test file (relative golden directories start there).
    report_root :
        Where reports go (``--czmpc-regress-report``), or None.
    """

    test_dir: Path
    report_root: Path | None

    def check(self, golden_dir: str | Path, *, executor: str = "serial", workers: int = 2,
              suite_dir: str | Path | None = None, cases: Sequence[str] | None = None
              ) -> CheckReport:
        """Re-run a golden directory; fail the test unless every case holds.

        Parameters
        ----------
        golden_dir :
            Written by ``czmpc regress record`` (relative: from the test file's folder).
        executor, workers :
            ``"serial"``, ``"processes"`` or ``"dask"`` and its worker count.
        suite_dir :
            See `czmpc.campaigns.regression.load_golden_dir`.
        cases :
            Case ids to check; None: all.

        Returns
        -------
        CheckReport
            The report of a passing check.
        """
        from czmpc.campaigns.regression import check_golden
        from czmpc.campaigns.regression_report import check_table, failure_lines, write_report

        path = Path(golden_dir)
        if not path.is_absolute():
            path = self.test_dir / path
        report = check_golden(path, executor=executor, workers=workers, suite_dir=suite_dir,
                              cases=cases)
        if self.report_root is not None:
            write_report(report, self.report_root / path.resolve().name)
        if not report.passed:
            details = [line for case in report.failed for line in failure_lines(case)]
            pytest.fail(f"czmpc regression check of {path} failed:\n" + check_table(report)
                        + "\n" + "\n".join(details), pytrace=False)
        return report


@pytest.fixture
def czmpc_regress(request: pytest.FixtureRequest) -> RegressChecker:
    """Check golden directories of ``czmpc regress record`` from a test (module notes)."""
    root = request.config.getoption(_REPORT_OPTION)
    return RegressChecker(test_dir=Path(request.path).parent,
                          report_root=None if root is None else Path(root))


__all__ = ["RegressChecker", "czmpc_regress", "pytest_addoption"]
