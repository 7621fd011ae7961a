"""The power curves of `calbench discover` as a PNG, from benchmarks/discover_bench.py's JSON.

For every hidden effect, the share of campaigns in which discovery names the right effect (and
option) first, against the effect's magnitude as a fraction of its tested size, with the
binomial standard error sqrt(p (1 - p) / n) of each point; a band marks the false-alarm rate
(anything named with nothing hidden) with its 95 % upper bound. Written for docs/.

    python benchmarks/discover_bench.py --seeds 20 > power.json
    python benchmarks/discover_power_plot.py power.json --out docs/discover_power.png [--null null.json]

``--null`` takes benchmarks/discover_null_bench.py's JSON for the false-alarm band (400 seeds)
instead of discover_bench's own no-effect seeds.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from scipy import stats

UNITS = {
    "link_compliance": "rad/(N·m)",
    "base_compliance": "rad/(N·m)",
    "joint_nonlinearity": "N·m/rad³",
    "compensator": "N/m",
    "tracker_drift": "m",
    "unexplained": "rad/(N·m)",
}


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("results", type=Path, help="benchmarks/discover_bench.py's JSON")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--null", type=Path, default=None, help="benchmarks/discover_null_bench.py's JSON")
    args = ap.parse_args()
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    res = json.loads(args.results.read_text())
    seeds = res["seeds"]
    if args.null:
        null = json.loads(args.null.read_text())["all"]
        n0, k0 = null["seeds"], null["false_alarms"]
    else:
        n0 = seeds
        k0 = round(res["no_effect"]["false_alarm_rate"] * seeds)
    upper = 1.0 if k0 >= n0 else float(stats.beta.ppf(0.95, k0 + 1, n0 - k0))
    fig, ax = plt.subplots(figsize=(8.5, 5.0), dpi=120)
    ax.axhspan(
        0.0,
        upper,
        color="0.85",
        label=f"false alarms: {k0}/{n0} campaigns with nothing hidden (95 % bound {100 * upper:.2g} %)",
    )
    for name, e in res["effects"].items():
        rows = sorted(e["rows"], key=lambda r: r["magnitude"])
        x = np.array([r["magnitude"] for r in rows]) / e["tested_magnitude"]
        p = np.array([r["right"] for r in rows])
        se = np.sqrt(p * (1 - p) / seeds)
        unit = UNITS.get(e["expected"].split("[")[0], "")
        flange = e.get("flange_extra_mm_median")
        extra = f", {flange * 1e3:.0f} µm at the flange" if flange and flange > 1e-3 else ""
        ax.errorbar(
            x,
            p,
            yerr=se,
            marker="o",
            ms=4,
            capsize=2,
            label=f"{name}: 1 = {e['tested_magnitude']:.3g} {unit}{extra}",
        )
    ax.set_xscale("log")
    ticks = sorted(
        {round(r["magnitude"] / e["tested_magnitude"], 2) for e in res["effects"].values() for r in e["rows"]}
    )
    ax.set_xticks(ticks, [f"{t:g}" for t in ticks])
    ax.minorticks_off()
    ax.set_xlabel("magnitude of the hidden effect / its tested size")
    ax.set_ylabel("share of campaigns naming the right effect first")
    ax.set_ylim(-0.03, 1.03)
    ax.set_title(
        f"calbench discover: detection power on the paper plan (20 µm tracker, {seeds} seeds per point)"
    )
    ax.legend(fontsize=7, loc="lower right")
    ax.grid(alpha=0.3, which="both")
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out)
    plt.close(fig)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
