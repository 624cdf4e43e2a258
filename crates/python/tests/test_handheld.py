"""The Python package against ground truth: iclnuim-5 (synthetic living room, exact poses) is
reconstructed through `handheld.reconstruct`, read back through `handheld.Workspace`, and scored
with ../shared/tools/eval_sfm.py. Run by `scripts/test.sh` after `cargo test`.

Without ../shared/datasets the data tests are skipped with a message; under CI they fail.
"""

import json
import os
import pathlib
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

import handheld

HERE = pathlib.Path(__file__).resolve()
# crates/python/tests/ in the repository; anywhere else (tests run against an installed wheel), set
# HANDHELD_DATASETS, HANDHELD_EVAL_SFM and HANDHELD_BIN.
REPO = HERE.parents[3] if len(HERE.parents) > 3 else HERE.parent
DATASETS = pathlib.Path(os.environ.get("HANDHELD_DATASETS", REPO.parent / "shared" / "datasets"))
EVAL_SFM = pathlib.Path(os.environ.get("HANDHELD_EVAL_SFM", DATASETS.parent / "tools" / "eval_sfm.py"))
ICL = DATASETS / "iclnuim-5"


def need(path):
    if not path.exists():
        if os.environ.get("CI"):
            pytest.fail(f"{path} is missing (CI needs ../shared)")
        pytest.skip(f"{path} is missing: put the shared data sets at {DATASETS} or set HANDHELD_DATASETS")


@pytest.fixture(scope="module")
def icl_ws(tmp_path_factory):
    """iclnuim-5 reconstructed up to the sparse model, with the progress calls it made."""
    need(ICL)
    ws = tmp_path_factory.mktemp("icl") / "ws"
    calls = []
    reports = handheld.reconstruct(ICL / "images", ws, until="sparse", progress=lambda *a: calls.append(a))
    return ws, reports, calls


# Options ------------------------------------------------------------------------------------


def test_default_options_round_trip():
    d = handheld.default_options()
    assert set(d) >= {"ingest", "features", "matches", "sparse", "dense", "mesh", "render"}
    assert handheld.check_options(d) == d
    assert handheld.check_options(None) == d
    # A dict names only what it changes; the rest keeps its default.
    changed = handheld.check_options({"sparse": {"sfm": {"seed": 7}}})
    assert changed["sparse"]["sfm"]["seed"] == 7
    assert changed["dense"] == d["dense"]
    # The JSON the manifests record.
    assert json.loads(json.dumps(changed)) == changed


@pytest.mark.parametrize(
    "options, named",
    [
        ({"sparse": {"sfm": {"sede": 1}}}, "sparse.sfm.sede"),
        ({"bogus": 1}, "bogus"),
        ({"sparse": {"sfm": {"seed": "x"}}}, "sparse.sfm.seed"),
        ({"matches": {"verification": {"guided_max_epipolar_px": -1.0}}}, "guided_max_epipolar_px"),
    ],
)
def test_wrong_option_is_named(options, named):
    with pytest.raises(handheld.OptionsError, match=named.replace(".", r"\.")):
        handheld.check_options(options)
    with pytest.raises(handheld.OptionsError, match=named.replace(".", r"\.")):
        handheld.reconstruct("/nonexistent", "/nonexistent-ws", options=options)


def test_an_enum_option_takes_another_variant():
    o = handheld.check_options({"mesh": {"fusion": {"tsdf": {"voxel_size": {"absolute": 0.1}}}}})
    assert o["mesh"]["fusion"]["tsdf"]["voxel_size"] == {"absolute": 0.1}


def test_options_must_be_a_dict():
    with pytest.raises(handheld.OptionsError, match="dict"):
        handheld.check_options([1, 2])
    assert issubclass(handheld.OptionsError, handheld.HandheldError)


# Errors -------------------------------------------------------------------------------------


def test_error_is_the_cli_message(tmp_path):
    missing = tmp_path / "no-such-photos"
    with pytest.raises(handheld.HandheldError) as py_error:
        handheld.reconstruct(missing, tmp_path / "ws")
    assert str(missing) in str(py_error.value)
    cli = cli_or_skip()
    run = subprocess.run([str(cli), "--quiet", "reconstruct", str(missing), "-o", str(tmp_path / "ws2")],
                         capture_output=True, text=True)
    assert run.returncode == 1
    assert run.stderr.strip() == "error: " + str(py_error.value).replace(str(tmp_path / "ws"), str(tmp_path / "ws2"))


def test_workspace_errors(tmp_path):
    with pytest.raises(handheld.HandheldError, match="not a workspace"):
        handheld.Workspace(tmp_path / "nothing-here")
    ws = handheld.Workspace(tmp_path)
    assert ws.stages() == []
    assert ws.summary("sparse") is None
    with pytest.raises(handheld.HandheldError, match="sparse"):
        ws.sparse()
    with pytest.raises(handheld.HandheldError, match="dense stage"):
        ws.depth("1.png")
    with pytest.raises(handheld.HandheldError, match="mesh stage"):
        ws.mesh()


# Reconstruction and the sparse model --------------------------------------------------------


def test_reconstruct_reports_stages_and_progress(icl_ws):
    ws, reports, calls = icl_ws
    assert [r["stage"] for r in reports] == ["ingest", "features", "matches", "sparse"]
    assert all(r["status"] == "ran" and r["seconds"] >= 0 for r in reports)
    assert reports[-1]["summary"]["registered"] == 5
    assert calls and all(isinstance(s, str) and isinstance(d, int) and isinstance(t, int) for s, d, t in calls)
    assert "matching pairs" in {s for s, _, _ in calls}
    w = handheld.Workspace(ws)
    assert w.stages() == ["ingest", "features", "matches", "sparse"]
    assert w.summary("sparse")["registered"] == 5
    assert set(w.timings()) == {"ingest", "features", "matches", "sparse"}


def test_sparse_model_arrays_and_conventions(icl_ws):
    ws, _, _ = icl_ws
    m = handheld.Workspace(ws).sparse()
    n = len(m)
    assert n == 5 and m.image_names == ["1.png", "2.png", "3.png", "4.png", "5.png"]
    assert m.rotations.shape == (n, 3, 3) and m.translations.shape == (n, 3) and m.quaternions.shape == (n, 4)
    for R, t, q, c, K, cam in zip(m.rotations, m.translations, m.quaternions, m.centers, m.intrinsics, m.camera_ids):
        assert np.allclose(R @ R.T, np.eye(3), atol=1e-9) and np.isclose(np.linalg.det(R), 1.0)
        x, y, z, w = q  # pycolmap's Rotation3d.quat order
        Rq = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                       [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                       [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
        assert np.allclose(R, Rq, atol=1e-9)
        assert np.allclose(c, -R.T @ t)
        assert np.allclose(K, m.cameras[int(cam)]["K"])
    cam = m.cameras[int(m.camera_ids[0])]
    assert cam["model"] == "SIMPLE_RADIAL" and (cam["width"], cam["height"]) == (640, 480)
    assert m.xyz.shape == (len(m.point_ids), 3) and m.rgb.dtype == np.uint8
    assert (m.track_lengths >= 2).all() and (m.errors >= 0).all()
    # Keypoints and 3D points agree: each point reprojects near the keypoints that observe it.
    xyz = dict(zip(m.point_ids.tolist(), m.xyz))
    p = cam["params"]
    for i in range(n):
        xy, ids = m.keypoints(i)
        seen = ids >= 0
        X = np.array([xyz[k] for k in ids[seen]])
        Xc = X @ m.rotations[i].T + m.translations[i]
        u = Xc[:, :2] / Xc[:, 2:]
        r2 = (u ** 2).sum(1, keepdims=True)
        proj = p[0] * u * (1 + p[3] * r2) + p[1:3]
        assert np.median(np.linalg.norm(proj - xy[seen], axis=1)) < 0.5
    with pytest.raises(IndexError):
        m.keypoints(n)
    # The same poses as the COLMAP text model of the workspace (cam_from_world, w x y z).
    text = read_colmap_images_txt(ws / "sparse" / "images.txt")
    assert sorted(text) == sorted(m.image_names)
    for name, R, t in zip(m.image_names, m.rotations, m.translations):
        assert np.allclose(R, text[name][0], atol=1e-6) and np.allclose(t, text[name][1], atol=1e-6)


def test_sparse_model_is_accurate(icl_ws):
    """The model the package reads back, scored against the ground truth by the shared tool."""
    ws, _, _ = icl_ws
    need(EVAL_SFM)
    out = subprocess.run([sys.executable, str(EVAL_SFM), str(ws / "sparse"), str(ICL)],
                         capture_output=True, text=True, check=True)
    score = json.loads(out.stdout)
    assert score["registered"] == 5
    assert score["focal_err_pct_median"] < 1.0
    assert score["rot_err_deg_median"] < 0.6  # the ground truth itself is ~0.4° from the images
    assert score["auc@5"] > 80


def cli_or_skip():
    cli = pathlib.Path(os.environ.get("HANDHELD_BIN", REPO / "target" / "debug" / "handheld"))
    if not cli.exists():
        if os.environ.get("CI"):
            pytest.fail(f"{cli} is not built")
        pytest.skip(f"{cli} is not built (cargo build -p handheld, or set HANDHELD_BIN)")
    return cli


def read_colmap_images_txt(path):
    """name -> (R, t) from a COLMAP images.txt (cam_from_world, quaternion w x y z)."""
    out = {}
    lines = [l for l in path.read_text().splitlines() if l and not l.startswith("#")]
    for line in lines[0::2]:
        v = line.split()
        w, x, y, z = map(float, v[1:5])
        R = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                      [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                      [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
        out[v[9]] = (R, np.array(list(map(float, v[5:8]))))
    return out


def test_reconstruct_the_demo_sequence(tmp_path):
    """`handheld demo`'s synthetic hand-held orbit (exact ground truth, rendered by the CLI),
    reconstructed through the package: every frame, the focal length and the relative rotations."""
    cli = cli_or_skip()
    subprocess.run([str(cli), "--quiet", "demo", "-o", str(tmp_path / "demo"), "--until", "ingest",
                    "--frames", "12"], check=True)
    ws = tmp_path / "ws"
    handheld.reconstruct(tmp_path / "demo" / "images", ws, until="sparse")
    m = handheld.Workspace(ws).sparse()
    truth = read_colmap_images_txt(tmp_path / "demo" / "ground_truth" / "sparse" / "images.txt")
    assert sorted(m.image_names) == sorted(truth)
    f_true = float((tmp_path / "demo" / "ground_truth" / "sparse" / "cameras.txt").read_text()
                   .splitlines()[-1].split()[4])
    f = m.cameras[int(m.camera_ids[0])]["params"][0]
    assert abs(f / f_true - 1) < 0.02, (f, f_true)
    R = dict(zip(m.image_names, m.rotations))
    worst = 0.0
    for a in m.image_names:
        for b in m.image_names:
            Re = R[b] @ R[a].T
            Rg = truth[b][0] @ truth[a][0].T
            c = (np.trace(Rg.T @ Re) - 1) / 2
            worst = max(worst, np.degrees(np.arccos(np.clip(c, -1, 1))))
    assert worst < 1.0, worst


def test_a_module_for_another_python_is_one_clear_error(tmp_path):
    """The compiled module replaced by one that cannot load (as a wheel for another Python or
    platform): importing the package says so, and what to do."""
    pkg = pathlib.Path(handheld.__file__).parent
    copy = tmp_path / "handheld"
    copy.mkdir()
    for f in pkg.glob("*.py"):
        (copy / f.name).write_bytes(f.read_bytes())
    (copy / "_handheld.abi3.so").write_bytes(b"not a shared object")
    run = subprocess.run([sys.executable, "-c", "import handheld"], cwd=tmp_path, capture_output=True, text=True,
                         env={**os.environ, "PYTHONPATH": str(tmp_path)})
    assert run.returncode == 1
    assert "its compiled module does not load in this Python" in run.stderr and "maturin" in run.stderr


def test_long_calls_release_the_gil(tmp_path):
    need(ICL)
    done = threading.Event()
    errors = []

    def work():
        try:
            handheld.reconstruct(ICL / "images", tmp_path / "ws", until="features")
        except Exception as e:  # noqa: BLE001 - reported below
            errors.append(e)
        finally:
            done.set()

    thread = threading.Thread(target=work)
    spins = 0
    t0 = time.perf_counter()
    thread.start()
    while not done.is_set():
        spins += 1
    thread.join()
    assert not errors, errors
    # Held for the whole call, the GIL would let this loop run only between bytecodes of the
    # worker; released, it spins freely for the whole extraction.
    assert time.perf_counter() - t0 > 0.2 and spins > 10000


def test_progress_callback_exception_is_raised(tmp_path):
    need(ICL)

    def bad(step, done, total):
        raise ZeroDivisionError("from the callback")

    with pytest.raises(ZeroDivisionError, match="from the callback"):
        handheld.reconstruct(ICL / "images", tmp_path / "ws", until="features", progress=bad)
    # The run itself finished: the stage resumes as up to date.
    again = handheld.reconstruct(ICL / "images", tmp_path / "ws", until="features")
    assert [r["status"] for r in again] == ["up_to_date", "up_to_date"]


# Dense and mesh -----------------------------------------------------------------------------


def test_depth_maps_and_mesh(icl_ws):
    ws, _, _ = icl_ws
    reports = handheld.reconstruct(ICL / "images", ws, until="mesh")
    status = {r["stage"]: r["status"] for r in reports}
    assert status["sparse"] == "up_to_date" and status["mesh"] == "ran"
    w = handheld.Workspace(ws)
    m = w.sparse()
    names = w.depth_images()
    assert names == m.image_names
    checked = 0
    for name in names:
        d = w.depth(name)
        depth, cam, R, t = d["depth"], d["camera"], d["R"], d["t"]
        assert depth.dtype == np.float32 and depth.shape == (cam["height"], cam["width"])
        assert d["confidence"].shape == depth.shape
        valid = np.isfinite(depth) & (depth > 0)
        if valid.sum() < 1000:
            continue  # a view whose pairs failed (the mesh stage names it)
        # The depth map agrees with the sparse points it sees (pinhole; k1 is ~5e-4 here).
        Xc = m.xyz @ R.T + t
        front = Xc[:, 2] > 0
        uv = Xc[front, :2] / Xc[front, 2:] * cam["params"][0] + cam["params"][1:3] - 0.5
        px = np.round(uv).astype(int)
        inside = (px[:, 0] >= 0) & (px[:, 0] < cam["width"]) & (px[:, 1] >= 0) & (px[:, 1] < cam["height"])
        z = Xc[front][inside, 2]
        dz = depth[px[inside, 1], px[inside, 0]]
        ok = np.isfinite(dz) & (dz > 0)
        if ok.sum() >= 50:
            assert np.median(np.abs(dz[ok] - z[ok]) / z[ok]) < 0.02
            checked += 1
    assert checked >= 2
    mesh = w.mesh()
    v, f = mesh["vertices"], mesh["faces"]
    assert v.dtype == np.float32 and v.shape[1] == 3 and f.dtype == np.uint32 and f.shape[1] == 3
    assert len(f) > 1000 and f.max() < len(v)
    assert mesh["uvs"].shape == (len(v), 2) and (mesh["uvs"] >= 0).all() and (mesh["uvs"] <= 1).all()
    tex = mesh["texture"]
    assert tex.dtype == np.uint8 and tex.ndim == 3 and tex.shape[2] == 3 and tex.std() > 5
    warnings = w.warnings("mesh")
    assert all({"code", "message"} <= set(x) for x in warnings)
