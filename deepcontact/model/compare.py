"""One map or two? Train the same network on both impulse maps at once, and as two separate
models (normal only, tangent only; the thesis's goals 7-9), and compare them on the validation
simulations at the contact points.

    python -m deepcontact.model.compare DATASET -o OUTDIR [--epochs N] [--model fcn] [--width W]
"""
import argparse
import json
import sys
import time
from pathlib import Path

from .. import atomic
from .train import TrainConfig, train

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


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("dataset")
    ap.add_argument("-o", "--output", required=True)
    ap.add_argument("--epochs", type=int, default=10)
    ap.add_argument("--model", default="fcn")
    ap.add_argument("--width", type=int, default=16)
    ap.add_argument("--loss", default="masked")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    rows = compare(args.dataset, args.output, model=args.model, fcn_width=args.width, epochs=args.epochs,
                   loss=args.loss, optimizer="adam", lr=1e-3, batch_size=64, seed=args.seed)
    text = table(rows)
    atomic.write_text(Path(args.output) / "compare.md", text + "\n")
    atomic.write_text(Path(args.output) / "compare.json", json.dumps(rows, indent=2) + "\n")
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
