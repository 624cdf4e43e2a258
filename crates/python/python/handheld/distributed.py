"""The pipeline on Dask distributed.

    from dask.distributed import Client
    import handheld.distributed
    client = Client("tcp://scheduler:8786")          # or LocalCluster(), SSHCluster, dask-jobqueue, ...
    handheld.distributed.reconstruct("/shared/photos", "/shared/ws", client, until="sparse")

The workspace (and the input) must be on a file system that every worker sees, at the same path.
Each stage that splits into work units (features: one per photo; matches: one per block of
pairs; sparse, when split-and-merge applies: one per cluster; dense: one per consecutive pair of
views) runs them as Dask tasks; then the stage itself
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

__all__ = ["reconstruct", "bench_scale"]


def _unit(input, workspace, stage, k, options):
    _handheld.run_unit(input, workspace, stage, k, options)
    return k


def _stage(input, workspace, stage, options, force):
    return _handheld.run_stage(input, workspace, stage, options, force)


def _sees(input, probe):
    import socket

    return socket.gethostname(), os.path.exists(input), os.path.exists(probe)


def check_workers_see(client, input, workspace):
    """Raises `HandheldError` naming the first worker that cannot see the input or the workspace
    (a file written here must appear there: the workspace is shared, at the same path)."""
    if not os.path.exists(input):
        raise HandheldError(f"{input}: no such file or folder")
    os.makedirs(workspace, exist_ok=True)
    probe = os.path.join(workspace, f".handheld-probe-{uuid.uuid4().hex[:8]}")
    with open(probe, "w") as f:
        f.write("every worker must see this file\n")
    try:
        seen = client.run(_sees, input, probe)
    finally:
        os.remove(probe)
    for worker, (host, has_input, has_workspace) in sorted(seen.items()):
        if not has_input:
            raise HandheldError(
                f"the Dask worker {worker} (on {host}) cannot see the input {input}: put it on a file system every "
                "worker mounts, at the same path")
        if not has_workspace:
            raise HandheldError(
                f"the Dask worker {worker} (on {host}) cannot see the workspace {workspace}: put it on a file system "
                "every worker mounts, at the same path")


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
    check_workers_see(client, input, workspace)
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


def _worker_peak_rss_mb():
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def bench_scale(client, views=(250, 500, 1000, 2000), points_per_view=300, cluster_views=200, overlap=0.3,
                seed=0, progress=None):
    """`handheld bench scale`'s split-and-merge on a Dask cluster: for each size of testkit's walk
    round a block (exact truth, synthetic correspondences), one task per cluster, then the merge
    and the global adjustment here. Returns one run per size (as the Rust benchmark's `runs`, mode
    `split-dask`; `peak_rss_mb` is the largest worker's peak, the driver's merge included), and
    `exponent`, the slope of log(seconds) against log(views)."""
    import math
    import time

    from dask.distributed import as_completed

    runs = []
    for n in views:
        t = time.perf_counter()
        k = _handheld.scale_clusters(n, points_per_view, cluster_views, overlap, seed)
        futures = client.map(_handheld.scale_cluster, [n] * k, range(k), [points_per_view] * k,
                             [cluster_views] * k, [overlap] * k, [seed] * k, pure=False)
        outcomes = [None] * k
        index = {f.key: i for i, f in enumerate(futures)}
        for done, f in enumerate(as_completed(futures), 1):
            outcomes[index[f.key]] = f.result()
            if progress is not None:
                progress(f"{n} views: clusters", done, k)
        run = _handheld.scale_merge(n, outcomes, time.perf_counter() - t, points_per_view, cluster_views,
                                    overlap, seed)
        workers = client.run(_worker_peak_rss_mb)
        run["peak_rss_mb"] = max([run.get("peak_rss_mb") or 0.0] + list(workers.values()))
        run["workers"] = len(workers)
        runs.append(run)
    pts = [(math.log(r["views"]), math.log(max(r["seconds"], 1e-6))) for r in runs if r.get("error") is None]
    exponent = None
    if len(pts) >= 2:
        mx = sum(p[0] for p in pts) / len(pts)
        my = sum(p[1] for p in pts) / len(pts)
        sxx = sum((p[0] - mx) ** 2 for p in pts)
        if sxx > 0:
            exponent = sum((p[0] - mx) * (p[1] - my) for p in pts) / sxx
    return {"runs": runs, "exponent_split": exponent}
