"""The batch on a Dask LocalCluster of 2 workers: the CLI's bytes."""

from __future__ import annotations

import time

import pytest

import subdfit
import subdfit.distributed
from conftest import SHARED, SPOT, assert_same_outputs, shared_meshes

distributed = pytest.importorskip("dask.distributed", reason="dask[distributed] is not installed")

# Small organic meshes, a few seconds each: the bundled spot always, two
# shared ones when ../shared/data is there.
SHARED_ORGANIC = ["homer.ply", "cheburashka.ply"]


def test_dask_batch_gives_the_clis_bytes(cli, tmp_path, capsys):
    inputs = [SPOT] + [str(p) for p in shared_meshes(SHARED_ORGANIC)]
    if len(inputs) == 1:
        with capsys.disabled():
            print(f"\nnote: {SHARED} is absent; the Dask test converts only {SPOT}")
    broken = tmp_path / "broken.ply"
    broken.write_text("ply\nformat ascii 1.0\nelement vertex 3\nend_header\n0 0 0\n")
    out = tmp_path / "out"
    t0 = time.monotonic()
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        outcomes = subdfit.distributed.batch(inputs + [str(broken)], out, client=client)
        workers = len(client.scheduler_info()["workers"])
    print(f"Dask batch of {len(inputs)} meshes on {workers} workers: {time.monotonic() - t0:.1f} s")
    assert workers == 2
    assert [o["status"] for o in outcomes] == ["converted"] * len(inputs) + ["failed"]
    assert "broken.ply" in outcomes[-1]["error"]
    for mesh, o in zip(inputs, outcomes):
        cli("convert", mesh, "-o", tmp_path / "cli" / o["name"], "--quiet")
        assert_same_outputs(out / o["name"], tmp_path / "cli" / o["name"])
    assert (out / "batch.csv").read_text().count("\n") == len(inputs) + 2
    # Run again: every finished asset is skipped, on this machine too.
    again = subdfit.batch(inputs, out)
    assert {o["status"] for o in again} == {"skipped"}
