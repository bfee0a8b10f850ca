"""What every job shares: opening an input, writing results atomically, the Rerun viewer."""

from __future__ import annotations

import json
import logging
import os
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from data_tools import DataError, open_dataset
from prc_slam.config import Config
from prc_slam.pipeline import FrameError
from prc_slam.scan import Scan, ScanError

log = logging.getLogger("prc_slam")


def open_input(path: Path, fmt: str | None = None, max_frames: int | None = None, stride: int = 1, **options: Any):
    """Open ``path`` (format detected unless ``fmt``); returns the dataset (every ``stride``-th
    frame of it) and the frame count used."""
    if max_frames is not None and max_frames < 1:
        raise ValueError(f"--max-frames: must be at least 1, got {max_frames}")
    if stride < 1:
        raise ValueError(f"--stride: must be at least 1, got {stride}")
    dataset = open_dataset(path, fmt, **{k: v for k, v in options.items() if v is not None})
    if stride > 1:
        dataset = Strided(dataset, stride)
    n = len(dataset) if max_frames is None else min(max_frames, len(dataset))
    if n == 0:
        raise DataError(f"{path}: no frames")
    return dataset, n


class Strided:
    """Every ``stride``-th frame of ``dataset`` (keyframes: 5 turns a 10 Hz sensor into 2 Hz);
    frame ``i`` is the dataset's frame ``i * stride``, with its own name, times and pose."""

    def __init__(self, dataset, stride: int) -> None:
        self.dataset, self.stride = dataset, int(stride)

    def __len__(self) -> int:
        return -(-len(self.dataset) // self.stride)

    def __getitem__(self, i: int) -> Scan:
        if not 0 <= i < len(self):
            raise IndexError(i)
        return self.dataset[i * self.stride]

    def __getattr__(self, name: str) -> Any:  # the dataset's other attributes (poses, sensor, ...)
        if name == "dataset":  # not set yet (unpickling)
            raise AttributeError(name)
        return getattr(self.dataset, name)


class frames_of(Iterator[Scan]):
    """The first ``n`` scans of ``dataset``. A frame that cannot be read raises :class:`FrameError`
    from ``next()`` and the iteration goes on with the next frame, so the pipeline skips and counts
    it instead of ending the run."""

    def __init__(self, dataset, n: int) -> None:
        self.dataset, self.n, self.i = dataset, n, 0

    def __next__(self) -> Scan:
        if self.i >= self.n:
            raise StopIteration
        i, self.i = self.i, self.i + 1
        try:
            return self.dataset[i]
        except (DataError, ScanError) as exc:
            raise FrameError(str(exc)) from exc


def _json_default(value: object) -> object:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")


def write_text_atomic(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` through a temporary name, so a reader never sees half a file."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    tmp.write_text(text)
    os.replace(tmp, path)


def write_json(path: Path, data: dict[str, Any], config: Config | None = None) -> list[Path]:
    """The metrics JSON (and ``<stem>.config.yaml`` beside it with the config actually used)."""
    write_text_atomic(path, json.dumps(data, indent=2, default=_json_default) + "\n")
    written = [path]
    if config is not None:
        cfg_path = path.with_name(path.stem + ".config.yaml")
        config.to_yaml(cfg_path)
        written.append(cfg_path)
    return written


def _shown(path: Path) -> str:
    """``path`` as the user would type it: relative to the working directory when below it."""
    try:
        return str(path.relative_to(Path.cwd()))
    except ValueError:
        return str(path)


#: seconds the recording may take to reach its file or viewer at the end of a run; beyond, the
#: rest is dropped with a warning instead of blocking (a viewer that stopped taking data)
FLUSH_TIMEOUT_S = 20.0


def exposed_warning(bind: str, ports: list[int]) -> str | None:
    """The warning for serving on an address other than the loopback (``--bind``), else None."""
    from prc_slam.viz.sink import is_loopback

    if is_loopback(bind):
        return None
    where = "this machine" if bind in ("0.0.0.0", "::") else bind
    listed = "/".join(str(p) for p in ports)
    return (
        f"serving on {bind}: anyone who can reach {where} on port{'s' if len(ports) > 1 else ''} {listed} "
        "can watch and send data"
    )


class Viewer:
    """Where a run's Rerun recording goes: an ``.rrd`` file, a running viewer, the web viewer or a
    spawned desktop viewer; a no-op when none is asked for.

    The file is written as ``NAME.partial.rrd`` and renamed to ``NAME.rrd`` only when the run
    completes; an interrupted run leaves ``NAME.partial.rrd`` ending with a text log
    ``interrupted at frame k``. What is served listens on ``bind`` (the loopback by default; any
    other address is said in a warning). A spawned viewer is watched: when it ends during the run,
    the next frame's logging raises :class:`~prc_slam.viz.sink.ViewerError` instead of waiting for
    it forever.
    """

    def __init__(
        self,
        rrd: Path | None = None,
        connect: str | None = None,
        serve_web: bool = False,
        every: int = 5,
        spawn: bool = False,
        serve_seconds: float | None = None,
        map_voxel: float = 0.5,
        web_port: int | None = None,
        grpc_port: int | None = None,
        bind: str = "127.0.0.1",
        spawn_name: str = "--spawn",
    ) -> None:
        self.sink = None
        self.rrd = rrd
        self.address: str | None = None
        self.serve_web, self.serve_seconds = serve_web, serve_seconds
        self._spawned = None  # a desktop viewer started for this run (it stays open after it)
        self._servers: list = []  # the web viewer's server (ended with the run)
        self.spawn_name = spawn_name
        if rrd is None and connect is None and not serve_web and not spawn:
            return
        from prc_slam.viz.sink import RerunSink, ViewerError, VizConfig, has_display, start_recording

        if spawn and not has_display():
            raise ViewerError(
                f"{spawn_name}: no display to open the viewer on; use --serve-web (browser) or --rrd FILE "
                f"(open later with {_shown(Path(sys.executable).parent / 'rerun')} FILE)"
            )
        if serve_web and (note := exposed_warning(bind, [web_port or 9090, grpc_port or 9876])):
            log.warning(note)
        if rrd is not None:
            rrd.parent.mkdir(parents=True, exist_ok=True)
        rec, self.address, procs = start_recording(
            rrd=None if rrd is None else str(self.partial_path),
            connect=connect,
            serve_web=serve_web,
            spawn=spawn,
            web_port=web_port,
            grpc_port=grpc_port,
            bind=bind,
            spawn_name=spawn_name,
        )
        if spawn:
            self._spawned = procs[0] if procs else None
        else:
            self._servers = procs
        self.sink = RerunSink(rec, VizConfig(every=every, map_every=every, map_voxel=map_voxel))
        self.sink.check = self.check
        if self.address:
            log.info(f"web viewer: {self.address}")

    def check(self) -> None:
        """Raise :class:`~prc_slam.viz.sink.ViewerError` when the spawned viewer has ended."""
        if self._spawned is not None and (code := self._spawned.poll()) is not None:
            from prc_slam.viz.sink import ViewerError

            self._spawned = None
            self.sink = None
            raise ViewerError(
                f"{self.spawn_name}: the Rerun viewer ended during the run (exit code {code}); the run stopped"
            )

    @property
    def partial_path(self) -> Path:
        assert self.rrd is not None
        stem = self.rrd.name[: -len(".rrd")] if self.rrd.name.endswith(".rrd") else self.rrd.name
        return self.rrd.with_name(stem + ".partial.rrd")

    def close(self, interrupted_at: int | None = None) -> Path | None:
        """Flush the recording (at most :data:`FLUSH_TIMEOUT_S`); rename the file when complete;
        serve the web viewer on for ``serve_seconds``, then end its server. Returns the file
        written."""
        if self.sink is None:
            self._end_servers()
            return None
        if interrupted_at is not None:
            self.sink.warn(f"interrupted at frame {interrupted_at}: this recording is partial")
        try:
            self.sink.rec.flush(timeout_sec=FLUSH_TIMEOUT_S)
        except RuntimeError as exc:  # e.g. the viewer at --connect never answered: the rest stands
            log.warning(f"Rerun: the recording could not be delivered: {str(exc).splitlines()[0]}")
        written = None
        if self.rrd is not None:
            self.sink.rec.disconnect()
            if interrupted_at is None:
                os.replace(self.partial_path, self.rrd)
                written = self.rrd
            else:
                written = self.partial_path
        if self.serve_web and interrupted_at is None:
            limit = "" if self.serve_seconds is None else f" for {self.serve_seconds:g} s"
            log.info(f"run finished; still serving the web viewer{limit} (Ctrl-C to stop)")
            deadline = None if self.serve_seconds is None else time.monotonic() + self.serve_seconds
            try:
                while deadline is None or time.monotonic() < deadline:
                    time.sleep(0.2)
            except KeyboardInterrupt:
                pass
        self._end_servers()
        return written

    def _end_servers(self) -> None:
        """End the web viewer's server (a spawned desktop viewer stays open)."""
        import subprocess

        for proc in self._servers:
            if proc.poll() is None:
                proc.terminate()
                try:
                    proc.wait(2.0)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait()
        self._servers = []
