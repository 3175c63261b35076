"""Shared fixtures: where the repository, its data and the CLI are."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[2]
SPOT = "data/spot.ply"  # relative to REPO: the CLI and Python name it the same way
SHARED = REPO.parent / "shared" / "data"

# The files `subdfit convert` writes; report.json is compared apart (timings).
OUTPUTS = ["control.obj", "control.usda", "limit.ply", "displaced.ply",
           "displacement.exr", "displacement_vector.exr", "fitmap.ply"]


def cli_path() -> Path:
    """The CLI to compare with: $SUBDFIT_CLI (scripts/test.sh sets it to the
    build the wheel was made from), else the newest of target/{debug,release}."""
    env = os.environ.get("SUBDFIT_CLI")
    if env:
        return Path(env)
    found = [p for p in (REPO / "target/debug/subdfit", REPO / "target/release/subdfit") if p.exists()]
    if not found:
        pytest.skip("no subdfit CLI built (cargo build), nothing to compare with")
    return max(found, key=lambda p: p.stat().st_mtime)


@pytest.fixture
def cli():
    exe = cli_path()

    def run(*args: str, check: bool = True) -> subprocess.CompletedProcess:
        r = subprocess.run([str(exe), *map(str, args)], cwd=REPO, capture_output=True, text=True)
        if check and r.returncode != 0:
            raise AssertionError(f"subdfit {' '.join(map(str, args))}: {r.returncode}\n{r.stderr}")
        return r

    return run


@pytest.fixture
def in_repo(monkeypatch):
    """Runs the test from the repository root, so relative paths name the
    input exactly as the CLI (run from there) does."""
    monkeypatch.chdir(REPO)
    return REPO


def stable_report(path: Path) -> dict:
    """report.json without what differs run to run (wall/CPU times, memory)."""
    def strip(v):
        if isinstance(v, dict):
            return {k: strip(x) for k, x in v.items()
                    if "seconds" not in k and "peak_memory" not in k}
        if isinstance(v, list):
            return [strip(x) for x in v]
        return v
    return strip(json.loads(Path(path).read_text()))


def assert_same_outputs(ours: Path, cli_dir: Path) -> None:
    for name in OUTPUTS:
        a, b = (ours / name).read_bytes(), (cli_dir / name).read_bytes()
        assert a == b, f"{name} differs from the CLI's ({len(a)} vs {len(b)} bytes)"
    assert stable_report(ours / "report.json") == stable_report(cli_dir / "report.json")


def icosphere(subdivisions: int, radius: float = 1.0, bumps: float = 0.0):
    """A closed triangle mesh made here (no data file): an icosahedron split
    `subdivisions` times, projected on a sphere, optionally bumpy."""
    t = (1 + 5 ** 0.5) / 2
    v = [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t),
         (0, -1, -t), (0, 1, -t), (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)]
    f = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4),
         (11, 10, 2), (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8),
         (3, 8, 9), (4, 9, 5), (2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    verts = [np.array(p, dtype=float) / np.linalg.norm(p) for p in v]
    for _ in range(subdivisions):
        cache: dict = {}

        def mid(a, b):
            key = (min(a, b), max(a, b))
            if key not in cache:
                m = verts[a] + verts[b]
                verts.append(m / np.linalg.norm(m))
                cache[key] = len(verts) - 1
            return cache[key]

        f = [g for a, b, c in f for g in
             ((a, mid(a, b), mid(c, a)), (b, mid(b, c), mid(a, b)),
              (c, mid(c, a), mid(b, c)), (mid(a, b), mid(b, c), mid(c, a)))]
    p = np.array(verts)
    if bumps:
        p *= (1 + bumps * np.sin(5 * p[:, 0]) * np.sin(4 * p[:, 1]) * np.sin(3 * p[:, 2]))[:, None]
    return p * radius, np.array(f, dtype=np.int64)


def shared_meshes(names):
    """The shared organic meshes that are there (../shared/data)."""
    return [SHARED / n for n in names if (SHARED / n).is_file()]


@pytest.fixture(scope="session")
def blender():
    exe = shutil.which("blender")
    if exe is None:
        pytest.skip("blender is not installed (apt install blender): the Blender test needs it")
    return exe
