"""Sub-commands of the ``czmpc`` console script, one module each.

Every module here defines ``NAME`` (the sub-command), ``HELP`` (one line),
``register(parser)`` that adds its options to an `argparse.ArgumentParser`, and
``run(args) -> int`` that does the work and returns the exit code. Modules import
their heavy dependencies inside ``run`` so that ``czmpc --help`` stays fast.
"""
