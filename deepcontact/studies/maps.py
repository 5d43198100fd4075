"""One map or two? Train the same network on both impulse maps at once, and as two separate
models (normal only, tangent only; the thesis's goals 7-9), and compare them on the validation
simulations at the contact points.

    dc study maps DATASET -o OUTDIR [--epochs N] [--model fcn] [--width W]
"""
import json
import time
from pathlib import Path

from .. import atomic
from ..protocol import protocol, protocol_line
from ..model.train import TrainConfig, train

ARMS = {"joint": ["normal_impulse", "tangent_impulse"], "normal only": ["normal_impulse"],
        "tangent only": ["tangent_impulse"]}


def compare(dataset, out, plots=True, **config):
    """Trains the three arms into `out` (each with its loss plot unless `plots` is false) and
    returns their rows: epochs, seconds, best epoch and its RMSEs at the contact points."""
    out = Path(out)
    rows = {}
    for name, targets in ARMS.items():
        t = time.perf_counter()
        history = train(dataset, out / name.replace(" ", "-"), TrainConfig(targets=targets, **config), plots=plots)
        best = min(history, key=lambda r: r.get("val_loss", r["train_loss"]))
        rows[name] = {"epochs": len(history), "seconds": time.perf_counter() - t, "best_epoch": best["epoch"],
                      **{k: v for k, v in best.items() if k.startswith(("val_contact_rmse", "val_zero_rmse",
                                                                        "val_floor_rmse"))}}
    return rows


def table(rows):
    """The comparison: each arm's RMSE at the contact points beside what predicting 0 scores and
    the grid's floor (the label image read back: the best any grid-predicting network can do)."""
    lines = ["| models | epochs | best epoch | normal RMSE at contacts | predicting 0 | grid's floor | "
             "tangent RMSE at contacts | predicting 0 | grid's floor | training time (s) |",
             "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]

    def cell(value):
        return "" if value is None else f"{value:.4g}"

    for name, r in rows.items():
        cells = [cell(r.get(f"val_{kind}_rmse_{target}")) for target in ("normal", "tangent")
                 for kind in ("contact", "zero", "floor")]
        lines.append(f"| {name} | {r['epochs']} | {r['best_epoch']} | {' | '.join(cells)} | {r['seconds']:.0f} |")
    return "\n".join(lines)


# Everything a maps folder holds: what --overwrite may replace (a training run per arm).
MAP_FILES = atomic.Owned("maps comparison", [r"compare\.(md|json)", r"(joint|normal-only|tangent-only)/",
                                              r"(joint|normal-only|tangent-only)/((last|best)\.pt|metrics\.(csv|json)|"
                                              r"loss\.(png|svg))"])


def write_comparison(out, rows, measured=None):
    """compare.md and compare.json into the folder out; returns the table."""
    text = table(rows)
    atomic.write_text(Path(out) / "compare.md", text + "\n\n" + protocol_line(measured or protocol()) + "\n")
    atomic.write_text(Path(out) / "compare.json", json.dumps(rows, indent=2) + "\n")
    return text
