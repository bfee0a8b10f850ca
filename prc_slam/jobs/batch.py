"""The ``batch`` job: many inputs, one task each, on a Dask cluster.

A plan (YAML, validated by pydantic) lists inputs (directories, files, bags, globs) and the job
run on each (``classify``, ``detect``, ``compare``, ``filter``, ``mapclass``, with that
command's options). Every input is one Dask task; it writes into ``OUT/<input-name>/`` exactly the
files the single-input command writes (see :data:`SINGLE_COMMAND`), then the client writes
``OUT/summary.json``, ``OUT/summary.md`` and ``OUT/summary.png``.

Exactly-once results. A task writes into its own scratch directory ``OUT/.partial/<name>.<uuid>``
and publishes it with one atomic ``rename`` to ``OUT/<name>``; a second attempt of the same input
(a worker died after the rename but before reporting) finds the result published, drops its own
scratch and returns the published row. A worker that dies mid-task is handled by the scheduler
(the task is rescheduled on another worker, up to ``distributed.scheduler.allowed-failures``
times); an unexpected exception is retried (``retries``); a bad input (``DataError``,
``ScanError``, ``ValueError``, ``OSError``, ...) is deterministic, so it is not retried but
recorded as a failed row, and the other inputs finish.

Example plan::

    job: {kind: compare, variants: [raw, prc], max_frames: 20}
    inputs:
      - sims/seq_*                  # a glob, relative to the plan file
      - path: ../data/kitti00
        job: {kind: classify, labels: true}
"""

from __future__ import annotations

import glob
import json
import os
import re
import shutil
import socket
import time
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, TypeAdapter, ValidationError, field_validator

from prc_slam.jobs.common import write_json, write_text_atomic
from prc_slam.jobs.progress import Reporter

PARTIAL = ".partial"
ROW_FILE = "batch_task.json"

# ---------------------------------------------------------------------------------------------
# The plan
# ---------------------------------------------------------------------------------------------


class _Job(BaseModel):
    model_config = ConfigDict(extra="forbid")

    format: str | None = Field(None, description="input format (default: detected)")
    max_frames: int | None = Field(None, ge=1, description="use only the first N frames")
    # reader options, as on every command that reads an input (--topic, --meta, --model, --rows, --cols)
    topic: str | None = None
    meta: Path | None = None
    model: str | None = None
    rows: int | None = Field(None, ge=1)
    cols: int | None = Field(None, ge=1)

    def open_options(self) -> dict[str, Any]:
        """The reader options set (for ``open_dataset``)."""
        opts = {"topic": self.topic, "meta": self.meta, "model": self.model, "rows": self.rows, "cols": self.cols}
        if getattr(self, "destaggered", True) is False:  # (the readers' default is destaggered)
            opts["destaggered"] = False
        return {k: v for k, v in opts.items() if v is not None}


class ClassifyJob(_Job):
    """``prc-slam classify IN --labels-out OUT/n/labels --json OUT/n/metrics.json [--las OUT/n/classified.las]``."""

    kind: Literal["classify"]
    mode: Literal["urban", "forest"] = "urban"
    preset: Literal["auto", "paper", "multibeam"] = "auto"
    adaptive: bool | None = None
    config: Path | None = None
    destaggered: bool = True
    labels: bool = True
    las: bool = False


class DetectJob(_Job):
    """``prc-slam detect IN --labels-out OUT/n/labels --json OUT/n/metrics.json [--las OUT/n/detected.las]``."""

    kind: Literal["detect"]
    paper: bool = False
    labels: bool = True
    las: bool = False


class CompareJob(_Job):
    """``prc-slam compare IN --out OUT/n --variants ... [--mapclass]``."""

    kind: Literal["compare"]
    variants: list[str] = Field(default_factory=lambda: ["raw", "prc"], min_length=1)
    mode: Literal["urban", "forest"] = "urban"
    preset: Literal["paper", "multibeam"] = "multibeam"
    deskew: bool = True
    online: bool = False
    config: Path | None = None
    mapclass: bool = False
    mapclass_every: int = Field(5, ge=1)

    @field_validator("variants")
    @classmethod
    def _known(cls, value: list[str]) -> list[str]:
        known = {"raw", "prc", "prc+classaware"}
        bad = [v for v in value if v not in known]
        if bad:
            raise ValueError(f"unknown variant {bad[0]!r}; choose from {', '.join(sorted(known))}")
        return value


class FilterJob(_Job):
    """``prc-slam filter IN --out OUT/n/filtered[.mcap|.bag] --json OUT/n/metrics.json``."""

    kind: Literal["filter"]
    mode: Literal["urban", "forest"] = "urban"
    preset: Literal["paper", "multibeam"] = "multibeam"
    config: Path | None = None
    keep_labels: list[str] | None = None
    out_format: Literal["mcap", "ros2", "ros1", "pcd", "kitti"] | None = None
    label_dtype: Literal["uint8", "uint16"] = "uint8"


class MapclassJob(_Job):
    """``prc-slam mapclass IN --out OUT/n --json OUT/n/metrics.json``."""

    kind: Literal["mapclass"]
    config: Path | None = None
    normals: Literal["voxels", "points"] | None = None
    paper: bool = False
    tile: float | None = Field(None, ge=0.0)
    margin: float = Field(6.0, ge=0.0)
    every: int = Field(1, ge=1)
    poses: Path | None = None


JobSpec = Annotated[ClassifyJob | DetectJob | CompareJob | FilterJob | MapclassJob, Field(discriminator="kind")]
JOB_ADAPTER: TypeAdapter = TypeAdapter(JobSpec)

#: the command each job stands for, and the files it writes (documented in the summary)
SINGLE_COMMAND = {
    "classify": "prc-slam classify IN --labels-out OUT/<name>/labels --json OUT/<name>/metrics.json",
    "detect": "prc-slam detect IN --labels-out OUT/<name>/labels --json OUT/<name>/metrics.json",
    "compare": "prc-slam compare IN --out OUT/<name>",
    "filter": "prc-slam filter IN --out OUT/<name>/filtered[.mcap|.bag] --json OUT/<name>/metrics.json",
    "mapclass": "prc-slam mapclass IN --out OUT/<name> --json OUT/<name>/metrics.json",
}


class InputEntry(BaseModel):
    """One plan input: a path or glob, an optional name (default: the file or directory name
    without its suffix) and an optional job replacing the plan's."""

    model_config = ConfigDict(extra="forbid")

    path: str
    name: str | None = None
    job: JobSpec | None = None


class Plan(BaseModel):
    """A batch plan: the default ``job`` and the ``inputs``."""

    model_config = ConfigDict(extra="forbid")

    job: JobSpec | None = None
    inputs: list[str | InputEntry] = Field(min_length=1)


class Task(BaseModel):
    """One input resolved: what a worker runs."""

    name: str
    input: str
    job: dict[str, Any]

    @property
    def kind(self) -> str:
        return self.job["kind"]


def _loc(loc: tuple) -> str:
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        elif part in ("str", "InputEntry") or part in JOB_KINDS:  # union branch tags, not keys
            continue
        else:
            out += ("." if out else "") + str(part)
    return out or "plan"


JOB_KINDS = ("classify", "detect", "compare", "filter", "mapclass")


def plan_error(path: Path, exc: ValidationError) -> ValueError:
    """A validation error as one line naming the plan file and the key."""
    errs = exc.errors()
    # a str | InputEntry union reports both branches: drop the string branch when the other failed too
    deeper = [e for e in errs if e.get("type") != "string_type"]
    errs = sorted(deeper or errs, key=lambda e: -len(e.get("loc", ())))
    err = errs[0]
    msg = err.get("msg", "invalid").removeprefix("Value error, ")
    got = f" (got {err['input']!r})" if "input" in err and not isinstance(err["input"], dict | list) else ""
    more = f" (+{len(errs) - 1} more)" if len(errs) > 1 else ""
    return ValueError(f"{path}: {_loc(tuple(err.get('loc', ())))}: {msg}{got}{more}")


def load_plan(path: Path) -> Plan:
    """Read and validate a plan; one-line ``ValueError`` naming the file and key otherwise."""
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text())
    except OSError as exc:
        raise ValueError(f"{path}: cannot read the plan: {exc.strerror or exc}") from exc
    except yaml.YAMLError as exc:
        raise ValueError(f"{path}: not valid YAML: {' '.join(str(exc).split())}") from exc
    if not isinstance(data, dict):
        raise ValueError(f"{path}: a plan is a mapping with 'inputs' (and 'job'), got {type(data).__name__}")
    try:
        return Plan.model_validate(data)
    except ValidationError as exc:
        raise plan_error(path, exc) from None


_NAME_OK = re.compile(r"[^A-Za-z0-9._+-]+")


def input_name(path: Path) -> str:
    """``OUT/<name>``: a directory's name, a file's name without its suffix(es)."""
    name = path.name
    if path.is_file() or path.suffix:
        for suffix in reversed(path.suffixes):
            if len(suffix) <= 5:
                name = name[: -len(suffix)]
    name = _NAME_OK.sub("_", name).strip("._") or "input"
    return name


def resolve_tasks(plan: Plan, base: Path) -> list[Task]:
    """Expand globs (relative to ``base``, the plan's directory), name the inputs, attach the
    jobs. A glob that matches nothing, an input without a job, or two inputs with one name are
    errors (one line naming the input)."""
    tasks: list[Task] = []
    seen: dict[str, str] = {}
    for i, entry in enumerate(plan.inputs):
        entry = InputEntry(path=entry) if isinstance(entry, str) else entry
        job = entry.job or plan.job
        if job is None:
            raise ValueError(f"inputs[{i}] ({entry.path}): no job: give the plan a 'job' or the input one")
        pattern = os.path.expanduser(entry.path)
        pattern = os.path.normpath(pattern if os.path.isabs(pattern) else str(base / pattern))
        if glob.has_magic(pattern):
            paths = sorted(Path(p) for p in glob.glob(pattern))
            if not paths:
                raise ValueError(f"inputs[{i}]: {entry.path!r} matches nothing")
            if entry.name is not None and len(paths) > 1:
                raise ValueError(f"inputs[{i}]: 'name' given for a glob matching {len(paths)} inputs")
        else:
            paths = [Path(pattern)]  # a missing path fails as its task (recorded in the summary)
        spec = job.model_dump(mode="json")
        for key in ("config", "poses", "meta"):
            if spec.get(key) is not None and not os.path.isabs(spec[key]):
                spec[key] = os.path.normpath(base / spec[key])
        for p in paths:
            name = entry.name or input_name(p)
            if name in seen:
                raise ValueError(f"inputs[{i}]: two inputs named {name!r} ({seen[name]} and {p}); give one a 'name'")
            seen[name] = str(p)
            tasks.append(Task(name=name, input=str(p), job=spec))
    return tasks


# ---------------------------------------------------------------------------------------------
# One task (runs on a worker)
# ---------------------------------------------------------------------------------------------


def _user_errors() -> tuple[type[BaseException], ...]:
    from data_tools.errors import DataError
    from prc_slam.pipeline import FrameError
    from prc_slam.scan import ScanError

    return (DataError, ScanError, FrameError, ValueError, ValidationError, OSError, ImportError)


def one_line(exc: BaseException) -> str:
    text = str(exc).strip() or type(exc).__name__
    return " ".join(text.split("\n")[0].split())


def _prc_config(job: Any):
    """The PRC config of ``classify`` / ``compare`` / ``filter`` (as their commands build it)."""
    from prc_slam.config import Config
    from prc_slam.prc.config import PRCConfig

    if job.config is not None:
        return Config.from_yaml(job.config).prc
    if job.preset == "auto":
        return None  # classify: decided on the first frame
    return PRCConfig.named(job.preset, job.mode, getattr(job, "adaptive", None))


def _run_config(job: Any):
    from prc_slam.config import Config
    from prc_slam.odometry.classaware import ClassAwareConfig

    base = Config(
        prc=_prc_config(job.model_copy(update={"config": None})), classaware=ClassAwareConfig.for_mode(job.mode)
    )
    return base if job.config is None else Config.from_yaml(job.config, base)


def run_job(task: Task, out: Path) -> dict[str, Any]:
    """Run ``task``'s job on its input, writing what the single-input command writes into
    ``out``; returns the summary figures (``frames``, ``points``, ``points_per_s``, ``ate_rmse_m``
    per variant, ``failed_variants``, ``skipped_frames``)."""
    job = JOB_ADAPTER.validate_python(task.job)
    source = Path(task.input)
    if not source.exists():
        raise FileNotFoundError(f"{source}: no such file or directory (on worker host {socket.gethostname()})")
    out.mkdir(parents=True, exist_ok=True)
    row: dict[str, Any] = {}
    if job.kind in ("classify", "detect"):
        from prc_slam.config import Config
        from prc_slam.jobs.classify import Outputs, classify_job, detect_job
        from prc_slam.prc.config import PRCConfig

        outputs = Outputs(out / "labels" if job.labels else None, out / f"{job.kind}ed.las" if job.las else None)
        if job.kind == "classify":
            metrics, _ = classify_job(
                source, _prc_config(job), mode=job.mode, adaptive=job.adaptive, fmt=job.format,
                max_frames=job.max_frames, outputs=outputs, **job.open_options(),
            )  # fmt: skip
            write_json(out / "metrics.json", metrics, Config(prc=PRCConfig.model_validate(metrics["config"])))
            pps = metrics.get("points_per_s")
        else:
            metrics, _ = detect_job(
                source, paper=job.paper, fmt=job.format, max_frames=job.max_frames, outputs=outputs,
                **job.open_options(),
            )  # fmt: skip
            write_json(out / "metrics.json", metrics)
            pps = metrics.get("points_per_s_after_first")  # the detectors' rate after their first frame
            if not pps and metrics.get("seconds"):
                pps = metrics["points"] / metrics["seconds"]
        row.update(frames=metrics.get("frames"), points=metrics.get("points"), points_per_s=pps)
        row["skipped_frames"] = metrics.get("skipped_frames", 0)
    elif job.kind == "compare":
        row.update(_compare(job, source, out))
    elif job.kind == "filter":
        row.update(_filter(job, source, out))
    else:
        from prc_slam.config import Config
        from prc_slam.jobs.mapclass import mapclass_job

        cfg = Config.from_yaml(job.config) if job.config is not None else Config()
        if job.paper:
            from prc_slam.mapclass import paper_config

            cfg.mapclass = paper_config().model_copy(update={"normals": cfg.mapclass.normals})
        if job.normals is not None:
            cfg.mapclass.normals = job.normals
        metrics = mapclass_job(
            source, cfg, out, tile=job.tile, margin=job.margin, fmt=job.format, max_frames=job.max_frames,
            every=job.every, poses=job.poses, **job.open_options(),
        )  # fmt: skip
        write_json(out / "metrics.json", metrics, cfg)
        row.update(frames=None, points=metrics.get("points"), points_per_s=metrics.get("points_per_s"))
    return row


def _compare(job: CompareJob, source: Path, out: Path) -> dict[str, Any]:
    from prc_slam.jobs.odometry import run_odometry, write_outputs

    cfg = _run_config(job)
    cfg.odometry.deskew = cfg.odometry.deskew and job.deskew
    run, prc_labels = run_odometry(
        source, cfg, job.variants, fmt=job.format, max_frames=job.max_frames, online=job.online, score_prc=True,
        keep_labels_every=job.mapclass_every if job.mapclass else None, **job.open_options(),
    )  # fmt: skip
    write_outputs(run, cfg, out, f"Odometry comparison on {source}")
    if job.mapclass:
        from prc_slam.jobs.mapclass import compare_mapclass
        from prc_slam.jobs.report import mapclass_section

        variant = next((v for v in job.variants if v != "raw"), job.variants[0])
        mc = compare_mapclass(
            source, job.format, run, variant, job.mapclass_every, prc_labels, cfg, out, **job.open_options()
        )
        write_json(out / "mapclass.json", mc)
        with (out / "report.md").open("a") as f:
            f.write(mapclass_section(mc))
    variants = run.metrics["variants"]
    first = next(iter(variants.values()))
    frames = first.get("frames")
    points = None if first.get("points_in") is None or frames is None else round(first["points_in"] * frames)
    ms = first.get("ms_per_frame")
    return {
        "frames": frames,
        "points": points,
        "points_per_s": first["points_in"] * 1000.0 / ms if ms and first.get("points_in") else None,
        "ate_rmse_m": {k: v.get("ate_rmse_m") for k, v in variants.items()},
        "ms_per_frame": {k: v.get("ms_per_frame") for k, v in variants.items()},
        "failed_variants": [k for k, v in variants.items() if v.get("failed")],
        "skipped_frames": run.metrics.get("skipped_frames", 0),
    }


def _filter(job: FilterJob, source: Path, out: Path) -> dict[str, Any]:
    try:
        from prc_slam.jobs.filter import filter_job
    except ImportError as exc:  # pragma: no cover - an installation without the stream writers
        raise ImportError(f"filter: not available in this installation ({exc})") from None

    cfg = _run_config(job)
    suffix = {"mcap": ".mcap", "ros1": ".bag"}.get(job.out_format or "", "")
    metrics = filter_job(
        source, cfg, out / f"filtered{suffix}", fmt=job.format, max_frames=job.max_frames,
        keep_labels=job.keep_labels, out_format=job.out_format, label_dtype=job.label_dtype, **job.open_options(),
    )  # fmt: skip
    write_json(out / "metrics.json", metrics, cfg)
    pts, sec = metrics.get("points_in"), metrics.get("seconds")
    return {"frames": metrics.get("frames"), "points": pts, "points_per_s": pts / sec if pts and sec else None}


def run_task(
    task: Task | dict, out_root: str, hook: Callable[[str], None] | None = None, batch_id: str = ""
) -> dict[str, Any]:
    """One input, on a worker: run its job into a scratch directory and publish it atomically as
    ``out_root/<name>``. Returns its summary row (``status`` ``ok`` or ``failed`` with ``error``).

    ``hook(name)`` runs first (fault injection in tests). A bad input is returned as a failed row;
    any other exception propagates (Dask retries the task).
    """
    task = Task.model_validate(task)
    if hook is not None:
        hook(task.name)
    root = Path(out_root)
    final = root / task.name
    row: dict[str, Any] = {"name": task.name, "input": task.input, "job": task.kind, "batch_id": batch_id}
    if batch_id and not (root / PARTIAL / f"{batch_id}.batch").is_file():
        # never write results to a worker's own disk where the client will not find them
        row.update(
            status="failed", error=f"--out: {root} is not on a file system worker host {socket.gethostname()} sees"
        )
        return row
    if (final / ROW_FILE).is_file():  # an earlier attempt published it
        return _published(final, batch_id)
    scratch = root / PARTIAL / f"{task.name}.{uuid.uuid4().hex[:12]}"
    scratch.mkdir(parents=True)
    row["worker"] = f"{socket.gethostname()}:{os.getpid()}"
    t0, c0 = time.perf_counter(), time.process_time()
    try:
        row.update(run_job(task, scratch))
        row["status"] = "ok"
    except _user_errors() as exc:
        shutil.rmtree(scratch, ignore_errors=True)
        row.update(status="failed", error=one_line(exc), seconds=time.perf_counter() - t0)
        return row
    except BaseException:
        shutil.rmtree(scratch, ignore_errors=True)
        raise
    row["seconds"] = time.perf_counter() - t0
    row["cpu_seconds"] = time.process_time() - c0  # all threads of the worker process
    if row.get("points_per_s") is None and row.get("points") and row["seconds"] > 0:
        row["points_per_s"] = row["points"] / row["seconds"]
    write_text_atomic(scratch / ROW_FILE, json.dumps(row, indent=2) + "\n")
    try:
        os.rename(scratch, final)
    except OSError:
        if (final / ROW_FILE).is_file():  # another attempt won the race: keep its result only
            shutil.rmtree(scratch, ignore_errors=True)
            return _published(final, batch_id)
        raise
    return row


def _published(final: Path, batch_id: str) -> dict[str, Any]:
    row = json.loads((final / ROW_FILE).read_text())
    if batch_id and row.get("batch_id") != batch_id:
        raise RuntimeError(f"{final}: holds the result of another batch; remove it or use --overwrite")
    return row


# ---------------------------------------------------------------------------------------------
# The batch (client side)
# ---------------------------------------------------------------------------------------------


def prepare_out(out: Path, tasks: list[Task], overwrite: bool) -> None:
    """Refuse to mix with earlier results unless ``overwrite`` (then remove the earlier batch's
    directories of these inputs; only directories a batch wrote, never anything else)."""
    out.mkdir(parents=True, exist_ok=True)
    for t in tasks:
        final = out / t.name
        if not final.exists():
            continue
        if not overwrite:
            raise ValueError(f"--out: {final} exists (an earlier batch?); use --overwrite or another --out")
        if not (final / ROW_FILE).is_file():
            raise ValueError(f"--out: {final} exists and was not written by a batch; not removing it")
        shutil.rmtree(final)


def input_bytes(path: Path) -> int:
    """Bytes on disk of an input (a file, or every file under a directory); 0 if missing."""
    try:
        if path.is_dir():
            return sum(e.stat().st_size for e in path.rglob("*") if e.is_file())
        return path.stat().st_size
    except OSError:
        return 0


def largest_first(tasks: list[Task]) -> list[int]:
    """Dask priorities (higher runs first) that start the largest inputs first: a long input
    started last would leave the other workers idle at the end of the batch (longest processing
    time first, the usual remedy)."""
    size = [input_bytes(Path(t.input)) for t in tasks]
    order = sorted(range(len(tasks)), key=lambda i: (size[i], -i))  # ties: plan order first
    rank = [0] * len(tasks)
    for r, i in enumerate(order):
        rank[i] = r
    return rank


def run_batch(
    tasks: list[Task],
    out: Path,
    client,
    *,
    reporter: Reporter | None = None,
    note: Callable[[str], None] | None = None,
    hook: Callable[[str], None] | None = None,
    retries: int = 2,
    overwrite: bool = False,
) -> dict[str, Any]:
    """Run every task on ``client``'s cluster; write ``summary.json``, ``summary.md`` and
    ``summary.png`` into ``out``; returns the summary. Failed inputs are rows with ``status``
    ``failed``; the batch itself only raises for plan or output-directory errors."""
    from distributed import as_completed

    out = Path(out).resolve()
    prepare_out(out, tasks, overwrite)
    batch_id = uuid.uuid4().hex
    (out / PARTIAL).mkdir(exist_ok=True)
    (out / PARTIAL / f"{batch_id}.batch").write_text(f"{batch_id}\n")  # tasks check they see OUT
    t0 = time.perf_counter()
    futures = {
        client.submit(
            run_task,
            t.model_dump(),
            str(out),
            hook,
            batch_id,
            key=f"batch-{t.name}-{batch_id[:8]}",
            pure=False,
            retries=retries,
            priority=rank,
        ): t
        for t, rank in zip(tasks, largest_first(tasks), strict=True)
    }
    bar = None if reporter is None else reporter.task("batch: inputs", len(tasks))
    rows: dict[str, dict[str, Any]] = {}
    for fut in as_completed(futures):
        t = futures[fut]
        try:
            row = fut.result()
        except Exception as exc:  # retries exhausted, or the worker died too often (KilledWorker)
            row = {"name": t.name, "input": t.input, "job": t.kind, "status": "failed"}
            row["error"] = f"{type(exc).__name__}: {one_line(exc)}"
        rows[t.name] = row
        if note is not None:
            state = "ok" if row["status"] == "ok" else f"FAILED: {row.get('error')}"
            note(f"{t.name}: {state}" + (f" ({row['seconds']:.1f} s)" if row.get("seconds") else ""))
        if bar is not None:
            bar.advance()
    wall = time.perf_counter() - t0
    shutil.rmtree(out / PARTIAL, ignore_errors=True)  # scratch of attempts that died
    summary = {
        "out": str(out),
        "wall_seconds": wall,
        "workers": len(client.scheduler_info(n_workers=-1).get("workers", {})),
        "inputs": len(tasks),
        "failed": sum(r["status"] != "ok" for r in rows.values()),
        "rows": [rows[t.name] for t in tasks],
    }
    write_summary(summary, out)
    return summary


def _fmt(v: Any, digits: int = 4) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return f"{v:.{digits}g}"
    if isinstance(v, int):
        return f"{v:,}"
    return str(v)


def summary_markdown(summary: dict[str, Any]) -> str:
    """``summary.md``: one row per input."""
    rows = summary["rows"]
    variants: list[str] = []
    for r in rows:
        for v in r.get("ate_rmse_m") or {}:
            if v not in variants:
                variants.append(v)
    head = ["input", "job", "status", "frames", "points", "points/s", "seconds"]
    head += [f"ATE {v} (m)" for v in variants] + ["failures"]
    lines = [
        "# Batch summary",
        "",
        f"{summary['inputs']} inputs, {summary['failed']} failed, {summary['workers']} workers, "
        f"{summary['wall_seconds']:.1f} s wall.",
        "",
        "| " + " | ".join(head) + " |",
        "|" + "---|" * len(head),
    ]
    for r in rows:
        ate = r.get("ate_rmse_m") or {}
        fails = []
        if r["status"] != "ok":
            fails.append(str(r.get("error", "failed")).replace("|", "\\|"))
        if r.get("failed_variants"):
            fails.append("odometry failed: " + ", ".join(r["failed_variants"]))
        if r.get("skipped_frames"):
            fails.append(f"{r['skipped_frames']} frames skipped")
        cells = [
            f"[{r['name']}]({r['name']}/)" if r["status"] == "ok" else r["name"],
            r["job"], r["status"], _fmt(r.get("frames")), _fmt(r.get("points")), _fmt(r.get("points_per_s"), 3),
            _fmt(r.get("seconds"), 3),
        ]  # fmt: skip
        cells += [_fmt(ate.get(v)) for v in variants] + ["; ".join(fails) or "-"]
        lines.append("| " + " | ".join(cells) + " |")
    lines += [
        "",
        "points/s: the job's own throughput figure (classify: PRC; detect: the detectors after their first "
        "frame; compare: the first variant's odometry; mapclass: the classification), else input points over "
        "the task's wall time. Each input's files are what the single-input command writes:",
        "",
    ]
    lines += [f"- `{k}`: `{v}`" for k, v in SINGLE_COMMAND.items() if any(r["job"] == k for r in rows)]
    lines += ["", "![summary](summary.png)", ""]
    return "\n".join(lines)


def write_summary(summary: dict[str, Any], out: Path) -> list[Path]:
    """``summary.json``, ``summary.md`` and the combined plot ``summary.png``."""
    write_json(out / "summary.json", summary)
    write_text_atomic(out / "summary.md", summary_markdown(summary))
    plot = summary_plot(summary, out / "summary.png")
    return [out / "summary.json", out / "summary.md"] + ([plot] if plot else [])


def summary_plot(summary: dict[str, Any], path: Path) -> Path | None:
    """Throughput per input and, where odometry ran, ATE per variant (one figure)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    rows = summary["rows"]
    names = [r["name"] for r in rows]
    variants = sorted({v for r in rows for v in (r.get("ate_rmse_m") or {})})
    panels = 2 if variants else 1
    fig, axes = plt.subplots(panels, 1, figsize=(max(6, 0.6 * len(rows) + 2), 3.2 * panels), squeeze=False)
    ax = axes[0, 0]
    pps = [r.get("points_per_s") or 0.0 for r in rows]
    colors = ["tab:blue" if r["status"] == "ok" else "tab:red" for r in rows]
    ax.bar(np.arange(len(rows)), np.array(pps) / 1e6, color=colors)
    ax.set_ylabel("M points/s")
    ax.set_title(f"{summary['inputs']} inputs, {summary['failed']} failed (red)")
    ax.set_xticks(np.arange(len(rows)), names, rotation=45, ha="right", fontsize=8)
    if variants:
        ax = axes[1, 0]
        width = 0.8 / len(variants)
        for j, v in enumerate(variants):
            vals = [(r.get("ate_rmse_m") or {}).get(v) for r in rows]
            ax.bar(
                np.arange(len(rows)) + (j - (len(variants) - 1) / 2) * width,
                [np.nan if x is None else x for x in vals],
                width,
                label=v,
            )
        ax.set_ylabel("ATE RMSE (m)")
        ax.legend(fontsize=8)
        ax.set_xticks(np.arange(len(rows)), names, rotation=45, ha="right", fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}.png")
    fig.savefig(tmp, dpi=90)
    plt.close(fig)
    os.replace(tmp, path)
    return path
