"""The project's own benchmarks and studies; each rewrites its section of BENCHMARKS.md.

Not part of the package (the wheel ships sysid, sim and czmpc only). Run one from the
root of a source checkout as ``python -m benchmarks.NAME`` (``--help`` for its
options); ``make bench`` runs them all. They may import anything of the product; the
product never imports them (tests/test_architecture.py).
"""
