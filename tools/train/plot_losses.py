"""plot_losses.py - loss curves of the training stages (checkpoints/stage{N}_log.csv, N = 1..4) and
the stage-1 validation figures (stored in checkpoints/stage1.pt) into one PNG.

    /usr/bin/python3 tools/train/plot_losses.py [--ckpt-dir tools/train/checkpoints] -o OUT.png
Needs python3-matplotlib (Debian)."""
import argparse
import csv
import json
import os

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import torch  # noqa: E402


def read_log(path):
    rows = []
    with open(path) as f:
        for r in csv.reader(f):
            rows.append((int(r[0]), float(r[1]), float(r[2]), json.loads(r[3])))
    return rows


def smooth(y, k=15):
    out, acc = [], []
    for v in y:
        acc.append(v)
        acc = acc[-k:]
        out.append(sum(acc) / len(acc))
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--ckpt-dir", default=os.path.join(os.path.dirname(os.path.abspath(__file__)), "checkpoints"))
    ap.add_argument("-o", "--out", required=True)
    a = ap.parse_args()
    stages = [s for s in (1, 2, 3, 4) if os.path.exists(os.path.join(a.ckpt_dir, f"stage{s}_log.csv"))]
    fig, axes = plt.subplots(1, len(stages) + 1, figsize=(5 * (len(stages) + 1), 4))
    for ax, s in zip(axes, stages):
        rows = read_log(os.path.join(a.ckpt_dir, f"stage{s}_log.csv"))
        steps = [r[0] for r in rows]
        keys = sorted({k for r in rows for k in r[3]})
        for k in keys:
            pts = [(r[0], r[3][k]) for r in rows if k in r[3]]
            ax.plot([p[0] for p in pts], smooth([p[1] for p in pts]), label=k)
        ax.plot(steps, smooth([r[2] for r in rows]), "k", lw=2, label="total")
        ax.set_yscale("log")
        ax.set_xlabel("step")
        ax.set_title(f"stage {s} (smoothed, {rows[-1][1] / 60:.0f} min)")
        ax.legend(fontsize=7)
    ax = axes[-1]
    ck = os.path.join(a.ckpt_dir, "stage1.pt")
    if os.path.exists(ck):
        val = torch.load(ck)["state"].get("val", [])
        if val:
            st = [v["step"] for v in val]
            ax.plot(st, [v["psnr"] for v in val], "o-", label="novel-view PSNR (dB)")
            ax2 = ax.twinx()
            ax2.plot(st, [100 * v["point_dist_m"] for v in val], "s-r", label="point distance (cm)")
            ax2.set_ylabel("cm")
            ax2.legend(loc="lower right", fontsize=7)
    ax.set_title("stage 1 validation (val split)")
    ax.set_xlabel("step")
    ax.legend(loc="upper left", fontsize=7)
    fig.tight_layout()
    fig.savefig(a.out, dpi=80)


if __name__ == "__main__":
    main()
