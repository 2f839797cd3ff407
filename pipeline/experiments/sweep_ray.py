"""A sweep's runs as Ray tasks (`sweep --executor ray`)."""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

from sonarmap.pipeline.engine.errors import ConfigError

if TYPE_CHECKING:
    from sonarmap.pipeline.engine.run.graph import Graph

Spec = Any
Outcome = Any
"""A sweep's `RunSpec` and `RunOutcome` (not imported: `sweep` imports this module)."""

__all__ = ["run_on_ray"]


def run_on_ray(
    specs: Sequence[Spec],
    jobs: int,
    address: str | None,
    done: Callable[[Outcome], None],
    graph: Graph | None,
    run_one: Callable[[Spec, Graph | None], Outcome],
) -> list[Outcome]:
    """Each run a Ray task (a local instance unless `address` names a cluster; the store
    must then be a path every worker sees); outcomes in the order of `specs`."""
    try:
        import ray
    except ImportError as err:
        raise ConfigError(
            "--executor ray needs the 'ray' package (pip install 'sonarmap[ray]')"
        ) from err
    # The graph travels with each task; PYTHONPATH lets workers import its modules.
    env = {k: v for k, v in os.environ.items() if k in ("PYTHONPATH", "OMP_NUM_THREADS")}
    started = False
    if not ray.is_initialized():
        kwargs: dict[str, Any] = {
            "include_dashboard": False,
            "log_to_driver": False,
            "runtime_env": {"env_vars": env},
        }
        if address:
            ray.init(address=address, **kwargs)
        else:
            ray.init(num_cpus=max(jobs, 1), **kwargs)
        started = True
    try:
        remote = ray.remote(num_cpus=1)(run_one)
        pending = {remote.remote(s, graph): i for i, s in enumerate(specs)}  # type: ignore[call-arg]
        results: dict[int, Outcome] = {}
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1)
            for ref in ready:
                i = pending.pop(ref)
                results[i] = ray.get(ref)
                done(results[i])
        return [results[i] for i in range(len(specs))]
    finally:
        if started:
            ray.shutdown()
