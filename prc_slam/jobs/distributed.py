"""Where batch and tiled work runs: a Dask cluster.

:func:`open_client` connects to a scheduler (``--scheduler tcp://HOST:8786`` or the
``DASK_SCHEDULER_ADDRESS`` environment variable) or starts an in-process ``LocalCluster`` of
worker *processes* (one thread each: numba and KISS-ICP hold the GIL unevenly, so threads would
not scale), sized to the machine's CPUs unless ``workers`` is given.

:func:`classify_tiled_distributed` is the out-of-core tiled map classification of
:func:`prc_slam.mapclass.tiles.classify_tiled` (paper 004, Sec. 5) with its pass 2 spread over
the workers: the client spills the cloud into tile files (the serial pass 1, reused), then for
every tile gathers the tile's points and the neighbours' points within ``margin`` exactly as the
serial loop does and sends them to a worker, which classifies them and returns the labels of the
tile's own points; the client writes those into ``labels_out`` (e.g. a memory-map). At most
``window`` tiles are in flight, so client memory stays bounded by a few tiles, and workers need
no shared file system. The labels are identical to the serial tiled run (tested).
"""

from __future__ import annotations

import importlib.util
import logging
import os
import tempfile
import time
import warnings
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

log = logging.getLogger("prc_slam")

#: where a local cluster listens unless ``--bind`` says otherwise
LOOPBACK = "127.0.0.1"
#: the dashboard's port (Dask's default)
DASHBOARD_PORT = 8787


def _is_loopback(address: str) -> bool:
    """Whether ``address`` is this machine's loopback only (one test for everything served)."""
    from prc_slam.viz.sink import is_loopback

    return is_loopback(address)


def default_workers() -> int:
    """Worker processes for a local cluster: the CPUs this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


def has_dashboard() -> bool:
    """Dask's dashboard needs bokeh (not a dependency of ``dask[distributed]``)."""
    return importlib.util.find_spec("bokeh") is not None


@contextmanager
def open_client(
    scheduler: str | None = None,
    workers: int | None = None,
    note: Callable[[str], None] | None = None,
    dashboard: bool | None = None,
    bind: str = LOOPBACK,
    dashboard_port: int = DASHBOARD_PORT,
) -> Iterator[Any]:
    """A ``distributed.Client``: on ``scheduler`` (or ``DASK_SCHEDULER_ADDRESS``), else on a
    fresh in-process ``LocalCluster`` of ``workers`` single-threaded worker processes.

    A local cluster's scheduler, workers and dashboard listen on ``bind`` (default the loopback:
    only this machine can connect; ``--bind 0.0.0.0`` exposes them, said in a warning).
    ``note`` receives one line naming the cluster and one with the dashboard address.
    """
    from distributed import Client, LocalCluster

    say = note or log.info
    if workers is not None and workers < 1:
        raise ValueError(f"--workers: must be at least 1, got {workers}")
    address = scheduler or os.environ.get("DASK_SCHEDULER_ADDRESS") or None
    dashboard = has_dashboard() if dashboard is None else dashboard
    if address:
        if workers is not None:
            say(f"--workers {workers} ignored: the cluster at {address} has its own workers")
        try:
            client = Client(address, timeout="20s")
        except OSError as exc:
            raise OSError(f"--scheduler: cannot reach {address}: {exc}") from None
        cluster = None
        say(f"dask: scheduler {address}, {len(client.scheduler_info(n_workers=-1)['workers'])} workers")
    else:
        n = workers or default_workers()
        if not _is_loopback(bind):
            ports = f"port {dashboard_port} (dashboard) and the scheduler's" if dashboard else "the scheduler's port"
            log.warning(f"serving on {bind}: anyone who can reach this machine on {ports} can watch and send work")
        host = f"[{bind}]" if ":" in bind else bind
        cluster = LocalCluster(
            n_workers=n,
            threads_per_worker=1,
            processes=True,
            host=bind,
            dashboard_address=f"{host}:{dashboard_port}" if dashboard else None,
            silence_logs=logging.ERROR,
            # numba's parallel kernels (the online detectors) and KISS-ICP's threads take every
            # core by default: share them out, or the workers' threads fight over the cores
            # (numba's several times slower; 8 compare tasks on 2 workers 7.9-8.2 s vs 7.0-7.4 s)
            env={k: str(max(1, default_workers() // n)) for k in ("NUMBA_NUM_THREADS", "PRC_SLAM_THREADS")},
        )
        client = Client(cluster)
        say(f"dask: local cluster of {n} worker process{'es' if n > 1 else ''} (1 thread each)")
    t0 = time.perf_counter()
    try:
        client.run(warm_worker)  # every worker at once, before any task is timed
    except Exception as exc:  # e.g. a remote worker without prc_slam: its tasks will say so
        say(f"dask: could not prepare the workers ({type(exc).__name__}: {exc}); tasks will load what they need")
    else:
        say(f"dask: workers ready in {time.perf_counter() - t0:.1f} s (modules imported, kernels loaded)")
    link = client.dashboard_link if dashboard else ""
    say(f"dask dashboard: {link}" if link else "dask dashboard: not available (install bokeh>=3.1 for it)")
    try:
        yield client
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def warm_worker() -> None:
    """Import the jobs' modules and load every numba kernel of the per-frame path in a worker,
    so that a worker's first task costs what the others cost (run once per worker when the
    client opens: a fresh process otherwise spends seconds on this in its first task)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot  # the reports' plots

    from prc_slam.config import Config
    from prc_slam.jobs import batch  # noqa: F401  (the job modules)
    from prc_slam.odometry.compare import warm_up_kernels
    from prc_slam.prc.algorithm import warm_up

    warm_up()
    warm_up_kernels(Config())


# ---------------------------------------------------------------------------------------------
# Tiled map classification across workers
# ---------------------------------------------------------------------------------------------


def classify_tile(points: np.ndarray, n_own: int, config) -> tuple[np.ndarray, dict[str, float], Any]:
    """On a worker: classify one tile with its margin; the labels of its ``n_own`` own points
    (they come first), the stage times and the tile's result without per-point arrays."""
    from prc_slam.mapclass import tiles
    from prc_slam.mapclass.classify import DensityWarning, classify_map

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DensityWarning)  # summed up by the client
        result = classify_map(points, config)
    light = tiles._light(result, n_own) if hasattr(tiles, "_light") else None
    return np.ascontiguousarray(result.labels[:n_own]), dict(result.seconds), light


def classify_tiled_distributed(
    chunks: Iterable[np.ndarray],
    config=None,
    tile: float = 40.0,
    margin: float = 6.0,
    workdir: str | Path | None = None,
    labels_out: np.ndarray | None = None,
    progress: Callable[[int, int], None] | None = None,
    details: bool = False,
    *,
    client,
    window: int | None = None,
):
    """:func:`prc_slam.mapclass.tiles.classify_tiled` with the tiles classified on ``client``'s
    workers; same arguments and returns (``window``: tiles in flight, default twice the workers).
    """
    from distributed import as_completed

    from prc_slam import labels as L
    from prc_slam.mapclass import tiles

    if tile <= 0 or margin < 0:
        raise ValueError(f"tile must be > 0 and margin >= 0, got {tile}, {margin}")
    if window is None:
        window = 2 * max(1, len(client.scheduler_info(n_workers=-1).get("workers", {})))
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        files, n, _ = tiles._spill(chunks, tile, Path(tmp))
        labels = np.full(n, L.NO_RETURN, np.uint8) if labels_out is None else labels_out
        if len(labels) != n:
            raise ValueError(f"labels_out holds {len(labels)} entries for {n} points")
        labels[:] = L.NO_RETURN
        keys = sorted(files)
        pending: dict[Any, tuple[tuple[int, int], np.ndarray]] = {}
        lights: dict[tuple[int, int], Any] = {}
        seconds_by_key: dict[tuple[int, int], dict[str, float]] = {}
        running = as_completed()
        next_key = done = 0

        def submit() -> None:
            nonlocal next_key
            key = keys[next_key]
            next_key += 1
            own, points = tiles.tile_points(files, key, tile, margin)
            data = client.scatter(points, direct=False)
            fut = client.submit(classify_tile, data, len(own), config, pure=False, retries=2)
            pending[fut] = (key, own["index"])
            running.add(fut)

        while next_key < len(keys) and len(pending) < window:
            submit()
        for fut in running:
            key, index = pending.pop(fut)
            own_labels, secs, light = fut.result()
            fut.release()
            labels[index] = own_labels
            lights[key], seconds_by_key[key] = light, secs
            done += 1
            if progress is not None:
                progress(done, len(keys))
            if next_key < len(keys):
                submit()
    seconds: dict[str, float] = {}
    for key in keys:  # summed in the serial order
        for k, v in seconds_by_key[key].items():
            seconds[k] = seconds.get(k, 0.0) + v
    if not details:
        return labels, seconds
    results = [lights[k] for k in keys]
    summarise = getattr(tiles, "density_summary", None)
    density = summarise(results) if summarise and all(r is not None for r in results) else {"messages": []}
    if density["messages"]:
        from prc_slam.mapclass.classify import DensityWarning

        warnings.warn(
            f"{len(density['messages'])} of {len(results)} tiles: " + density["messages"][0],
            DensityWarning,
            stacklevel=2,
        )
    return labels, seconds, density
