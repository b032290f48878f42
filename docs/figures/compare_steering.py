"""Steering of two `kartpilot experiment teach-repeat` runs, one over the other (the README's figure).

    kartpilot experiment teach-repeat --track straight20 --controller plain_stanley --out exp-thesis
    kartpilot experiment teach-repeat --track straight20 --out exp-kartpilot
    python docs/figures/compare_steering.py exp-thesis exp-kartpilot docs/figures/straight20-steering.png
"""

import csv
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np


def load(folder: str) -> dict[str, np.ndarray]:
    with open(f"{folder}/drive_log.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    return {k: np.array([float(r[k]) for r in rows]) for k in ("stamp_ns", "steer_rad", "cross_track_m")}


def main() -> None:
    thesis, ours, target = load(sys.argv[1]), load(sys.argv[2]), sys.argv[3]
    figure, axes = plt.subplots(2, 1, figsize=(10, 5), sharex=True)
    for run, label, colour in ((thesis, "the thesis's pipeline", "tab:red"), (ours, "kartpilot", "tab:blue")):
        t = (run["stamp_ns"] - run["stamp_ns"][0]) * 1e-9
        rate = np.sqrt(np.mean((np.diff(run["steer_rad"]) / np.diff(t)) ** 2))
        axes[0].plot(t, np.degrees(run["steer_rad"]), color=colour, lw=1, label=f"{label} (steer-rate RMS {rate:.3f} rad/s)")
        axes[1].plot(t, run["cross_track_m"], color=colour, lw=1, label=label)
    axes[0].set_ylabel("steer (deg, + left)")
    axes[1].set_ylabel("cross-track error (m)")
    axes[1].set_xlabel("time (s)")
    axes[0].set_title("straight20 at 0.62 m/s, the kart pulling 0.03 rad left, on the track's cross-slope")
    for ax in axes:
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
    figure.tight_layout()
    figure.savefig(target, dpi=110)


if __name__ == "__main__":
    main()
