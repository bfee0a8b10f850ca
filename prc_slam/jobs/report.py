"""Outputs of ``prc-slam compare``: trajectories, metrics JSON, report.md and plots."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from prc_slam.config import Config
from prc_slam.evaluation import metrics as E
from prc_slam.odometry.compare import CompareResult

FIELDS = ("ate_rmse_m", "rpe_trans_m", "kitti_trans_pct", "ms_per_frame", "points_in", "points_to_icp", "frames")


#: said of a class a method never outputs, instead of scores that are 0 (or undefined) by construction
NOT_OUTPUT = "not output by this method"
#: a class the method outputs while the reference has none of it (SemanticKITTI has no curbs): its
#: precision is 0 by construction, every such label counting as wrong
NOT_IN_REFERENCE = "none in the reference"


def _fmt(v: Any) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return f"{v:.4g}" if abs(v) < 1000 else f"{v:,.0f}"
    return str(v)


def too_short_for_kitti(m: dict[str, Any]) -> bool:
    """Whether a variant has no KITTI drift because its path is shorter than KITTI's shortest
    segment (100 m): the devkit's error is a mean over segments of 100 to 800 m."""
    path = m.get("path_length_m")
    return m.get("kitti_trans_pct") is None and path is not None and path < E.KITTI_LENGTHS[0]


def variant_cell(m: dict[str, Any], field: str) -> str:
    """One cell of the variants table: ``-`` says why where a figure is missing for a reason a
    reader would not guess (the KITTI drift of a path under 100 m)."""
    if field == "kitti_trans_pct" and too_short_for_kitti(m):
        return f"- (path < {E.KITTI_LENGTHS[0]} m)"
    return _fmt(m.get(field))


def kitti_note(variants: dict[str, dict[str, Any]]) -> list[str]:
    """Markdown lines under the variants table when the KITTI drift is missing for a short path."""
    short = [m["path_length_m"] for m in variants.values() if too_short_for_kitti(m)]
    if not short:
        return []
    lo, hi = E.KITTI_LENGTHS[0], E.KITTI_LENGTHS[-1]
    return [
        "",
        f"`kitti_trans_pct` is `-` because the path is {max(short):.1f} m long: KITTI's drift is the mean "
        f"relative error over path segments of {lo} to {hi} m, and no segment of {lo} m fits in it.",
    ]


def class_rows(per_class: dict[str, dict[str, Any]], fmt) -> list[tuple[str, int, str, str, str]]:
    """Rows ``(class, support, precision, recall, f1)`` of a per-class score table, scores
    formatted by ``fmt``. A class the method never outputs (no precision: nothing labelled so,
    while the reference has points of it) is named so, its scores ``-`` (its recall and F1 are 0
    by construction, not by a mistake); a class it outputs while the reference has none of it is
    named so too (its precision 0 by construction); a class it outputs but gets wrong keeps its 0."""
    rows = []
    for name, s in per_class.items():
        support = int(s.get("support") or 0)
        if s.get("precision") is None and support:
            rows.append((f"{name} ({NOT_OUTPUT})", support, "-", "-", "-"))
        elif not support and s.get("precision") is not None:  # labelled so, but not a class of the reference
            rows.append(
                (f"{name} ({NOT_IN_REFERENCE})", support, *(fmt(s.get(k)) for k in ("precision", "recall", "f1")))
            )
        else:
            rows.append((name, support, *(fmt(s.get(k)) for k in ("precision", "recall", "f1"))))
    return rows


def icp_share_rows(m: dict[str, Any]) -> list[str]:
    """Markdown: points per class in and to ICP with the share that reached it, and why noise
    reaches it at all."""
    kept = m["points_kept_per_class"]
    lines = ["| class | in | to ICP | share to ICP |", "|---|---|---|---|"]
    for cls, n in m["points_in_per_class"].items():
        k = kept.get(cls, 0)
        lines.append(f"| {cls} | {n} | {k} | {k / n:.0%} |" if n else f"| {cls} | {n} | {k} | - |")
    noise_in, noise_kept = m["points_in_per_class"].get("noise", 0), kept.get("noise", 0)
    if noise_kept:
        lines += [
            "",
            f"Noise is dropped except on purpose: {noise_kept:,} of the {noise_in:,} noise-labelled points "
            f"({noise_kept / noise_in:.0%}) reached ICP. They are PRC's one-sided returns, which meet one of the two "
            "support conditions of eq. (4) (thin poles, trunks, edges seen from one side): they are labelled noise "
            "but kept (`filter.keep_one_sided`, `prc_slam.filtering`), since dropping them would remove the thin "
            "structures that anchor the registration.",
        ]
    return lines


def health_section(result: CompareResult, metrics: dict[str, Any]) -> list[str]:
    """Markdown lines: which variants failed (frame, reason), and each variant's first
    suspicious frame (ICP residual, threshold or inlier fraction off its running level)."""
    variants = metrics["variants"]
    n_frames = len(result.times)
    lines = ["", "## Health of each variant", ""]
    lines += ["| variant | status | first suspicious frame | why | suspicious frames | mean inlier fraction |"]
    lines += ["|---|---|---|---|---|---|"]
    for name, m in variants.items():
        if m.get("failed"):
            status = f"**FAILED at frame {m['failed_at_frame']}**: {m['failure_reason']}"
        elif m.get("health") == "untrustworthy":
            status = f"**untrustworthy**: {m['health_reason']}"
        else:
            status = f"ok ({m['frames']} of {n_frames} frames)"
        first = m.get("first_suspicious_frame")
        where = "-" if first is None else str(first)
        if first is not None and first < len(result.names):
            where += f" (`{result.names[first]}`)"
        fr = [f for f in m.get("per_frame", {}).get("inlier_fraction", []) if f is not None]
        lines.append(
            f"| {name} | {status} | {where} | {m.get('first_suspicious_reason') or '-'} | "
            f"{len(m.get('suspicious_frames', []))} | {_fmt(float(np.mean(fr)) if fr else None)} |"
        )
    failed = [n for n, m in variants.items() if m.get("failed")]
    if failed:
        lines += [
            "",
            "A failed variant's trajectory, metrics and times cover the frames before its failure; "
            "its error figures are therefore not comparable with the others'.",
        ]
    disagreements = metrics.get("disagreements", {})
    if disagreements:
        lines += [
            "",
            "Variants whose motions disagree (first frame, frames, largest difference over the window, suspect):",
            "",
        ]
        for pair, d in disagreements.items():
            lines.append(
                f"- {pair}: from frame {d['first_frame']}, {d['frames']} frames, up to "
                f"{_fmt(d['max_difference_m'])} m / {_fmt(d['max_difference_deg'])} deg; "
                f"suspect: {', '.join(d['suspects']) or '-'}"
            )
    for name, why in metrics.get("skipped_variants", {}).items():
        lines.append(f"- `{name}` skipped: {why}")
    return lines


def markdown_report(result: CompareResult, metrics: dict[str, Any], title: str) -> str:
    """The report: metrics table, health (failures, first suspicious frame), per-stage timings,
    points per class."""
    variants = metrics["variants"]
    fields = [f for f in FIELDS if any(f in m for m in variants.values())]
    lines = [f"# {title}", "", "| variant | " + " | ".join(fields) + " |", "|---" * (len(fields) + 1) + "|"]
    for name, m in variants.items():
        mark = " (failed)" if m.get("failed") else " (untrustworthy)" if m.get("health") == "untrustworthy" else ""
        lines.append(f"| {name}{mark} | " + " | ".join(variant_cell(m, f) for f in fields) + " |")
    lines += kitti_note(variants)
    base = variants.get("raw")
    if base and base.get("ms_per_frame"):
        lines += ["", "Relative to `raw`:", ""]
        for name, m in variants.items():
            if name == "raw" or not m.get("ms_per_frame"):
                continue
            parts = [f"time x{m['ms_per_frame'] / base['ms_per_frame']:.3f}"]
            if m.get("ate_rmse_m") is not None and base.get("ate_rmse_m"):
                parts.append(f"ATE x{m['ate_rmse_m'] / base['ate_rmse_m']:.3f}")
            if m.get("failed") or base.get("failed"):
                parts.append("(over different frames: a variant failed)")
            lines.append(f"- `{name}`: " + ", ".join(parts))
    if metrics.get("no_variant_trusted"):  # the run's verdict leads, right under the title
        at = next((i + 1 for i, line in enumerate(lines) if line.startswith("# ")), 0)
        lines[at:at] = ["", f"**{metrics['no_variant_trusted']}**"]
    lines += health_section(result, metrics)
    lines += [
        "",
        "## Milliseconds per frame, by stage",
        "",
        "`overlapped`: stage time that ran beside another (the next frame's organising, PRC and filter",
        "beside this frame's registration, `odometry.overlap`), not counted in `ms_per_frame`.",
        "",
        "| variant | prc | filter | icp | overlapped |",
        "|---|---|---|---|---|",
    ]
    for name, m in variants.items():
        st = m.get("ms_per_stage", {})
        cells = [_fmt(st.get(k)) for k in ("prc", "filter", "icp")] + [_fmt(m.get("ms_overlapped"))]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    for name, m in variants.items():
        if "points_in_per_class" in m:
            lines += ["", f"## Points per class, `{name}` (all frames)", "", *icp_share_rows(m)]
    if result.gt_poses is None:
        lines += ["", "No ground truth: error fields omitted."]
    return "\n".join(lines) + "\n"


def plot_trajectories(result: CompareResult, path: Path) -> None:
    """Top view of ground truth and every variant, and position error along the path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2 if result.gt_poses is not None else 1, figsize=(13, 5.5), squeeze=False)
    ax = axes[0, 0]
    if result.gt_poses is not None:
        ax.plot(result.gt_poses[:, 0, 3], result.gt_poses[:, 1, 3], "k-", lw=2.5, label="ground truth")
    for name, run in result.runs.items():
        p = result.estimate_in_world(name)
        if not len(p):
            continue
        label = name if run.failed is None else f"{name} (failed at frame {run.failed['frame']})"
        (line,) = ax.plot(p[:, 0, 3], p[:, 1, 3], lw=1.2, label=label)
        if run.failed is not None:
            ax.plot(p[-1, 0, 3], p[-1, 1, 3], "x", color=line.get_color(), ms=10, mew=2)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title("top view")
    if ax.get_legend_handles_labels()[0]:
        ax.legend()
    if result.gt_poses is not None:
        ax = axes[0, 1]
        gt = result.gt_poses
        dist = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(gt[:, :3, 3], axis=0), axis=1))])
        for name in result.runs:
            est = result.estimate_in_world(name)
            n = len(est)
            if n < 3:
                continue
            rot, t, _ = E.umeyama(est[:, :3, 3], gt[:n, :3, 3])
            err = np.linalg.norm(est[:, :3, 3] @ rot.T + t - gt[:n, :3, 3], axis=1)
            ax.plot(dist[:n], err, label=name)
        ax.set_xlabel("distance along the path (m)")
        ax.set_ylabel("position error after alignment (m)")
        ax.set_title("error along the path")
        if ax.get_legend_handles_labels()[0]:
            ax.legend()
        else:  # fewer than 3 poses per variant: nothing to align
            ax.text(0.5, 0.5, "fewer than 3 poses", ha="center", va="center", transform=ax.transAxes)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_compare_outputs(
    result: CompareResult, config: Config, out: Path, title: str, pose_writer, tum_writer
) -> tuple[dict[str, Any], list[Path]]:
    """Write trajectories, frames.txt, metrics.json, config.yaml, report.md and trajectories.png
    into ``out``; the metrics and the paths written.

    The KITTI-format trajectories have one line per registered frame and no times: ``frames.txt``
    gives the time and input frame of each line. ``pose_writer(path, poses)`` and
    ``tum_writer(path, times, poses)`` are injected (data_tools)."""
    out.mkdir(parents=True, exist_ok=True)
    metrics = result.metrics()
    tracks = {name: (result.estimate_in_world(name), result.times) for name in result.runs}
    if result.gt_poses is not None:
        tracks["ground_truth"] = (result.gt_poses, result.times)
    written = []
    for name, (poses, times) in tracks.items():
        pose_writer(out / f"{name}_poses_kitti.txt", poses)
        tum_writer(out / f"{name}_poses_tum.txt", times[: len(poses)], poses)  # a failed variant's stop early
        written += [out / f"{name}_poses_kitti.txt", out / f"{name}_poses_tum.txt"]
    lines = zip(result.names, result.times, strict=True)
    (out / "frames.txt").write_text(
        "# line of the *_poses_kitti.txt files, time (s), input frame\n"
        + "".join(f"{i} {t:.9f} {name}\n" for i, (name, t) in enumerate(lines))
    )
    (out / "metrics.json").write_text(json.dumps(metrics, indent=2) + "\n")
    config.to_yaml(out / "config.yaml")
    (out / "report.md").write_text(markdown_report(result, metrics, title))
    plot_trajectories(result, out / "trajectories.png")
    files = ("report.md", "metrics.json", "trajectories.png", "config.yaml", "frames.txt")
    return metrics, [out / n for n in files] + written


def mapclass_section(mc: dict[str, Any]) -> str:
    """Markdown for ``compare --mapclass``: the map classification and PRC's agreement with it."""

    def table(per_class: dict[str, dict[str, Any]]) -> list[str]:
        rows = ["| class | support | precision | recall | f1 |", "|---|---|---|---|---|"]
        for name, support, *vals in class_rows(per_class, _fmt):
            rows.append(f"| {name} | {support:,} | " + " | ".join(vals) + " |")
        return rows

    lines = [
        "",
        "## Map classification after registration (paper 004)",
        "",
        f"{mc['points']:,} map points at the `{mc['poses']}` poses, classified in {mc['seconds']:.2f} s "
        f"({mc['points_per_s'] / 1e6:.2f} M points/s). Points per class: "
        + ", ".join(f"{k} {v:,}" for k, v in mc["counts"].items()),
        "",
    ]
    if "per_class" in mc:
        lines += ["Against the reference labels:", "", *table(mc["per_class"]), ""]
    for name, o in mc.get("objects", {}).items():
        lines.append(f"- {name} objects found: {o['found']} of {o['present']}")
    if "prc_vs_map" in mc:
        lines += [
            "",
            "PRC labels scored against the map classification:",
            "",
            *table(mc["prc_vs_map"]["per_class"]),
            "",
        ]
    return "\n".join(lines) + "\n"


def classification_section(metrics: dict[str, Any], title: str) -> str:
    """Markdown for per-class scores (the ``classify``/``detect`` metrics' ``per_class``)."""
    lines = ["", f"## {title}", ""]
    per_class = metrics.get("per_class")
    if not per_class:
        return "\n".join([*lines, "No reference labels in this input.", ""]) + "\n"
    lines += ["| class | support | precision | recall | f1 |", "|---|---|---|---|---|"]
    for name, support, *vals in class_rows(per_class, _fmt):
        lines.append(f"| {name} | {support:,} | " + " | ".join(vals) + " |")
    if "noise_in_solid_classes" in metrics:
        lines += ["", f"Reference solid-class points labelled noise: {metrics['noise_in_solid_classes']:.3%}"]
    for name, o in metrics.get("objects", {}).items():
        lines.append(f"- {name} objects found: {o['found']} of {o['present']}")
    if "vehicle_by_range" in metrics:  # per-instance scores by range band (online detectors)
        from prc_slam.evaluation.scoring import range_band_rows

        header, rows = range_band_rows(metrics["vehicle_by_range"])
        lines += ["", "Vehicles by range (found: at least half of an instance's points labelled vehicle):", ""]
        lines += ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
        lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines) + "\n"
