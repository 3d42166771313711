"""The C's OSQP is set up from the Python controller's exact problem (`czmpc.codegen.generate`).

OSQP's code generator prints its workspace as "%.20f"; the C sets the solver up again at
init from ``osqp_values`` (exact P, A and settings), put in the places of the generated
workspace's CSC pattern, which `check_osqp_structure` checks.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from czmpc.codegen import CodegenError, generate_step
from czmpc.codegen.generate import OSQP_DIR, OSQP_PREFIX, check_osqp_structure, osqp_problem, osqp_values
from czmpc.controller import OffsetFreeMPC
from sysid.model import HammersteinModel


def test_exact_values_fill_the_generated_pattern_and_a_wrong_pattern_is_refused(
        tmp_path: Path, paper_armax_model: HammersteinModel) -> None:
    generate_step(paper_armax_model, None, tmp_path)
    workspace = (tmp_path / OSQP_DIR / f"{OSQP_PREFIX}workspace.c").read_text(encoding="utf-8")
    qp = OffsetFreeMPC(paper_armax_model).qp
    P, A = osqp_problem(qp)
    values = osqp_values(qp)
    assert values["QP_NNZ_P"] == str(P.nnz) and values["QP_NNZ_A"] == str(A.nnz)
    assert values["QP_P_X"].count("0x") == P.nnz and values["QP_A_X"].count("0x") == A.nnz
    header = (tmp_path / "czmpc_model.h").read_text(encoding="utf-8")
    assert f"#define CZMPC_QP_NNZ_P {P.nnz} " in header
    check_osqp_structure(workspace, qp)
    # one row index moved: the exact values would land elsewhere
    var = f"{OSQP_PREFIX}data_A_csc_i"
    body = re.search(rf"{var}\[\d+\] = \{{([^}}]*)\}}", workspace)
    assert body is not None
    entries = body.group(1).split(",")
    entries[1] = " 9999"
    broken = workspace.replace(body.group(1), ",".join(entries))
    with pytest.raises(CodegenError, match="data_A_csc_i must be the pattern"):
        check_osqp_structure(broken, qp)
    with pytest.raises(CodegenError, match="data_P_csc_p"):
        check_osqp_structure("", qp)
