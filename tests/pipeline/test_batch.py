"""``prc-slam batch`` and the distributed tiled map classification, on a
``LocalCluster`` of 2 worker processes: outputs identical to running each input alone, a worker
killed mid-task, a bad input recorded while the others finish, tiled labels identical to the
serial tiled run."""

from __future__ import annotations

import json
import os
import signal
from functools import partial
from pathlib import Path

import numpy as np
import pytest
import yaml

from prc_slam.jobs.batch import PARTIAL, ROW_FILE, Task, largest_first, load_plan, resolve_tasks, run_batch

FRAMES = 3


@pytest.fixture(scope="module")
def sims(tmp_path_factory) -> list[Path]:
    """Two tiny simulated vlp16 drives (ground truth labels and poses)."""
    from data_tools.sim.dataset import write_sequence
    from data_tools.sim.simulator import SimConfig, Simulator

    root = tmp_path_factory.mktemp("sims")
    out = []
    for seed in (1, 2):
        path = root / f"drive{seed}"
        write_sequence(Simulator(SimConfig(scene="urban", sensor="vlp16", frames=FRAMES, seed=seed)), path)
        out.append(path)
    return out


@pytest.fixture(scope="module")
def client():
    from prc_slam.jobs.distributed import open_client

    # the cluster `prc-slam batch` starts: workers prepared, cores shared out among them
    with open_client(workers=2, dashboard=False) as c:
        yield c


def test_local_workers_share_the_cores(client):
    """Each of the 2 local workers gets its share of the cores for numba's parallel kernels and
    for KISS-ICP's threads (by default each would take every core)."""
    from prc_slam.jobs.distributed import default_workers

    share = max(1, default_workers() // 2)
    got = client.run(
        lambda: (
            __import__("os").environ.get("NUMBA_NUM_THREADS"),
            __import__("numba").config.NUMBA_NUM_THREADS,
            __import__("prc_slam.odometry.kiss", fromlist=["x"])
            .kiss_config(__import__("prc_slam.odometry.kiss", fromlist=["x"]).OdometryConfig())
            .registration.max_num_threads,
        )
    )
    assert len(got) == 2
    assert all(v == (str(share), share, share) for v in got.values()), got


def _plan(tmp: Path, data: dict) -> Path:
    path = tmp / "plan.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


# ---- the plan: one-line errors naming the key ------------------------------------------------


@pytest.mark.parametrize(
    ("data", "expected"),
    [
        ({"job": {"kind": "compare", "variantz": ["raw"]}, "inputs": ["x"]}, "job.variantz: Extra inputs"),
        ({"job": {"kind": "compare", "variants": ["raw", "fast"]}, "inputs": ["x"]}, "job.variants: unknown variant"),
        ({"inputs": [{"path": "x", "job": {"kind": "classify", "max_frames": 0}}]}, "inputs[0].job.max_frames"),
        ({"job": {"kind": "explode"}, "inputs": ["x"]}, "job: Input tag 'explode'"),
        ({"job": {"kind": "detect"}}, "inputs: Field required"),
    ],
)
def test_plan_errors_name_the_key(tmp_path, data, expected):
    path = _plan(tmp_path, data)
    with pytest.raises(ValueError) as err:
        load_plan(path)
    message = str(err.value)
    assert message.startswith(f"{path}: ") and expected in message and "\n" not in message


def test_inputs_resolve_globs_names_and_jobs(tmp_path):
    for name in ("a", "b"):
        (tmp_path / "seqs" / name).mkdir(parents=True)
    (tmp_path / "x.bag").write_bytes(b"")
    plan = load_plan(
        _plan(
            tmp_path,
            {
                "job": {"kind": "compare", "max_frames": 4},
                "inputs": ["seqs/*", {"path": "x.bag", "job": {"kind": "detect"}}, {"path": "seqs/a", "name": "a2"}],
            },
        )
    )
    tasks = resolve_tasks(plan, tmp_path)
    assert [(t.name, t.kind) for t in tasks] == [("a", "compare"), ("b", "compare"), ("x", "detect"), ("a2", "compare")]
    assert tasks[0].input == str(tmp_path / "seqs" / "a") and tasks[0].job["max_frames"] == 4
    with pytest.raises(ValueError, match=r"inputs\[0\]: 'nothing\*' matches nothing"):
        resolve_tasks(load_plan(_plan(tmp_path, {"job": {"kind": "detect"}, "inputs": ["nothing*"]})), tmp_path)
    with pytest.raises(ValueError, match="two inputs named 'a'"):
        resolve_tasks(load_plan(_plan(tmp_path, {"job": {"kind": "detect"}, "inputs": ["seqs/a", "seqs/a"]})), tmp_path)
    with pytest.raises(ValueError, match=r"inputs\[0\] \(seqs/a\): no job"):
        resolve_tasks(load_plan(_plan(tmp_path, {"inputs": ["seqs/a"]})), tmp_path)


# ---- batch on 2 worker processes against each input alone ------------------------------------

# timings, and where the next frame was made (a forked process alone, a thread on a Dask worker)
_TIMING = ("seconds", "per_s", "ms_", "next_frame_made_in")


def _no_timings(value):
    if isinstance(value, dict):
        return {k: _no_timings(v) for k, v in value.items() if not any(t in k for t in _TIMING)}
    if isinstance(value, list):
        return [_no_timings(v) for v in value]
    return value


def _differences(a, b, path="", rtol: float = 0.0) -> list[str]:
    """Leaves that differ (floats within ``rtol``: KISS-ICP's threaded reductions change the last
    bits from run to run even in one process, see ``test_batch_outputs_identical_to_single_runs``)."""
    if isinstance(a, dict) and isinstance(b, dict):
        return [d for k in sorted(set(a) | set(b)) for d in _differences(a.get(k), b.get(k), f"{path}.{k}", rtol)]
    if isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        return [d for i, (x, y) in enumerate(zip(a, b, strict=True)) for d in _differences(x, y, f"{path}[{i}]", rtol)]
    if isinstance(a, float) and isinstance(b, float) and rtol and abs(a - b) <= rtol * max(abs(a), abs(b)):
        return []
    return [] if a == b else [f"{path}: {a!r} != {b!r}"]


def test_largest_inputs_start_first(tmp_path):
    """Dask priorities: the larger an input on disk (a file, or all files under a directory), the
    earlier it starts; equal sizes in plan order; a missing input last."""
    (tmp_path / "seq").mkdir()
    (tmp_path / "seq" / "a.bin").write_bytes(b"x" * 25)
    (tmp_path / "seq" / "b.bin").write_bytes(b"x" * 20)
    sizes = {"small": 10, "big": 45, "same": 45}
    for name, n in sizes.items():
        (tmp_path / name).write_bytes(b"x" * n)
    names = ["small", "seq", "big", "missing", "same"]
    tasks = [Task(name=n, input=str(tmp_path / n), job={"kind": "classify"}) for n in names]
    rank = dict(zip(names, largest_first(tasks), strict=True))
    assert sorted(names, key=lambda n: -rank[n]) == ["seq", "big", "same", "small", "missing"]


def test_batch_outputs_identical_to_single_runs(client, sims, tmp_path):
    from prc_slam.config import Config
    from prc_slam.jobs.classify import Outputs, classify_job
    from prc_slam.jobs.common import write_json
    from prc_slam.jobs.odometry import run_odometry, write_outputs
    from prc_slam.prc.config import PRCConfig

    bad = tmp_path / "bad.bin"
    bad.write_bytes(b"not a point cloud")
    plan = load_plan(
        _plan(
            tmp_path,
            {
                "job": {"kind": "compare", "variants": ["raw", "prc"]},
                "inputs": [str(sims[0]), {"path": str(sims[1]), "job": {"kind": "classify"}}, str(bad)],
            },
        )
    )
    out = tmp_path / "out"
    summary = run_batch(resolve_tasks(plan, tmp_path), out, client)
    rows = {r["name"]: r for r in summary["rows"]}
    assert [r["status"] for r in summary["rows"]] == ["ok", "ok", "failed"] and summary["failed"] == 1
    assert "bad.bin" in rows["bad"]["error"] and not (out / "bad").exists()  # recorded; the others finished
    assert (out / "summary.md").read_text().count("| failed |") == 1 and (out / "summary.png").stat().st_size > 0
    assert json.loads((out / "summary.json").read_text())["rows"][0]["ate_rmse_m"].keys() == {"raw", "prc"}

    # compare, alone (what `prc-slam compare IN --out DIR` writes)
    from prc_slam.odometry.classaware import ClassAwareConfig

    cfg = Config(prc=PRCConfig.preset("multibeam"), classaware=ClassAwareConfig.for_mode("urban"))
    run, _ = run_odometry(sims[0], cfg, ["raw", "prc"], score_prc=True)
    alone = tmp_path / "alone_compare"
    write_outputs(run, cfg, alone, f"Odometry comparison on {sims[0]}")
    mine = out / sims[0].name
    assert sorted(p.name for p in alone.iterdir()) == sorted(p.name for p in mine.iterdir() if p.name != ROW_FILE)
    # the worker runs KISS-ICP on its share of the cores, the run alone on all of them: threaded
    # reductions sum in another order, the 6x6 solves (condition up to ~1e6) give the last bits
    # times that, so poses to 1e-7 relative (1e-9 m absolute), the errors derived from their
    # differences to 1e-6, every integer and label exactly
    for name in ("raw_poses_kitti.txt", "raw_poses_tum.txt", "prc_poses_kitti.txt", "prc_poses_tum.txt"):
        np.testing.assert_allclose(np.loadtxt(alone / name), np.loadtxt(mine / name), rtol=1e-7, atol=1e-9)
    assert (alone / "config.yaml").read_bytes() == (mine / "config.yaml").read_bytes()
    a, b = (json.loads((d / "metrics.json").read_text()) for d in (alone, mine))
    assert _differences(_no_timings(a), _no_timings(b), rtol=1e-6) == []
    assert rows[sims[0].name]["ate_rmse_m"]["prc"] == b["variants"]["prc"]["ate_rmse_m"]

    # classify, alone (`prc-slam classify IN --labels-out DIR/labels --json DIR/metrics.json`)
    # (the default preset, auto: multibeam for the simulated hdl64 sweeps)
    alone = tmp_path / "alone_classify"
    metrics, _ = classify_job(sims[1], None, outputs=Outputs(alone / "labels"))
    prc = PRCConfig.model_validate(metrics["config"])
    assert prc == PRCConfig.named("multibeam")
    write_json(alone / "metrics.json", metrics, Config(prc=prc))
    mine = out / sims[1].name
    labels = sorted(p.name for p in (alone / "labels").iterdir())
    assert len(labels) == FRAMES and labels == sorted(p.name for p in (mine / "labels").iterdir())
    for name in labels:
        assert (alone / "labels" / name).read_bytes() == (mine / "labels" / name).read_bytes(), name
    assert (alone / "metrics.config.yaml").read_bytes() == (mine / "metrics.config.yaml").read_bytes()
    a, b = (json.loads((d / "metrics.json").read_text()) for d in (alone, mine))
    assert _differences(_no_timings(a), _no_timings(b)) == [] and b["frames"] == FRAMES

    # the same OUT again: refused, then replaced with --overwrite
    with pytest.raises(ValueError, match="exists"):
        run_batch(resolve_tasks(plan, tmp_path)[:1], out, client)


# ---- a worker killed during a task -----------------------------------------------------------


def kill_once(markers: str, victim: str, name: str) -> None:
    """Kill this worker process the first time ``victim`` runs (the marker says it ran)."""
    marker = Path(markers) / name
    if name == victim and not marker.exists():
        marker.write_text(str(os.getpid()))
        os.kill(os.getpid(), signal.SIGKILL)


def test_worker_killed_mid_task_every_result_once(client, sims, tmp_path):
    markers = tmp_path / "markers"
    markers.mkdir()
    tasks = [
        Task(name=f"{p.name}_{i}", input=str(p), job={"kind": "classify", "max_frames": 1}) for i, p in enumerate(sims)
    ]
    out = tmp_path / "out"
    summary = run_batch(tasks, out, client, hook=partial(kill_once, str(markers), tasks[0].name))
    assert [p.name for p in markers.iterdir()] == [tasks[0].name]  # its worker died once
    assert [r["name"] for r in summary["rows"]] == [t.name for t in tasks]
    assert all(r["status"] == "ok" for r in summary["rows"]), summary["rows"]
    killed = int((markers / tasks[0].name).read_text())
    assert summary["rows"][0]["worker"].rsplit(":", 1)[1] != str(killed)  # done by another (or a restarted) worker
    for t in tasks:
        assert len(list((out / t.name / "labels").iterdir())) == 1
    assert sorted(p.name for p in out.iterdir()) == sorted(
        [t.name for t in tasks] + ["summary.json", "summary.md", "summary.png"]
    )
    assert not (out / PARTIAL).exists()


# ---- tiled map classification across workers ------------------------------------------------


def test_distributed_tiles_identical_to_serial(client, sims, tmp_path):
    from data_tools import open_dataset
    from prc_slam.jobs.distributed import classify_tiled_distributed
    from prc_slam.jobs.mapclass import map_from_dataset
    from prc_slam.mapclass import MapClassConfig
    from prc_slam.mapclass.tiles import array_chunks, classify_tiled

    dataset = open_dataset(sims[0])
    cloud = map_from_dataset(dataset, len(dataset), 1, None)
    points = np.asarray(cloud.points, dtype=np.float64).copy()
    points[::997] = np.nan  # non-finite points keep no_return, in place
    cfg = MapClassConfig()
    serial, _ = classify_tiled(array_chunks(points, 20_000), cfg, tile=12.0, margin=4.0)
    store = np.memmap(tmp_path / "labels.u8", np.uint8, "w+", shape=(len(points),))
    done = []
    labels, seconds = classify_tiled_distributed(
        array_chunks(points, 20_000), cfg, 12.0, 4.0, labels_out=store, progress=lambda d, t: done.append((d, t)),
        client=client, window=3,
    )  # fmt: skip
    assert labels is store and len(done) > 3 and done[-1][0] == done[-1][1]  # several tiles, all done
    np.testing.assert_array_equal(np.asarray(store), serial)
    assert (serial[::997] == 0).all() and len(np.unique(serial)) > 2 and seconds


# ---- the command, on a running scheduler ----------------------------------------------------


def test_cli_batch_on_a_scheduler(client, sims, tmp_path, monkeypatch):
    from typer.testing import CliRunner

    from prc_slam.cli import app

    runner = CliRunner()
    address = client.scheduler.address
    plan = _plan(tmp_path, {"job": {"kind": "classify", "max_frames": 1}, "inputs": [str(sims[0]), "nothing_here"]})
    out = tmp_path / "out"
    res = runner.invoke(app, ["batch", str(plan), "--out", str(out), "--scheduler", address, "--workers", "3"])
    assert res.exit_code == 1, res.output  # one input failed: recorded, the other done
    assert "1 of 2 inputs done" in res.output and "failed: nothing_here" in res.output
    assert "--workers 3 ignored" in res.output and "dask dashboard" in res.output
    assert (out / sims[0].name / "labels" / "000000.label").is_file()
    assert json.loads((out / "summary.json").read_text())["failed"] == 1
    # DASK_SCHEDULER_ADDRESS instead of --scheduler; the earlier results are kept unless --overwrite
    monkeypatch.setenv("DASK_SCHEDULER_ADDRESS", address)
    res = runner.invoke(app, ["batch", str(plan), "--out", str(out)])
    last = res.output.strip().splitlines()[-1]
    assert (
        res.exit_code == 2 and last.startswith("error: --out: ") and last.endswith("use --overwrite or another --out")
    )
    assert "dask:" not in res.output  # refused before any cluster work
    res = runner.invoke(app, ["batch", str(plan), "--out", str(out), "--overwrite"])
    assert res.exit_code == 1 and f"scheduler {address}" in res.output
    res = runner.invoke(app, ["batch", str(tmp_path / "none.yaml")])
    assert res.exit_code == 2 and "none.yaml: cannot read the plan" in res.output


# ---- exactly once, without a cluster --------------------------------------------------------


def test_second_attempt_returns_the_published_result(sims, tmp_path):
    from prc_slam.jobs.batch import run_task

    out = tmp_path / "out"
    (out / PARTIAL).mkdir(parents=True)
    (out / PARTIAL / "b1.batch").write_text("b1\n")
    task = Task(name="d", input=str(sims[0]), job={"kind": "classify", "max_frames": 1})
    first = run_task(task, str(out), None, "b1")
    label = out / "d" / "labels" / "000000.label"
    stamp = label.stat().st_mtime_ns
    again = run_task(task, str(out), None, "b1")  # e.g. the worker died after publishing
    assert first["status"] == "ok" and again == first and label.stat().st_mtime_ns == stamp
    assert [p.name for p in (out / PARTIAL).iterdir()] == ["b1.batch"]  # no scratch left, nothing duplicated
    (out / PARTIAL / "b2.batch").write_text("b2\n")
    with pytest.raises(RuntimeError, match="another batch"):  # a stale result is never taken for this batch's
        run_task(task, str(out), None, "b2")
    # an OUT this worker does not see: refused, nothing written on the worker's disk
    row = run_task(task, str(tmp_path / "elsewhere"), None, "b3")
    assert row["status"] == "failed" and "not on a file system" in row["error"]
    assert not (tmp_path / "elsewhere").exists()


def test_mapclass_job_tiles_on_the_cluster(client, sims, tmp_path):
    """``mapclass_job(tile=..., tiler=...)``: the job's tiles on the workers, the same files and scores."""
    from prc_slam.config import Config
    from prc_slam.jobs.distributed import classify_tiled_distributed
    from prc_slam.jobs.mapclass import mapclass_job

    serial = mapclass_job(sims[1], Config(), tmp_path / "serial", tile=15.0, margin=5.0)
    tiler = partial(classify_tiled_distributed, client=client)
    spread = mapclass_job(sims[1], Config(), tmp_path / "spread", tile=15.0, margin=5.0, tiler=tiler)
    serial.pop("files"), spread.pop("files")  # their own directories
    assert _differences(_no_timings(serial), _no_timings(spread)) == []
    las = sorted(p.name for p in (tmp_path / "serial").glob("*.las"))
    assert "map_classified.las" in las and las == sorted(p.name for p in (tmp_path / "spread").glob("*.las"))
    for name in las:
        assert (tmp_path / "serial" / name).read_bytes() == (tmp_path / "spread" / name).read_bytes(), name
