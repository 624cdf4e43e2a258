"""The pipeline on Dask distributed (a LocalCluster of worker processes), against the same run on
one machine: bundler-ET (9 photos: 9 feature units, 36 pairs in 3 units of matching, 8 dense pairs).
"""

import hashlib
import json
import os
import pathlib
import shutil
import subprocess
import sys

import pytest

import handheld
from handheld import _handheld

distributed = pytest.importorskip("dask.distributed")
import handheld.distributed  # noqa: E402

from test_handheld import DATASETS, need  # noqa: E402

ET = DATASETS / "bundler-ET"


@pytest.fixture(scope="module")
def client():
    cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0")
    with distributed.Client(cluster) as c:
        yield c
    cluster.close()


@pytest.fixture(scope="module")
def runs(tmp_path_factory, client):
    """bundler-ET up to the depth maps, on one machine and on the cluster."""
    need(ET)
    root = tmp_path_factory.mktemp("et")
    single = handheld.reconstruct(ET / "images", root / "single", until="dense")
    calls = []
    dist = handheld.distributed.reconstruct(ET / "images", root / "dist", client, until="dense",
                                            progress=lambda *a: calls.append(a))
    return root, single, dist, calls


def digest(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


def without_timing(summary):
    """A summary without its clock readings (`*seconds*`, `timings_s`), at any depth."""
    def strip(v):
        if isinstance(v, dict):
            return {k: strip(x) for k, x in v.items() if "seconds" not in k and k != "timings_s"}
        if isinstance(v, list):
            return [strip(x) for x in v]
        return v
    return strip(json.loads(summary.read_text()))


def test_same_files_as_one_machine(runs):
    root, single, dist, calls = runs
    stages = ["ingest", "features", "matches", "sparse", "dense"]
    assert [r["stage"] for r in dist] == [r["stage"] for r in single] == stages
    assert all(r["status"] == "ran" for r in dist)
    assert ("features units", 9, 9) in calls and ("matches units", 3, 3) in calls and ("dense units", 8, 8) in calls
    compared = 0
    for stage in ["features", "matches", "sparse", "dense"]:
        for a in sorted((root / "single" / stage).rglob("*")):
            if a.is_dir() or a.name == "manifest.json":
                continue
            b = root / "dist" / a.relative_to(root / "single")
            assert b.is_file(), b
            if a.name == "summary.json":
                # The only difference a run on other machines can make: how long it took.
                assert without_timing(a) == without_timing(b), a
            else:
                assert digest(a) == digest(b), a
            compared += 1
    # feature files, thumbnails, database + pairs, the COLMAP model, 4 maps and 2 previews per view
    assert compared >= 9 + 9 + 2 + 6 + 9 * 6
    assert not (root / "dist" / ".units").exists()
    # The manifests agree on everything but the clock.
    for stage in ["features", "matches", "sparse", "dense"]:
        m1, m2 = (json.loads((root / w / stage / "manifest.json").read_text()) for w in ("single", "dist"))
        assert m1["input_hash"] == m2["input_hash"] and m1["outputs"] == m2["outputs"]
    # A distributed workspace is a workspace: the single-machine run finds it up to date.
    again = handheld.reconstruct(ET / "images", root / "dist", until="dense")
    assert {r["status"] for r in again} == {"up_to_date"}


def test_a_retried_unit_is_harmless(tmp_path):
    need(ET)
    ws = tmp_path / "ws"
    handheld.reconstruct(ET / "images", ws, until="ingest")
    images = str(ET / "images")
    assert _handheld.stage_units(images, str(ws), "features") == 9
    _handheld.run_unit(images, str(ws), "features", 3)
    done = list((ws / ".units" / "features").rglob("000003.feat"))
    assert len(done) == 1
    mtime = done[0].stat().st_mtime_ns
    _handheld.run_unit(images, str(ws), "features", 3)  # a retry after the unit finished: nothing
    assert done[0].stat().st_mtime_ns == mtime
    # A worker that died half-way leaves only its own temporary folder, which nothing reads.
    (done[0].parent / "tmp-5-1-1").mkdir()
    (done[0].parent / "tmp-5-1-1" / "000005.feat").write_bytes(b"half")
    report = _handheld.run_stage(images, str(ws), "features")
    assert report["status"] == "ran" and report["summary"]["images"] == 9
    assert handheld.Workspace(ws).stages() == ["ingest", "features"]
    with pytest.raises(handheld.HandheldError, match="no unit 9"):
        _handheld.run_unit(images, str(ws), "features", 9)


def test_errors_come_back_from_the_workers(tmp_path, client):
    need(ET)
    one = tmp_path / "one"
    one.mkdir()
    (one / "a.jpg").write_bytes((ET / "images" / "et000.jpg").read_bytes())
    with pytest.raises(handheld.HandheldError) as local:
        handheld.reconstruct(one, tmp_path / "ws1", until="features")
    with pytest.raises(handheld.HandheldError) as remote:
        handheld.distributed.reconstruct(one, tmp_path / "ws2", client, until="features")
    assert str(remote.value) == str(local.value).replace("ws1", "ws2")
    with pytest.raises(handheld.OptionsError, match="sparse.sfm.sede"):
        handheld.distributed.reconstruct(one, tmp_path / "ws3", client, options={"sparse": {"sfm": {"sede": 1}}})


def test_python_m_handheld_on_a_scheduler(runs, client, tmp_path):
    root, _, _, _ = runs
    ws = tmp_path / "ws"
    run = subprocess.run([sys.executable, "-m", "handheld", "reconstruct", str(ET / "images"), "-o", str(ws),
                          "--until", "features", "--scheduler", client.scheduler.address, "--json"],
                         capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    out = json.loads(run.stdout)
    assert [s["stage"] for s in out["stages"]] == ["ingest", "features"]
    for f in (root / "single" / "features").glob("*.feat"):
        assert digest(f) == digest(ws / "features" / f.name)
    bad = subprocess.run([sys.executable, "-m", "handheld", "reconstruct", str(tmp_path / "nothing"), "-o",
                          str(tmp_path / "ws2"), "--quiet"], capture_output=True, text=True)
    assert bad.returncode == 1 and "nothing" in bad.stderr


def test_a_killed_worker_changes_nothing(runs, tmp_path):
    """A worker process killed while it holds units: Dask runs its tasks again elsewhere, the
    units it left half-done are redone whole, and the files are those of the single run."""
    import signal
    import threading

    root, _, _, _ = runs
    cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0")
    try:
        with distributed.Client(cluster) as c:
            pids = c.run(os.getpid)
            killed = threading.Event()

            def kill_once(step, done, total):
                # After the first few feature units, while the others are running or queued.
                if step == "features units" and done == 2 and not killed.is_set():
                    killed.set()
                    os.kill(next(iter(pids.values())), signal.SIGKILL)

            ws = tmp_path / "ws"
            handheld.distributed.reconstruct(ET / "images", ws, c, until="matches", progress=kill_once)
            assert killed.is_set()
    finally:
        cluster.close()
    for stage in ["features", "matches"]:
        for a in sorted((root / "single" / stage).rglob("*")):
            if a.is_file() and a.name not in ("manifest.json", "summary.json"):
                assert digest(a) == digest(ws / a.relative_to(root / "single")), a
    assert not (ws / ".units").exists()


SPLIT = {"sparse": {"sfm": {"split": {"above": 4, "cluster_views": 8, "overlap": 0.3}}}}


def test_split_and_merge_runs_a_cluster_per_task(runs, client):
    """bundler-ET cut into clusters of at most 8 views: each cluster is a task on the cluster, and the
    merged model is the one the same options give on one machine, byte for byte."""
    root = runs[0]
    for name in ["split-single", "split-dist"]:
        for stage in ["ingest", "features", "matches"]:
            shutil.copytree(root / "single" / stage, root / name / stage)
    handheld.reconstruct(ET / "images", root / "split-single", options=SPLIT, until="sparse")
    calls = []
    handheld.distributed.reconstruct(ET / "images", root / "split-dist", client, options=SPLIT,
                                     until="sparse", progress=lambda *a: calls.append(a))
    summary = json.loads((root / "split-single" / "sparse" / "summary.json").read_text())
    clusters = len(summary["split"]["clusters"])
    assert clusters >= 2, summary["split"]
    assert ("sparse units", clusters, clusters) in calls, calls
    for f in ["cameras.bin", "images.bin", "points3D.bin"]:
        a, b = (root / n / "sparse" / f for n in ["split-single", "split-dist"])
        assert digest(a) == digest(b), f
    a, b = (root / n / "sparse" / "summary.json" for n in ["split-single", "split-dist"])
    assert without_timing(a) == without_timing(b)


def test_bench_scale_runs_the_clusters_as_tasks(client):
    """The scale benchmark's split-and-merge on the cluster: a short walk (exact truth) cut into
    clusters of at most 24 views, one task each, merged, scored."""
    out = handheld.distributed.bench_scale(client, views=[60], points_per_view=200, cluster_views=24)
    (run,) = out["runs"]
    assert run["error"] is None and run["mode"] == "split-dask"
    assert run["clusters"] >= 3 and run["registered"] == 60 and not run["split"]["apart"], run["split"]
    assert run["auc5"] > 90 and run["focal_error_pct"] < 1.0, run


def test_an_unreachable_scheduler_is_one_clear_error(tmp_path):
    run = subprocess.run([sys.executable, "-m", "handheld", "reconstruct", str(tmp_path), "-o", str(tmp_path / "ws"),
                          "--scheduler", "tcp://127.0.0.1:9"], capture_output=True, text=True, timeout=120)
    assert run.returncode == 1
    assert "cannot reach the Dask scheduler at tcp://127.0.0.1:9" in run.stderr, run.stderr
    assert "Traceback" not in run.stderr


def test_a_worker_that_cannot_see_the_workspace_is_named(tmp_path):
    """What a worker on a machine without the shared file system reports (a LocalCluster's workers
    share this one's, so the worker's answer is given here)."""
    class Blind:
        def run(self, f, *args):
            return {"tcp://10.0.0.7:40000": ("node7", True, False)}

    with pytest.raises(handheld.HandheldError, match="tcp://10.0.0.7:40000 .on node7. cannot see the workspace"):
        handheld.distributed.check_workers_see(Blind(), str(tmp_path), str(tmp_path / "ws"))
    assert not list((tmp_path / "ws").glob(".handheld-probe-*"))
