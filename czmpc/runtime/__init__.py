"""One controller against a live plant: wall-clock loop, OPC UA link and its security.

Layer 3 (tests/test_architecture.py): imports the core, peers, reports, sim and sysid;
never campaigns or the CLI.
"""
