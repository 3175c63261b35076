"""subdfit's Python API: the CLI's bytes and messages, arrays, errors,
progress, cancellation, fit and limit."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import numpy as np
import pytest

import subdfit
from conftest import REPO, SPOT, assert_same_outputs, icosphere, stable_report


@pytest.fixture(scope="module")
def spot():
    m = subdfit.read(REPO / SPOT)
    return m, subdfit.convert(m.vertices, m.faces, name=SPOT)


@pytest.fixture(scope="module")
def ball():
    v, f = icosphere(3, bumps=0.1)
    return v, f, subdfit.convert(v, f)


def test_convert_spot_writes_the_clis_bytes(spot, cli, tmp_path):
    cli("convert", SPOT, "-o", tmp_path / "cli", "--quiet")
    _, r = spot
    written = r.write(tmp_path / "py")
    assert {p.name for p in written} >= {"control.obj", "report.json", "displacement.exr"}
    assert_same_outputs(tmp_path / "py", tmp_path / "cli")
    assert r.control_obj == (tmp_path / "cli/control.obj").read_bytes()
    cli_report = stable_report(tmp_path / "cli/report.json")
    assert cli_report["options"]["run"]["run"]["mesh"] == SPOT
    # Every report.json number is in metrics, with the CLI's value.
    def leaves(v, key=""):
        if isinstance(v, dict):
            for k, x in v.items():
                yield from leaves(x, f"{key}.{k}" if key else k)
        elif isinstance(v, list):
            for i, x in enumerate(v):
                yield from leaves(x, f"{key}[{i}]")
        elif isinstance(v, (int, float)) and not isinstance(v, bool):
            yield key, float(v)
    want = dict(leaves(cli_report))
    assert len(want) > 50
    assert {k: r.metrics[k] for k in want} == want


def test_result_arrays_describe_the_control_mesh(spot):
    m, r = spot
    c = r.control
    n = len(c.positions)
    assert c.positions.shape == (n, 3) and c.positions.dtype == np.float64
    assert c.face_sizes.sum() == c.face_indices.size and c.face_indices.max() < n
    assert set(np.unique(c.face_sizes)) == {4}  # organic: all quads
    assert c.uv_indices.shape == c.face_indices.shape
    assert c.uvs.shape[1] == 2 and 0 <= c.uvs.min() and c.uvs.max() <= 1
    assert len(r.tiles) == r.tile_resolutions.size == c.face_sizes.size
    for t, res in zip(r.tiles, r.tile_resolutions):
        assert t.dtype == np.float32 and t.shape == (res, res) and res > 1
        assert np.isfinite(t).all()
    # Adaptive (the default): 2^k + 1 per side, several sizes on spot, and
    # the samples, each shared one counted once, within 5 % of the budget
    # (M's vertex count) — so the tiles hold more, their edges repeated.
    assert all(((res - 1) & (res - 2)) == 0 for res in r.tile_resolutions.tolist())
    assert len(set(r.tile_resolutions.tolist())) > 1
    budget = r.metrics["input.vertices"]
    assert abs(r.report["projectability"]["displacement"]["samples"] - budget) <= 0.05 * budget
    assert list(r.tile_faces) == list(range(c.face_sizes.size))
    assert r.metrics["control.faces"] == c.face_sizes.size
    assert r.metrics["input.vertices"] == len(m.vertices)
    assert r.report["control"]["vertices"] == n
    # The displacement brings the surface closer to the input than the limit.
    assert r.metrics["accuracy.displaced.rms_permille"] < r.metrics["accuracy.limit.rms_permille"]


def test_array_forms_give_the_same_result(ball):
    v, f, r = ball
    polys = [list(map(int, x)) for x in f]
    for other in (
        subdfit.convert(np.asfortranarray(v), f.astype(np.int32)),
        subdfit.convert(v.tolist(), polys),
        subdfit.convert(v, f.ravel(), face_sizes=np.full(len(f), 3)),
    ):
        assert other.control_obj == r.control_obj


BAD = [
    ("nan", lambda v, f: (np.where(np.arange(len(v))[:, None] == 2, np.nan, v), f), ["vertex 2", "NaN"]),
    ("2 columns", lambda v, f: (v[:, :2], f), ["(n, 3)", "shape"]),
    ("flat vertices", lambda v, f: (v.ravel(), f), ["(n, 3)"]),
    ("ragged", lambda v, f: ([[0, 0, 0], [1, 0]], f), ["vertices"]),
    ("strings", lambda v, f: (v.astype(str), f), ["vertices"]),
    ("index too large", lambda v, f: (v, np.where(f == f.max(), len(v), f)), ["face", str(len(icosphere(3)[0]))]),
    ("negative index", lambda v, f: (v, f - 1), ["faces", "-1"]),
    ("index above u32", lambda v, f: (v, f + 2**33), ["faces", "out of range"]),
    ("float faces", lambda v, f: (v, f.astype(float)), ["faces", "integers"]),
    ("3-d faces", lambda v, f: (v, f[None]), ["faces"]),
    ("empty", lambda v, f: (np.zeros((0, 3)), np.zeros((0, 3), int)), ["input mesh"]),
]


@pytest.mark.parametrize("case", BAD, ids=[c[0] for c in BAD])
def test_bad_arrays_raise_subdfit_error(case):
    _, make, words = case
    v, f = make(*icosphere(3))
    with pytest.raises(subdfit.Error) as e:
        subdfit.convert(v, f)
    assert isinstance(e.value, subdfit.InvalidInput)
    for w in words:
        assert w in str(e.value), str(e.value)


def test_every_convert_option_reaches_python():
    # One options type (subdfit::convert::ConvertOptions) behind every host:
    # the proxy and the tessellation are checked and applied as the CLI's.
    v, f = icosphere(3, bumps=0.1)
    c = subdfit.convert(v, f, tessellation=4, proxy="none", mode="organic")
    r = c.report
    assert r["tessellation"]["segments_per_patch_side"] == 4 and r["tessellation"]["given"]
    assert r["options"]["run"]["convert"]["proxy"] == "none"
    assert r["options"]["run"]["convert"]["tessellation"] == 4
    with pytest.raises(subdfit.InvalidInput, match="proxy"):
        subdfit.convert(v, f, proxy="99")
    with pytest.raises(subdfit.InvalidInput, match="tessellation"):
        subdfit.convert(v, f, tessellation=2000)
    # τ's range is the Fitmap's own, (0, 1].
    assert subdfit._subdfit.Options(tolerance=1.0).tolerance == 1.0


def test_bad_sizes_and_options_raise_subdfit_error():
    v, f = icosphere(2)
    with pytest.raises(subdfit.InvalidInput, match="add up to"):
        subdfit.convert(v, f.ravel(), face_sizes=[3, 2**31])
    with pytest.raises(subdfit.InvalidInput, match="tolerance"):
        subdfit.convert(v, f, tolerance=2.0)
    with pytest.raises(subdfit.InvalidInput, match="mode"):
        subdfit.convert(v, f, mode="cad")
    with pytest.raises(subdfit.InvalidInput, match="faces: missing"):
        subdfit.convert(v)


def test_option_and_input_errors_have_distinct_kinds():
    # subdfit::ErrorKind reaches Python: an option out of its range is an
    # InvalidOption (a kind of InvalidInput, so older handlers still catch
    # it), a mesh that cannot be used an InvalidInput that is not one.
    v, f = icosphere(2)
    with pytest.raises(subdfit.InvalidOption, match="tolerance"):
        subdfit.convert(v, f, tolerance=2.0)
    with pytest.raises(subdfit.InvalidOption, match="mode"):
        subdfit.convert(v, f, mode="cad")
    bad = f.copy()
    bad[0, 0] = len(v) + 5
    with pytest.raises(subdfit.InvalidInput) as e:
        subdfit.convert(v, bad)
    assert not isinstance(e.value, subdfit.InvalidOption), repr(e.value)
    assert issubclass(subdfit.BackendError, subdfit.NumericalError)
    assert not issubclass(subdfit.InternalError, subdfit.InvalidInput)


def test_errors_carry_the_clis_message(cli, tmp_path):
    bad = tmp_path / "bad.off"
    bad.write_text("OFF\n4 2 0\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 1 2\n3 0 2 9\n")
    r = cli("convert", bad, "-o", tmp_path / "out", check=False)
    assert r.returncode == 2
    msg = r.stderr.strip().removeprefix("subdfit: error: ")
    assert str(bad) in msg and "face 1" in msg
    with pytest.raises(subdfit.InvalidInput) as e:
        subdfit.convert(subdfit.read(bad))
    assert str(e.value) == msg
    with pytest.raises(subdfit.FileError, match="missing.ply"):
        subdfit.read(tmp_path / "missing.ply")


def test_progress_reports_and_cancels(ball):
    v, f, _ = ball
    seen = []

    def progress(stage, fraction):
        seen.append((stage, fraction))
        return stage != "fit"

    with pytest.raises(subdfit.Cancelled, match="fit"):
        subdfit.convert(v, f, progress=progress)
    stages = [s for s, _ in seen]
    assert stages[0] == "read" and "simplify" in stages and stages[-1] == "fit"
    assert all(0 <= x <= 1 for _, x in seen)

    def boom(stage, fraction):
        raise ZeroDivisionError("from the callback")

    with pytest.raises(ZeroDivisionError, match="from the callback"):
        subdfit.convert(v, f, progress=boom)


def test_the_gil_is_released_while_converting():
    v, f = icosphere(4, bumps=0.1)
    done = threading.Event()
    box = {}

    def work():
        box["r"] = subdfit.convert(v, f)
        done.set()

    t = threading.Thread(target=work)
    t0 = time.monotonic()
    t.start()
    ticks = 0
    while not done.is_set():
        ticks += 1
        time.sleep(0.001)
    t.join()
    elapsed = time.monotonic() - t0
    # Held GIL: this thread would hardly run; released: ~1 tick per ms.
    assert ticks > 0.3 * elapsed * 1000, (ticks, elapsed)
    assert box["r"].metrics["control.faces"] > 0


# The child restores Python's own SIGINT handler first: a test runner started
# in the background of a non-interactive shell (`cmd &`) inherits SIGINT as
# ignored, Python then installs no handler, and the Ctrl-C this test sends
# would be dropped before it reached the binding ("finished" instead of
# "interrupted", seen once in session 10).
CTRL_C = textwrap.dedent("""
    import signal, sys, time, numpy as np, subdfit
    signal.signal(signal.SIGINT, signal.default_int_handler)
    d = np.load(sys.argv[1])
    started = []
    def progress(stage, fraction):
        if not started:
            started.append(1)
            print("started", flush=True)
    try:
        subdfit.convert(d["v"], d["f"], progress=progress)
        print("finished", flush=True)
    except KeyboardInterrupt:
        print("interrupted", time.monotonic(), flush=True)
""")


def test_ctrl_c_cancels_within_50ms(tmp_path):
    v, f = icosphere(6, bumps=0.1)  # 40962 vertices: seconds of work
    np.savez(tmp_path / "m.npz", v=v, f=f)
    p = subprocess.Popen([sys.executable, "-c", CTRL_C, str(tmp_path / "m.npz")],
                         stdout=subprocess.PIPE, text=True)
    assert p.stdout.readline().strip() == "started"
    time.sleep(1.5)  # well inside the conversion
    sent = time.monotonic()
    p.send_signal(2)  # SIGINT, as Ctrl-C
    out = p.stdout.read().split()
    p.wait(timeout=30)
    assert out[0] == "interrupted", out
    latency = float(out[1]) - sent
    print(f"Ctrl-C latency: {latency * 1000:.1f} ms")
    # ~50 ms is the goal on a quiet machine; the bar leaves room for one
    # shared with builds (170 ms measured at load 8 on 2 cores), while a
    # cancellation that only lands at the next stage takes seconds.
    assert latency < 0.5, f"KeyboardInterrupt came {latency * 1000:.0f} ms after SIGINT"


def test_fit_limit_and_read_control(ball, tmp_path):
    v, f, r = ball
    again = subdfit.fit(v, f, r.control)
    assert again.control.face_sizes.size == r.control.face_sizes.size
    assert again.metrics["accuracy.limit.rms_permille"] < 2 * r.metrics["accuracy.limit.rms_permille"]

    (tmp_path / "c.obj").write_bytes(r.control_obj)
    c = subdfit.read_control(tmp_path / "c.obj")
    assert np.array_equal(c.face_indices, r.control.face_indices)
    assert np.allclose(c.positions, r.control.positions, rtol=0, atol=1e-12)

    osd = subdfit.limit(c)
    rust = subdfit.limit(c, backend="rust")
    assert osd.positions.shape == (len(c.positions), 3)
    assert np.abs(osd.positions - rust.positions).max() < 1e-6
    assert np.allclose(np.linalg.norm(osd.normals, axis=1), 1)
    # (face, 0, 0) is the face's first corner, whose limit point is the
    # vertex limit there.
    faces = np.arange(c.face_sizes.size)
    first = c.face_indices[np.concatenate([[0], np.cumsum(c.face_sizes)[:-1]]).astype(np.int64)]
    at = subdfit.limit(c, np.stack([faces, 0 * faces, 0 * faces], axis=1), backend="rust")
    assert np.abs(at.positions - rust.positions[first]).max() < 1e-9

    with pytest.raises(subdfit.InvalidInput, match="backend"):
        subdfit.limit(c, backend="gpu")
    with pytest.raises(subdfit.Error):
        subdfit.limit(c, [[c.face_sizes.size + 5, 0.5, 0.5]])
    with pytest.raises(subdfit.InvalidInput, match="locations"):
        subdfit.limit(c, [[0, 0.5]])


def write_obj(path: Path, v, f) -> None:
    lines = [f"v {float(x)!r} {float(y)!r} {float(z)!r}" for x, y, z in v] + [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in f]
    path.write_text("\n".join(lines) + "\n")


def test_batch_resumes_and_reports_failures(tmp_path):
    lib = tmp_path / "lib"
    lib.mkdir()
    v, f = icosphere(3, bumps=0.1)
    write_obj(lib / "ball.obj", v, f)
    (lib / "broken.obj").write_text("v 0 0 0\nv 1 0 0\nf 1 2 3\n")
    out = tmp_path / "out"
    first = subdfit.batch([lib], out)
    status = {o["name"]: o["status"] for o in first}
    assert status == {"ball": "converted", "broken": "failed"}
    broken = next(o for o in first if o["name"] == "broken")
    assert "broken.obj" in broken["error"] and "face 0" in broken["error"]
    ball = next(o for o in first if o["name"] == "ball")
    assert ball["figures"]["control.faces"] > 0 and ball["mode"] == "organic"
    assert (out / "ball/control.obj").is_file() and not (out / "broken").exists()
    csv = (out / "batch.csv").read_text().splitlines()
    assert len(csv) == 3 and csv[0].startswith("asset,status")
    assert json.loads((out / "batch.json").read_text()) == first

    t0 = time.monotonic()
    second = subdfit.batch([lib], out)
    assert time.monotonic() - t0 < 1
    assert [o["status"] for o in second] == ["skipped", "failed"]
    assert second[0]["figures"] == ball["figures"]
    # Other options: not the same result, so converted again.
    third = subdfit.batch([lib / "ball.obj"], out, tolerance=0.1)
    assert third[0]["status"] == "converted"
    assert "converted" in subdfit.summary_table(third)


def test_bspline_reconstruction_is_recorded_and_close_to_bilinear(ball, tmp_path):
    """``displacement_reconstruction="bspline"`` (the CLI's
    ``--displacement-reconstruction bspline``): the record says so, the maps
    for bilinear hosts are written and bound in the USD, and the displaced
    surface is another reconstruction of the same detail: at the same
    tessellation (given, so both grids are the same) it differs from the
    bilinear one, but by less than the limit surface's own RMS distance to
    the input (both reconstructions fit the same offsets of that surface,
    so they differ by their residuals, which are below the offsets;
    measured RMS 2.5e-4 of the diagonal against RMS L 3.1e-3)."""
    v, f, _ = ball
    runs = {}
    for rec in ("bilinear", "bspline"):
        r = subdfit.convert(v, f, tessellation=8, displacement_reconstruction=rec)
        out = tmp_path / rec
        names = {p.name for p in r.write(out)}
        runs[rec] = (r, out, names)
    r, out, names = runs["bspline"]
    assert r.report["projectability"]["displacement"]["reconstruction"] == "bspline"
    assert r.report["options"]["run"]["convert"]["displacement_reconstruction"] == "bspline"
    assert "reconstruction" not in runs["bilinear"][0].report["projectability"]["displacement"]
    assert {"displacement_bilinear.exr", "displacement_bilinear_vector.exr"} <= names
    assert not any("bilinear" in n for n in runs["bilinear"][2])
    usda = (out / "control.usda").read_text()
    assert "@./displacement_bilinear.exr@" in usda
    a = subdfit.read(runs["bilinear"][1] / "displaced.ply").vertices
    b = subdfit.read(out / "displaced.ply").vertices
    assert a.shape == b.shape
    diag = float(np.linalg.norm(v.max(axis=0) - v.min(axis=0)))
    rms = float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=1)))) / diag
    rms_l = r.metrics["accuracy.limit.rms_permille"] / 1000.0
    assert 0.0 < rms <= rms_l, (rms, rms_l)
    with pytest.raises(subdfit.InvalidOption, match="displacement_reconstruction"):
        subdfit.convert(v, f, displacement_reconstruction="cubic")
