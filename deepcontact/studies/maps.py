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


def compare(dataset, out, **config):
    out = Path(out)
    rows = {}
    for name, targets in ARMS.items():
        t = time.perf_counter()
        history = train(dataset, out / name.replace(" ", "-"), TrainConfig(targets=targets, **config))
        best = min(history, key=lambda r: r.get("val_loss", r["train_loss"]))
        rows[name] = {"epochs": len(history), "seconds": time.perf_counter() - t, "best_epoch": best["epoch"],
                      **{k: v for k, v in best.items() if k.startswith("val_contact_rmse")}}
    return rows


def table(rows):
    lines = ["| models | epochs | best epoch | normal RMSE at contacts | tangent RMSE at contacts | training time (s) |",
             "| --- | ---: | ---: | ---: | ---: | ---: |"]
    for name, r in rows.items():
        n = r.get("val_contact_rmse_normal")
        t = r.get("val_contact_rmse_tangent")
        lines.append(f"| {name} | {r['epochs']} | {r['best_epoch']} | {'' if n is None else f'{n:.4g}'} | "
                     f"{'' if t is None else f'{t:.4g}'} | {r['seconds']:.0f} |")
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
