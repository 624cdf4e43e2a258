"""`python -m handheld reconstruct INPUT -o WORKSPACE [--scheduler tcp://HOST:8786 | --local-workers N]`

Without a scheduler, the run is `handheld.reconstruct` on this machine; with one, it is
`handheld.distributed.reconstruct` on that Dask cluster (the workspace on a file system every
worker sees). `--local-workers N` starts a `LocalCluster` of N single-threaded processes.
"""

import argparse
import json
import sys

import handheld


def main(argv=None):
    parser = argparse.ArgumentParser(prog="python -m handheld", description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    r = sub.add_parser("reconstruct", help="images or a video -> a workspace (as `handheld reconstruct`)")
    r.add_argument("input", help="a folder of photos, or a video file")
    r.add_argument("-o", "--output", required=True, help="the workspace folder")
    r.add_argument("--until", help=f"stop after this stage ({', '.join(handheld.STAGES)})")
    r.add_argument("--options", help="a JSON file of options (the form of handheld.default_options())")
    r.add_argument("--force", action="store_true", help="redo every stage")
    where = r.add_mutually_exclusive_group()
    where.add_argument("--scheduler", help="a Dask scheduler's address, e.g. tcp://HOST:8786")
    where.add_argument("--local-workers", type=int, metavar="N", help="run on a LocalCluster of N processes")
    r.add_argument("--quiet", action="store_true", help="print nothing but errors")
    r.add_argument("--json", action="store_true", help="print the stage reports as one JSON object")
    b = sub.add_parser("bench-scale", help="split-and-merge on synthetic walks, one Dask task per cluster")
    b.add_argument("--views", default="250,500,1000,2000", help="sizes, comma-separated")
    b.add_argument("--cluster-views", type=int, default=200)
    b.add_argument("--points-per-view", type=int, default=300)
    b.add_argument("--seed", type=int, default=0)
    bw = b.add_mutually_exclusive_group()
    bw.add_argument("--scheduler", help="a Dask scheduler's address")
    bw.add_argument("--local-workers", type=int, default=2, metavar="N", help="a LocalCluster of N processes")
    a = parser.parse_args(argv)
    if a.command == "bench-scale":
        return bench_scale_main(a)

    try:
        options = None
        if a.options:
            try:
                with open(a.options) as f:
                    options = json.load(f)
            except (OSError, ValueError) as e:
                raise handheld.OptionsError(f"{a.options}: cannot read the options ({e})") from None

        def progress(step, done, total):
            if not a.quiet and not a.json:
                print(f"\r{step}: {done}/{total or '?'}   ", end="", file=sys.stderr, flush=True)

        if a.scheduler or a.local_workers:
            from dask.distributed import Client, LocalCluster

            from handheld.distributed import reconstruct as reconstruct_on

            if a.scheduler:
                client = connect(a.scheduler)
            else:
                if a.local_workers < 1:
                    raise handheld.OptionsError(f"--local-workers: must be at least 1, got {a.local_workers}")
                client = Client(LocalCluster(n_workers=a.local_workers, threads_per_worker=1))
            with client:
                reports = reconstruct_on(a.input, a.output, client, options, a.until, a.force, progress)
        else:
            reports = handheld.reconstruct(a.input, a.output, options, a.until, a.force, progress)
    except handheld.HandheldError as e:
        if a.json:
            print(json.dumps({"error": str(e)}))
        print(f"\nerror: {e}" if not a.quiet and not a.json else f"error: {e}", file=sys.stderr)
        return 1
    if a.json:
        print(json.dumps({"workspace": a.output, "stages": reports}))
    elif not a.quiet:
        print(file=sys.stderr)
        for rep in reports:
            print(f"  {rep['stage']:<10} {rep['status']:<10} {rep['seconds']:7.2f} s")
    return 0


def connect(address, timeout="10s"):
    """A client of the scheduler at `address`, or `HandheldError` saying it cannot be reached."""
    from dask.distributed import Client

    try:
        return Client(address, timeout=timeout)
    except (OSError, TimeoutError) as e:
        raise handheld.HandheldError(
            f"cannot reach the Dask scheduler at {address} ({e.__class__.__name__}: {e}): start it "
            "(`dask scheduler`), or check the address and the port") from None


def bench_scale_main(a):
    from dask.distributed import Client, LocalCluster

    from handheld.distributed import bench_scale

    try:
        views = [int(v) for v in a.views.split(",")]
        client = (connect(a.scheduler) if a.scheduler
                  else Client(LocalCluster(n_workers=a.local_workers, threads_per_worker=1)))
        with client:
            out = bench_scale(client, views, a.points_per_view, a.cluster_views, seed=a.seed)
    except (ValueError, handheld.HandheldError) as e:
        print(json.dumps({"error": str(e)}))
        return 1
    print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
