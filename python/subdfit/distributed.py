"""``subdfit batch`` on a Dask distributed cluster: one task per asset.

Why Dask rather than Ray: it installs from PyPI as plain Python (no
separate object store or daemon to run), a ``LocalCluster`` starts in a
test in seconds, the same code reaches the clusters studios already have
(SSH, SLURM/PBS through dask-jobqueue, Kubernetes) by changing only the
``Client`` address, and a task here is a plain function of a file path
and a folder, with nothing shared in memory that Ray's object store would
help with.

Each task converts one asset exactly as ``subdfit batch`` does (the same
Rust function: same folder, same bytes, same resume rule) and returns its
outcome; the client writes ``batch.csv`` / ``batch.json``. Paths are used
as given, so on a real cluster give paths that every worker sees (a
shared file system) — relative ones resolve in each worker's working
folder.
"""

from __future__ import annotations

import json
import os
from typing import Any, Iterable

from . import _subdfit


def convert_asset(asset: str, force: bool, options: dict[str, Any]) -> str:
    """The task: converts one asset of ``_subdfit.batch_plan`` on a worker;
    returns its outcome record (JSON). A bad asset is a "failed" outcome,
    not an exception."""
    return _subdfit.convert_asset(asset, _subdfit.Options(**options), force)


def _failed(asset: str, error: str) -> str:
    """The outcome of an asset whose task itself died (a worker killed)."""
    record = json.loads(asset)
    record.update(status="failed", seconds=0.0, mode=None, error=error, figures={})
    return json.dumps(record)


def batch(
    inputs: Iterable[str | os.PathLike[str]],
    out_root: str | os.PathLike[str],
    *,
    client: Any = None,
    force: bool = False,
    **options: Any,
) -> list[dict[str, Any]]:
    """Converts every asset of ``inputs`` (files, folders, globs, manifests)
    on the Dask cluster of ``client`` (default: the current one), one task
    per asset, each writing its own folder under ``out_root``; writes the
    summary files and returns every asset's outcome, in input order.
    ``options`` are :func:`subdfit.convert`'s."""
    from dask.distributed import get_client

    client = client or get_client()
    # Checked here, once, rather than failing every task the same way.
    _subdfit.Options(**options)
    out_root = os.fspath(out_root)
    assets = _subdfit.batch_plan([os.fspath(i) for i in inputs], out_root)
    keys = [f"subdfit-{json.loads(a)['name']}-{i}" for i, a in enumerate(assets)]
    futures = client.map(
        convert_asset, assets, force=force, options=options, key=keys, pure=False
    )
    records = []
    for asset, future in zip(assets, futures):
        try:
            records.append(future.result())
        except Exception as e:  # the task died (worker lost): that asset only
            records.append(_failed(asset, f"task failed: {type(e).__name__}: {e}"))
    _subdfit.write_summary(out_root, records)
    return [json.loads(r) for r in records]
