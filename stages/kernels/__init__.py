"""The kernel layer: pure array functions that several stages (and the simulator) share.

Below the stages, above `schemas`: a kernel imports numpy, scipy and `schemas` only,
never a stage, the engine or the simulator. A stage that needs another stage's
per-frame work calls the kernel here, never the sibling stage's internals.
"""
