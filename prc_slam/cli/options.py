"""The options several commands share, each defined once.

A shared option is an ``Annotated`` alias (typer's way of reusing an option): the command names
the parameter and gives its default, the alias gives the flag, the range and the help. Options
that come together in several commands are an option group (how the input is read, which frames,
the label outputs, where the Rerun recording goes): typer has no groups, so :func:`grouped` puts a
group's options into the command's signature where the parameter annotated with the group stands
(the help lists them there), and hands the command the group as one value.
"""

import dataclasses
import functools
import inspect
import typing
from pathlib import Path
from typing import Annotated, Any, Literal

import typer

from prc_slam.cli.common import Preset

AnyInput = Annotated[
    Path, typer.Argument(help="any supported input (KITTI, Ouster pcap/npz, bag, MCAP, PCD folder, ...)")
]
SequenceInput = Annotated[
    Path, typer.Argument(help="any supported input (KITTI, simulated, Ouster, bag, MCAP, PCD folder)")
]
Topic = Annotated[str | None, typer.Option("--topic", help="bags/MCAP: the PointCloud2 topic (when there are several)")]
Meta = Annotated[
    Path | None, typer.Option("--meta", help="Ouster pcap: the sensor's metadata json (default: beside the pcap)")
]
Model = Annotated[
    str | None, typer.Option("--model", help="Velodyne pcap: the sensor model (default: from the packets)")
]
Rows = Annotated[
    int | None, typer.Option("--rows", min=1, help="unorganised sweeps: the sensor's beams (default: estimated)")
]
Cols = Annotated[
    int | None, typer.Option("--cols", min=1, help="unorganised sweeps: columns per sweep (default: estimated)")
]
Organize = Annotated[
    Literal["auto", "ring", "order", "beams"] | None,
    typer.Option(
        "--organize", help="unorganised sweeps: rows from a ring field, the point order or the beams (default: auto)"
    ),
]
Format = Annotated[str | None, typer.Option("--format", help="input format (default: detected)")]
MaxFrames = Annotated[int | None, typer.Option("--max-frames", min=1, help="use only the first N frames")]
Stride = Annotated[
    int,
    typer.Option(
        "--stride",
        min=1,
        help="use every N-th frame (keyframes: 5 turns a 10 Hz sensor into 2 Hz); before --max-frames",
    ),
]
Json = Annotated[Path | None, typer.Option("--json", help="write the metrics JSON here")]
RunConfig = Annotated[Path | None, typer.Option(help="YAML config (prc, filter, odometry sections)")]
PrcPreset = Annotated[Preset, typer.Option(help="PRC parameters")]
Deskew = Annotated[bool, typer.Option("--deskew/--no-deskew", help="KISS-ICP's constant-velocity deskewing")]

Rrd = Annotated[Path | None, typer.Option("--rrd", help="write a Rerun recording (.rrd) here")]
Connect = Annotated[
    str | None,
    typer.Option("--connect", help="stream to a running Rerun viewer at this URL (rerun+http, port 9876, path /proxy)"),
]
ServeWeb = Annotated[
    bool, typer.Option("--serve-web", help="serve the Rerun web viewer on localhost and print its address")
]
LogEvery = Annotated[int, typer.Option("--log-every", min=1, help="log clouds and images on every n-th frame")]
MapVoxel = Annotated[float, typer.Option("--map-voxel", min=0.0, help="thin the logged local map to this voxel (m)")]
ServeSeconds = Annotated[
    float | None, typer.Option("--serve-seconds", min=0.0, help="with --serve-web: stop serving after this long")
]
WebPort = Annotated[
    int | None, typer.Option("--web-port", min=1, max=65535, help="with --serve-web: HTTP port (default 9090)")
]
GrpcPort = Annotated[
    int | None, typer.Option("--grpc-port", min=1, max=65535, help="with --serve-web: stream port (default 9876)")
]
Bind = Annotated[
    str,
    typer.Option(
        "--bind",
        help="address what is served listens on (default the loopback: this machine only; 0.0.0.0: every interface)",
    ),
]
LOOPBACK = "127.0.0.1"


@dataclasses.dataclass(frozen=True)
class ReaderOptions:
    """How the input is read where it does not say so itself (``open_dataset``'s keywords)."""

    topic: Topic = None
    meta: Meta = None
    model: Model = None
    rows: Rows = None
    cols: Cols = None
    organize: Organize = None
    fmt: Format = None

    def open_options(self, destaggered: bool = True) -> dict[str, Any]:
        """The reader options given on the command line (only those set), for ``open_dataset``
        (``--format`` goes on its own: :attr:`fmt`)."""
        opts: dict[str, Any] = dict(topic=self.topic, meta=self.meta, model=self.model, rows=self.rows, cols=self.cols)
        if self.organize is not None:
            opts["organize_method"] = self.organize
        if not destaggered:  # (the readers' default is destaggered)
            opts["destaggered"] = False
        return {k: v for k, v in opts.items() if v is not None}


@dataclasses.dataclass(frozen=True)
class FrameOptions:
    """Which frames of a sequence are used."""

    max_frames: MaxFrames = None
    stride: Stride = 1


@dataclasses.dataclass(frozen=True)
class LabelOutputs:
    """The labels written as the frames are labelled: one file per frame, and the points as LAS."""

    labels_out: Annotated[Path | None, typer.Option(help="write NNNNNN.label per frame here")] = None
    las: Annotated[Path | None, typer.Option(help="write the labelled points as LAS 1.4 (.laz: compressed)")] = None

    def job_outputs(self) -> Any:
        """As the jobs take them (:class:`prc_slam.jobs.classify.Outputs`)."""
        from prc_slam.jobs.classify import Outputs

        return Outputs(self.labels_out, self.las)


@dataclasses.dataclass(frozen=True)
class RerunOptions:
    """Where the run's Rerun recording goes: a file, a running viewer, the web viewer."""

    rrd: Rrd = None
    connect: Connect = None
    serve_web: ServeWeb = False

    def viewer(self, log_every: int, **options: Any) -> Any:
        """The run's :class:`prc_slam.jobs.common.Viewer` (``options``: its further keywords)."""
        from prc_slam.jobs.common import Viewer

        return Viewer(self.rrd, self.connect, self.serve_web, log_every, **options)


@dataclasses.dataclass(frozen=True)
class ServedRerunOptions(RerunOptions):
    """:class:`RerunOptions` and the address what is served listens on."""

    bind: Bind = LOOPBACK

    def viewer(self, log_every: int, **options: Any) -> Any:
        return super().viewer(log_every, bind=self.bind, **options)


def grouped(fn: Any) -> Any:
    """``fn`` as typer sees it: every parameter annotated with an option group (a dataclass of
    ``Annotated`` fields) replaced by the group's options, in the group's order, at its place;
    ``fn`` is called with the group built from them."""
    signature = inspect.signature(fn, eval_str=True)
    groups: dict[str, Any] = {}
    params: list[inspect.Parameter] = []
    for param in signature.parameters.values():
        if not dataclasses.is_dataclass(param.annotation):
            params.append(param.replace(kind=inspect.Parameter.KEYWORD_ONLY))
            continue
        groups[param.name] = group = param.annotation
        hints = typing.get_type_hints(group, include_extras=True)
        params += [
            inspect.Parameter(f.name, inspect.Parameter.KEYWORD_ONLY, default=f.default, annotation=hints[f.name])
            for f in dataclasses.fields(group)
        ]

    @functools.wraps(fn)
    def command(**kwargs: Any) -> Any:
        for name, group in groups.items():
            kwargs[name] = group(**{f.name: kwargs.pop(f.name) for f in dataclasses.fields(group)})
        return fn(**kwargs)

    command.__signature__ = signature.replace(parameters=params)  # type: ignore[attr-defined]
    return command
