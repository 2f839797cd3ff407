"""The kernel layer: pure array functions that several stages (and the simulator) share.

Below the stages, above `schemas`: a kernel imports numpy, scipy, pyarrow (tables, never
Parquet files), the algorithm libraries (loaded on first use, `sonarmap.stages.kernels.lazy`) and
`schemas`, never a stage, the engine or the simulator. A stage that needs another
stage's per-frame work calls the kernel here, never the sibling stage's internals; a
kernel reads a stage's config through a `Protocol` of the fields it uses.
"""
