"""Teaching and simulation: the simulator, the demos, UMBmark and their CLI subcommands.

This package imports the library; the library never imports it (only ``odofuse.cli`` wires
its subcommands, lazily). It imports nothing at package level, so that
``import odofuse.teaching.simulate`` does not pull in matplotlib.
"""
