"""Errors of `czmpc.codegen`: settings the generated C cannot run, and failed builds."""

from __future__ import annotations

from czmpc.errors import CzmpcError


class CodegenError(CzmpcError, ValueError):
    """A model or settings the generated step cannot reproduce (e.g. OSQP polishing)."""


class BuildError(CzmpcError, RuntimeError):
    """The generated C could not be built or loaded (no compiler, a compile error)."""


__all__ = ["BuildError", "CodegenError"]
