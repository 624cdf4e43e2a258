#!/usr/bin/env python3
"""The same run on one machine and on Dask: `handheld reconstruct` (the CLI binary BIN) and
`handheld.distributed.reconstruct` on a LocalCluster of WORKERS single-threaded processes, into
OUT/<set>-cli and OUT/<set>-dist, then every file of the stage folders compared byte for byte
(`manifest.json` and `summary.json` hold clock readings and are left out). Prints one JSON object.

    PYTHONPATH=crates/python/python python3 scripts/dist_check.py BIN ../shared/datasets/fountain-P11 mesh OUT [WORKERS [OPTIONS_JSON CLI_ARG...]]

OPTIONS_JSON (for the cluster run) and the CLI arguments after it must ask for the same options, e.g.
`'{"mesh": {"fusion": {"tsdf": {"voxel_size": {"absolute": 0.1}}}}}' --voxel-size 0.1`.

Build the CLI and the module together (`cargo build --release -p handheld -p handheld-python`) so
that both have the same features, and put `target/release/lib_handheld.so` beside the package as
`_handheld.abi3.so` (what `maturin develop --release` does).
"""
import hashlib
import json
import pathlib
import subprocess
import sys
import time

import handheld
import handheld.distributed
from dask.distributed import Client, LocalCluster

STAGES = ["features", "matches", "sparse", "dense", "mesh"]


def digest(p):
    return hashlib.sha256(p.read_bytes()).hexdigest()


def main():
    cli, data, until, out = sys.argv[1], pathlib.Path(sys.argv[2]), sys.argv[3], pathlib.Path(sys.argv[4])
    workers = int(sys.argv[5]) if len(sys.argv) > 5 else 2
    options = json.loads(sys.argv[6]) if len(sys.argv) > 6 else None
    cli_args = sys.argv[7:]
    images = data / "images"
    cli_ws, dist_ws = out / f"{data.name}-cli", out / f"{data.name}-dist"
    t = time.time()
    subprocess.run([cli, "--quiet", "reconstruct", str(images), "-o", str(cli_ws), "--until", until, *cli_args],
                   check=False)
    t_cli = time.time() - t
    error = None
    with Client(LocalCluster(n_workers=workers, threads_per_worker=1, dashboard_address=":0")) as c:
        t = time.time()
        try:
            handheld.distributed.reconstruct(images, dist_ws, c, options=options, until=until)
        except handheld.HandheldError as e:
            error = str(e)
        t_dist = time.time() - t
    same, differ, missing = 0, [], []
    for stage in STAGES:
        if not (cli_ws / stage).exists():
            continue
        for a in sorted((cli_ws / stage).rglob("*")):
            if not a.is_file() or a.name in ("manifest.json", "summary.json"):
                continue
            b = dist_ws / a.relative_to(cli_ws)
            if not b.is_file():
                missing.append(str(a.relative_to(cli_ws)))
            elif digest(a) == digest(b):
                same += 1
            else:
                differ.append(str(a.relative_to(cli_ws)))
    print(json.dumps({
        "set": data.name, "until": until, "workers": workers,
        "stages_done": [s for s in STAGES if (cli_ws / s / "manifest.json").exists()],
        "cli_seconds": round(t_cli, 1), "distributed_seconds": round(t_dist, 1), "distributed_error": error,
        "files_identical": same, "files_differing": differ, "files_missing": missing,
    }))


if __name__ == "__main__":
    main()
