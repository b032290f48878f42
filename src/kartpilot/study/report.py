"""A study's report: its rows as CSV, figures, and a Markdown page that answers each question with numbers.

Every mean is over the seeds of a simulated source and comes with a 95 % interval (Student's t over the
seeds; none for a real dataset, which is one cell). The thesis's figure numbers are given beside ours.
"""

from __future__ import annotations

import itertools
import json
import math
from collections import defaultdict
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from kartpilot.core.files import write_csv_atomic, write_text_atomic
from kartpilot.eval.plots import pyplot
from kartpilot.study.jobs import DEPTH_EDGES_M, GRID_COLS, GRID_ROWS
from kartpilot.study.run import load_rows

__all__ = ["Estimate", "estimate", "paired_effects", "write_report"]

Row = dict[str, Any]


@dataclass(frozen=True)
class Estimate:
    """A mean over ``n`` values and the half-width of its 95 % interval (nan with one value)."""

    mean: float
    half_width: float
    n: int

    def text(self, digits: int = 2, unit: str = "") -> str:
        if self.n == 0 or math.isnan(self.mean):
            return "n/a"
        body = f"{self.mean:.{digits}f}"
        if self.n > 1 and not math.isnan(self.half_width):
            body += f" ± {self.half_width:.{digits}f}"
        return body + unit


def estimate(values: Iterable[float]) -> Estimate:
    """Mean and 95 % t-interval of the finite values."""
    data = np.array([v for v in values if v is not None and np.isfinite(v)], float)
    if len(data) == 0:
        return Estimate(math.nan, math.nan, 0)
    if len(data) == 1:
        return Estimate(float(data[0]), math.nan, 1)
    from scipy import stats  # here, not at import: scipy.stats alone costs a command a fifth of a second

    half = float(stats.t.ppf(0.975, len(data) - 1) * data.std(ddof=1) / math.sqrt(len(data)))
    return Estimate(float(data.mean()), half, len(data))


def _ok(rows: Iterable[Row]) -> list[Row]:
    return [r for r in rows if r.get("status") == "ok"]


def _value(row: Row, metric: str) -> float:
    value = row.get(metric)
    if isinstance(value, bool):
        return float(value)
    return float(value) if isinstance(value, (int, float)) else math.nan


def _groups(rows: Iterable[Row], keys: Sequence[str]) -> dict[tuple[Any, ...], list[Row]]:
    out: dict[tuple[Any, ...], list[Row]] = defaultdict(list)
    for row in rows:
        out[tuple(row[k] for k in keys)].append(row)
    return out


def paired_effects(rows: Sequence[Row], metric: str, baseline: str) -> dict[str, Estimate]:
    """Each variant's change of ``metric`` against ``baseline`` on the same source and seed (in the same part
    where it has one), over all pairs."""
    base = {(r.get("part"), r["source"], r["seed"]): _value(r, metric) for r in _ok(rows) if r["variant"] == baseline}
    anywhere = {(r["source"], r["seed"]): _value(r, metric) for r in _ok(rows) if r["variant"] == baseline}
    diffs: dict[str, list[float]] = defaultdict(list)
    for row in _ok(rows):
        if row["variant"] == baseline:
            continue
        # the baseline of the row's own part, else of another part (a part that only changes the job's params)
        reference = base.get((row.get("part"), row["source"], row["seed"]), anywhere.get((row["source"], row["seed"])))
        if reference is not None:
            diffs[row["variant"]].append(_value(row, metric) - reference)
    return {variant: estimate(values) for variant, values in diffs.items()}


def _table(rows: Sequence[Row], metrics: Sequence[tuple[str, str, int]], keys: Sequence[str] = ("variant", "source")
           ) -> str:
    """A Markdown table: one line per (variant, source), mean ± interval of each metric over seeds."""
    header = [k for k in keys] + ["runs"] + [label for _, label, _ in metrics]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for group, members in _groups(_ok(rows), keys).items():
        cells = [str(g) for g in group] + [str(len(members))]
        cells += [estimate(_value(r, m) for r in members).text(d) for m, _, d in metrics]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _save(figure: Any, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_name(path.stem + ".partial.png")
    figure.savefig(partial, dpi=110, bbox_inches="tight")
    pyplot().close(figure)
    partial.replace(path)
    return path


# --- features (RQ2) -----------------------------------------------------------------------------------------

def _share(arrays: list[np.ndarray]) -> np.ndarray:
    total = np.sum(arrays, axis=0).astype(float)
    return total / total.sum() if total.sum() > 0 else total


def _features(rows: list[Row], figures: Path) -> tuple[list[str], dict[str, str]]:
    ok = _ok(rows)
    cones = [r for r in ok if r["part"] in ("cones", "real frames")]
    sections, answers = [], {}
    labels = list(dict.fromkeys((r["variant"], r["source"]) for r in cones))
    fig, axes = pyplot().subplots(1, 2, figsize=(12, 4))
    width = 0.8 / max(len(labels), 1)
    for i, (variant, source) in enumerate(labels):
        members = [r for r in cones if r["variant"] == variant and r["source"] == source]
        grid = _share([np.array(r["grid_counts"]).ravel() for r in members])
        depth = _share([np.array(r["depth_counts"]) for r in members])
        x = np.arange(len(grid))
        axes[0].bar(x + i * width, 100 * grid, width, label=f"{source}, {variant}")
        axes[1].bar(np.arange(len(depth)) + i * width, 100 * depth, width, label=f"{source}, {variant}")
    axes[0].set(title=f"Final points over a {GRID_ROWS}x{GRID_COLS} image grid (thesis Fig. 16c-d)",
                xlabel="grid cell (top left first, row by row)", ylabel="share of final points (%)")
    bins = [f"{a:g}-{b:g}" for a, b in itertools.pairwise(DEPTH_EDGES_M)]
    axes[1].set(title="Depth of the final points, 1-45 m (thesis Fig. 16e-f)", xlabel="depth (m)",
                ylabel="share of final points (%)")
    axes[1].set_xticks(np.arange(len(bins)) + 0.4 - width / 2, bins, rotation=45)
    axes[0].legend(fontsize=7)
    _save(fig, figures / "features_distribution.png")
    sections.append("![Where the final points fall](figures/features_distribution.png)")
    metrics = [("near_share", "share < 3 m", 3), ("final_points", "final points", 0),
               ("mean_inliers", "inliers/frame", 1), ("drift_percent", "drift %", 2),
               ("bridged_frames", "bridged frames", 1)]
    sections.append(_table(cones, metrics))
    with_c = [r for r in cones if r["variant"] == "cones"]
    without = [r for r in cones if r["variant"] == "no cones"]
    if with_c and without:
        empty = sum(1 for r in without if _value(r, "final_points") == 0)
        near_without = estimate(100 * _value(r, "near_share") for r in without)
        if near_without.n:
            without_text = (f"without cones {near_without.text(1)} % of them do "
                            f"({estimate(_value(r, 'mean_inliers') for r in without).text(1)} per frame)")
        else:
            without_text = f"without cones no final point survives the filters in {empty} of {len(without)} runs"
        answers["RQ2"] = (
            f"With cones, {estimate(100 * _value(r, 'near_share') for r in with_c).text(1)} % of the final points "
            f"lie nearer than 3 m ({estimate(_value(r, 'mean_inliers') for r in with_c).text(1)} per frame) and "
            f"VO drifts {estimate(_value(r, 'drift_percent') for r in with_c).text(2)} %; {without_text}, and VO "
            f"drifts {estimate(_value(r, 'drift_percent') for r in without).text(1)} %. As in the thesis "
            "(Fig. 16), the near, distinctive cones are what the motion is measured from.")
    bands = [r for r in ok if r["part"] == "depth bands"]
    if bands:
        fig, axes = pyplot().subplots(1, 2, figsize=(10, 3.5))
        variants = list(dict.fromkeys(r["variant"] for r in bands))
        for ax, (metric, label) in zip(axes, (("rpe_translation_percent", "translation error over 1 m (%)"),
                                              ("rpe_rotation_deg_per_m", "rotation error (deg/m)")), strict=True):
            values = [estimate(_value(r, metric) for r in bands if r["variant"] == v) for v in variants]
            ax.barh(variants, [v.mean for v in values], xerr=[0 if math.isnan(v.half_width) else v.half_width
                                                             for v in values], color="tab:blue")
            ax.set(xlabel=label)
        axes[0].set_title("Removing a depth band (the thesis's near/far claim)")
        _save(fig, figures / "features_bands.png")
        sections.append("![Removing near or far points](figures/features_bands.png)")
        sections.append(_table(bands, [("rpe_translation_percent", "translation %/m", 2),
                                       ("rpe_rotation_deg_per_m", "rotation deg/m", 3),
                                       ("drift_percent", "drift %", 2), ("mean_inliers", "inliers/frame", 1)]))
        answers["bands"] = _bands_answer(bands, variants)
    return sections, answers


def _bands_answer(bands: list[Row], variants: list[str]) -> str:
    def of(variant: str, metric: str) -> Estimate:
        return estimate(_value(r, metric) for r in bands if r["variant"] == variant)

    base, near, far = variants[0], variants[1], variants[2]
    t = {v: of(v, "rpe_translation_percent") for v in (base, near, far)}
    r = {v: of(v, "rpe_rotation_deg_per_m") for v in (base, near, far)}
    near_translation = t[near].mean > t[base].mean
    far_rotation = r[far].mean > r[base].mean
    verdict = ("both halves of the claim hold" if near_translation and far_rotation else
               "only the near half holds" if near_translation else
               "only the far half holds" if far_rotation else "neither half shows here")
    if t[far].mean > t[near].mean:
        verdict += (", though the far points matter for the translation too: without them it is worse than "
                    "without the near ones")
    return (f"Without the near points the translation error is {t[near].text(2)} %/m against "
            f"{t[base].text(2)} with all points; without the far points the rotation error is "
            f"{r[far].text(3)} deg/m against {r[base].text(3)} (and the translation error {t[far].text(2)}): "
            f"{verdict}.")


# --- filters (RQ3) ------------------------------------------------------------------------------------------

def _ranked_effects(rows: list[Row], figures: Path, question: str, title: str, stem: str
                    ) -> tuple[list[str], dict[str, str]]:
    """Every variant against ``defaults`` on the same drives, ranked by the change of drift; closed-loop rows
    (``teach_repeat``) are counted as successes."""
    closed = [r for r in _ok(rows) if r.get("job") == "teach_repeat"]
    ok = [r for r in _ok(rows) if r.get("job") != "teach_repeat"]
    effects = paired_effects(ok, "drift_percent", "defaults")
    ate = paired_effects(ok, "ate_m", "defaults")
    ranked = sorted(effects.items(), key=lambda kv: -abs(kv[1].mean) if not math.isnan(kv[1].mean) else 0)
    fig, ax = pyplot().subplots(figsize=(8, 0.35 * len(ranked) + 1.2))
    names = [name for name, _ in ranked][::-1]
    values = [effects[n] for n in names]
    ax.barh(names, [v.mean for v in values], xerr=[0 if math.isnan(v.half_width) else v.half_width for v in values],
            color=["tab:red" if v.mean > 0 else "tab:green" for v in values])
    ax.axvline(0, color="k", lw=0.8)
    ax.set(xlabel="change of end drift against the defaults (percentage points, 95 % interval)", title=title)
    _save(fig, figures / f"{stem}.png")
    lines = ["Change against the defaults on the same source and seed, over every pair:", "",
             "| variant | group | pairs | drift change (points) | ATE change (m) |", "|---|---|---|---|---|"]
    group_of = {r["variant"]: r["group"] for r in ok}
    lines += [f"| {name} | {group_of.get(name, '')} | {e.n} | {e.text(2)} | "
              f"{ate.get(name, Estimate(math.nan, math.nan, 0)).text(3)} |" for name, e in ranked]
    sections = [f"![Ranked by the change of drift](figures/{stem}.png)", "\n".join(lines),
                _table(ok, [("drift_percent", "drift %", 2), ("ate_m", "ATE m", 3),
                            ("mean_epipolar_ok", "stereo matches kept/frame", 0),
                            ("mean_depth_ok", "3D points/frame", 0), ("mean_inliers", "inliers/frame", 1),
                            ("bridged_frames", "bridged", 1), ("ms_per_frame", "ms/frame", 1)])]
    answer = _ranking_answer(ranked, group_of, "drift")
    if closed:
        counts = {v: (sum(1 for r in closed if r["variant"] == v and r.get("success")),
                      sum(1 for r in closed if r["variant"] == v)) for v in dict.fromkeys(r["variant"] for r in closed)}
        sections.append(_table(closed, [("success", "success rate", 2), ("end_error_m", "end error m", 3),
                                        ("max_distance_from_taught_path_m", "max from taught path m", 3)]))
        answer += " Closed loop (teach and repeat): " + ", ".join(f"{v} {k} of {n}" for v, (k, n) in counts.items()) \
            + " runs succeed."
    return sections, {question: answer}


def _filters(rows: list[Row], figures: Path) -> tuple[list[str], dict[str, str]]:
    return _ranked_effects(rows, figures, "RQ3", "Each filter off or swept, same drives (thesis RQ3, Fig. 9)",
                           "filters_ranking")


def _robustness(rows: list[Row], figures: Path) -> tuple[list[str], dict[str, str]]:
    return _ranked_effects(rows, figures, "robustness", "Each disturbance on its own, same drives",
                           "robustness_ranking")


def _ranking_answer(ranked: list[tuple[str, Estimate]], group_of: dict[str, str], what: str) -> str:
    """Which settings change ``what`` beyond their 95 % interval, worse first, then better, then the rest."""
    worse = [(n, e) for n, e in ranked if e.n > 1 and e.mean - e.half_width > 0]
    better = [(n, e) for n, e in ranked if e.n > 1 and e.mean + e.half_width < 0]
    moved = {group_of.get(n, n) for n, _ in worse + better}
    neutral = [g for g in dict.fromkeys(group_of.get(n, n) for n, _ in ranked) if g not in moved]
    parts = []
    if worse:
        parts.append(f"{what} is worse, beyond the 95 % interval, with " +
                     "; ".join(f"{n} ({e.text(2)} points)" for n, e in sorted(worse, key=lambda kv: -kv[1].mean)))
    if better:
        parts.append(f"{what} is better with " +
                     "; ".join(f"{n} ({e.text(2)} points)" for n, e in sorted(better, key=lambda kv: kv[1].mean)))
    if neutral:
        parts.append("no setting of " + ", ".join(neutral) + f" moves the {what} beyond the seed-to-seed spread")
    if not parts:
        parts = [f"no setting changes the {what}"]
    return " ".join(p[0].upper() + p[1:] + "." for p in parts)


# --- detectors, lanes, controllers ---------------------------------------------------------------------------

def _means(rows: list[Row], metric: str) -> dict[str, Estimate]:
    variants = list(dict.fromkeys(r["variant"] for r in rows))
    return {v: estimate(_value(r, metric) for r in rows if r["variant"] == v) for v in variants}


def _detectors(rows: list[Row], figures: Path) -> tuple[list[str], dict[str, str]]:
    ok = _ok(rows)
    sources = list(dict.fromkeys(r["source"] for r in ok))
    fig, axes = pyplot().subplots(1, len(sources), figsize=(6.5 * len(sources), 5), squeeze=False)
    answer = []
    for ax, source in zip(axes[0], sources, strict=True):
        members = [r for r in ok if r["source"] == source]
        drift, ms = _means(members, "drift_percent"), _means(members, "ms_per_frame")
        for variant in drift:
            marker = "o" if variant.startswith("bf") else "s" if variant.startswith("flann") else "^"
            ax.scatter(ms[variant].mean, drift[variant].mean, marker=marker)
            ax.annotate(variant.replace("detector=", "").replace("ratio=", ""),
                        (ms[variant].mean, drift[variant].mean), fontsize=6)
        ax.set(xlabel="ms per frame pair", ylabel="end drift with true step lengths (%)", title=source,
               yscale="log")
        best = min(drift, key=lambda v: drift[v].mean if not math.isnan(drift[v].mean) else math.inf)
        good = [v for v in drift if drift[v].mean <= 1.5 * drift[best].mean]
        fastest = min(good, key=lambda v: ms[v].mean)
        thesis = next((v for v in drift if v == "bf, detector=orb, ratio=0.7"), None)
        answer.append(f"On {source} the lowest drift is {best}'s ({drift[best].text(2)} %, {ms[best].text(0)} ms "
                      f"per pair); the fastest within 1.5 times of it is {fastest} ({drift[fastest].text(2)} %, "
                      f"{ms[fastest].text(0)} ms)"
                      + (f"; the thesis's ORB with brute force at 0.7 gives {drift[thesis].text(2)} %" if thesis
                         else ""))
    fig.suptitle("Monocular front end: drift against time (circles brute force, squares FLANN, triangles KLT)")
    _save(fig, figures / "detectors.png")
    table = _table(ok, [("mean_matches", "matches", 0), ("mean_inliers", "inliers", 0),
                        ("rotation_error_deg", "rotation error deg", 3),
                        ("direction_error_deg", "direction error deg", 2), ("drift_percent", "drift %", 2),
                        ("ms_per_frame", "ms/pair", 1)])
    return ["![Drift against time](figures/detectors.png)", table], {"front-end": ". ".join(answer) + "."}


def _setting(row: Row) -> str:
    """The part of a variant's name its sweep added (``speed_mode_mps=4.17``), without its group's name."""
    group, variant = row["group"], row["variant"]
    return variant[len(group) + 2:] if group and variant.startswith(group + ", ") else ""


def _lanes(rows: list[Row], figures: Path) -> tuple[list[str], dict[str, str]]:
    ok = _ok(rows)
    sections = [_bar_figure(rows, figures, "mean_center_offset_m", "Centre offset"), _every_metric(rows)]
    answer = []
    for setting in dict.fromkeys(_setting(r) for r in ok):
        members = [r for r in ok if _setting(r) == setting]
        parts = []
        for group in dict.fromkeys(r["group"] for r in members):
            runs = [r for r in members if r["group"] == group]
            touched = sum(1 for r in runs if r.get("touched"))
            parts.append(f"{group} touched a line in {touched} of {len(runs)} runs, "
                         f"{estimate(_value(r, 'mean_center_offset_m') for r in runs).text(3)} m from the centre on "
                         f"average, steer rate RMS {estimate(_value(r, 'steer_rate_rms_radps') for r in runs).text(3)}"
                         " rad/s")
        answer.append((f"With {setting}: " if setting else "") + "; ".join(parts))
    return sections, {"lanes": ". ".join(answer) + "."}


def _controllers(rows: list[Row], figures: Path) -> tuple[list[str], dict[str, str]]:
    ok = _ok(rows)
    sections = [_bar_figure(rows, figures, "max_offset_m", "Largest offset"), _every_metric(rows)]
    variants = list(dict.fromkeys(r["variant"] for r in ok))
    safe = [v for v in variants if all(r.get("success") for r in ok if r["variant"] == v)]
    offset = _means(ok, "max_offset_m")
    rate = _means(ok, "steer_rate_rms_radps")
    answer = f"{len(safe)} of {len(variants)} settings finish every run. "
    if safe:
        best = min(safe, key=lambda v: offset[v].mean)
        smooth = min(safe, key=lambda v: rate[v].mean)
        answer += (f"Nearest the path: {best} (largest offset {offset[best].text(3)} m, steer rate RMS "
                   f"{rate[best].text(3)} rad/s); smoothest: {smooth} ({offset[smooth].text(3)} m, "
                   f"{rate[smooth].text(3)} rad/s)")
        thesis = next((v for v in variants if "k_heading=0.5" in v and "k_cross_track=1.2" in v), None)
        if thesis:
            answer += f"; the thesis's gains: {offset[thesis].text(3)} m, {rate[thesis].text(3)} rad/s"
    return sections, {"controllers": answer + "."}


# --- any study ----------------------------------------------------------------------------------------------

_SKIP = {"seed", "cell_seconds", "grid_counts", "depth_counts", "config_hash"}


def _numeric(rows: list[Row]) -> list[str]:
    return [k for k in dict.fromkeys(k for r in rows for k in r)
            if k not in _SKIP and all(isinstance(r.get(k), (int, float)) for r in rows if k in r)]


def _every_metric(rows: list[Row]) -> str:
    ok = _ok(rows)
    return _table(ok, [(k, k.replace("_", " "), 3) for k in _numeric(ok)])


def _bar_figure(rows: list[Row], figures: Path, metric: str, label: str = "") -> str:
    """A bar chart of ``metric`` per variant (means and intervals over every run); its Markdown line."""
    ok = _ok(rows)
    values = _means(ok, metric)
    variants = list(values)[::-1]
    fig, ax = pyplot().subplots(figsize=(8, 0.35 * len(variants) + 1.2))
    ax.barh(variants, [values[v].mean for v in variants],
            xerr=[0 if math.isnan(values[v].half_width) else values[v].half_width for v in variants])
    ax.set(xlabel=metric.replace("_", " "))
    _save(fig, figures / f"{metric}.png")
    return f"![{label or metric}](figures/{metric}.png)"


def _generic(rows: list[Row], figures: Path) -> tuple[list[str], dict[str, str]]:
    """A table of every metric, and a bar chart of the first numeric one."""
    numeric = _numeric(_ok(rows))
    return ([_bar_figure(rows, figures, numeric[0])] if numeric else []) + [_every_metric(rows)], {}


REPORTS: dict[str, Callable[[list[Row], Path], tuple[list[str], dict[str, str]]]] = {
    "features": _features, "filters": _filters, "robustness": _robustness, "detectors": _detectors,
    "lanes": _lanes, "controllers": _controllers, "table": _generic,
}


def _csv_value(value: Any) -> Any:
    return json.dumps(value) if isinstance(value, (list, dict)) else value


def write_report(folder: str | Path) -> list[Path]:
    """Write ``report.md``, ``rows.csv`` and ``figures/`` into the study folder; returns the files."""
    folder = Path(folder)
    meta, rows = load_rows(folder)
    columns = list(dict.fromkeys(k for r in rows for k in r))
    csv = write_csv_atomic(folder / "rows.csv", columns, ([_csv_value(r.get(c, "")) for c in columns] for r in rows))
    make = REPORTS.get(meta.get("report", "table"), _generic)
    sections, answers = make(rows, folder / "figures")
    if make is not _generic:
        sections += ["## Every metric", _every_metric(rows)]
    lines = [f"# {meta.get('title', meta.get('name', 'study'))}", "",
             f"{len(rows)} cells ({'quick size' if meta.get('quick') else 'full size'}), kartpilot "
             f"{meta.get('code_version', '?')}. Means over seeds with 95 % intervals.", "", "## Answers", ""]
    for key, question in meta.get("questions", {}).items():
        lines += [f"**{key}: {question}**", "", answers.get(key, "No answer: the cells it needs are missing."), ""]
    lines += ["## Results", ""] + [s + "\n" for s in sections]
    failed = [r for r in rows if r.get("status") != "ok"]
    if failed:
        lines += ["## Failed cells", "", "| variant | source | seed | error |", "|---|---|---|---|"]
        lines += [f"| {r['variant']} | {r['source']} | {r['seed']} | {r.get('error', '')} |" for r in failed]
    report = write_text_atomic(folder / "report.md", "\n".join(lines) + "\n")
    pictures = sorted((folder / "figures").glob("*.png")) if (folder / "figures").is_dir() else []
    return [report, csv, *pictures]
