"""Planning and running a stage graph on a dataset.

Modules:
    graph: the stage graph (`Graph`) and `load_graph`.
    session: a dataset, config and store resolved into a run.
    planner: hit-or-miss planning (`planned`: the records it produces).
    runner: execution of a plan's misses (`compute`: one stage; `workers`,
        `worker_life`: where it runs); `run_records`: what each run used.
    output_checks: empty or collapsed outputs; progress: progress on stderr.
"""
