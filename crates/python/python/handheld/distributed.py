"""The pipeline on Dask distributed.

    from dask.distributed import Client
    import handheld.distributed
    client = Client("tcp://scheduler:8786")          # or LocalCluster(), SSHCluster, dask-jobqueue, ...
    handheld.distributed.reconstruct("/shared/photos", "/shared/ws", client, until="sparse")

The workspace (and the input) must be on a file system that every worker sees, at the same path.
Each stage that splits into work units (features: one per photo; matches: one per block of
pairs; dense: one per consecutive pair of views) runs them as Dask tasks; then the stage itself
runs as one task, takes the units' files and writes what is left (the database, the depth maps
after linking, the summaries, the manifest). The other stages run as one
task each. The files of the split stages are byte-identical to a single-machine run's: the same
code writes them. A unit writes its files under temporary names and its marker last, so a task
that Dask retries after a worker died redoes it whole or finds it done.
"""

import os
import uuid

from . import _handheld
from ._handheld import HandheldError

__all__ = ["reconstruct"]


def _unit(input, workspace, stage, k, options):
    _handheld.run_unit(input, workspace, stage, k, options)
    return k


def _stage(input, workspace, stage, options, force):
    return _handheld.run_stage(input, workspace, stage, options, force)


def _report(workspace):
    return str(_handheld.write_report(workspace))


def reconstruct(input, workspace, client, options=None, until=None, force=False, progress=None):
    """`handheld.reconstruct` on a Dask cluster: the same stages, the same files, the same result.

    `client` is a `dask.distributed.Client`. `progress(step, done, total)` is called on this
    machine as units and stages finish. Returns one report per stage, as `handheld.reconstruct`;
    raises `HandheldError` with the failing stage's message (after writing the report, as the
    command line does).
    """
    from dask.distributed import as_completed

    input = os.path.abspath(os.fspath(input))
    workspace = os.path.abspath(os.fspath(workspace))
    options = _handheld.check_options(options)
    plan = _handheld.plan(input, options, until)
    run_id = uuid.uuid4().hex[:8]
    reports, failed, first_error = [], set(), None
    for stage, reads, required in plan:
        if failed.intersection(reads):
            failed.add(stage)
            continue
        try:
            n = client.submit(_handheld.stage_units, input, workspace, stage, options, force,
                              pure=False, key=f"handheld-{stage}-plan-{run_id}").result()
            if n:
                futures = client.map(_unit, [input] * n, [workspace] * n, [stage] * n, range(n), [options] * n,
                                     pure=False, key=[f"handheld-{stage}-unit-{k}-{run_id}" for k in range(n)])
                for done, f in enumerate(as_completed(futures), 1):
                    f.result()
                    if progress is not None:
                        progress(f"{stage} units", done, n)
            report = client.submit(_stage, input, workspace, stage, options, force,
                                   pure=False, key=f"handheld-{stage}-{run_id}").result()
            reports.append(report)
            if progress is not None:
                progress(stage, 1, 1)
        except HandheldError as e:
            if isinstance(e, _handheld.OptionsError):
                raise
            failed.add(stage)
            if required and first_error is None:
                first_error = e
    try:
        client.submit(_report, workspace, pure=False, key=f"handheld-report-{run_id}").result()
    except HandheldError:
        pass  # as the command line: a report that cannot be written does not fail the run
    if first_error is not None:
        raise first_error
    return reports
