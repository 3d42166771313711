"""The pytest plugin (fixture czmpc_regress), run in an inner pytest session (pytester)."""

from __future__ import annotations

from pathlib import Path

import pytest

from czmpc.campaigns.regression import record_suite

pytest_plugins = ["pytester"]

USER_TEST = """
def test_puller7_did_not_change(czmpc_regress):
    report = czmpc_regress.check("golden")
    assert len(report.cases) == 2
"""


def test_the_fixture_passes_unchanged_and_fails_with_the_check_table(
        user_suite: Path, pytester: pytest.Pytester) -> None:
    record_suite(user_suite, pytester.path / "golden")
    pytester.makepyfile(test_user=USER_TEST)
    pytester.runpytest_subprocess("-p", "no:cacheprovider").assert_outcomes(passed=1)

    settings = user_suite.parent / "puller7_settings.toml"
    settings.write_text(settings.read_text(encoding="utf-8").replace(
        "move_weight = 0.1", "move_weight = 0.2"), encoding="utf-8")
    result = pytester.runpytest_subprocess("-p", "no:cacheprovider")
    result.assert_outcomes(failed=1)
    result.stdout.fnmatch_lines([
        "*czmpc regression check of *golden failed:*",
        "*tuned/model/recipe_a/s3*FAIL*iae_kw_s*t = * s (*",
        "*move_weight: 0.1 -> 0.2*",
        "*tuned/model/recipe_a/s3: likely cause: changed input(s) puller7_settings.toml*",
    ])
