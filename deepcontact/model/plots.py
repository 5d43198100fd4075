"""What a training run writes beside its checkpoints: metrics.csv/json and the loss plot."""
import io
import json

from .. import output
from ..escape import CsvWriter
from ..plotstyle import readable_log_ticks


def write_metrics(out_dir, history):
    """metrics.csv and metrics.json: one row per epoch."""
    keys = sorted({k for row in history for k in row}, key=lambda k: (k != "epoch", k))
    buf = io.StringIO()
    w = CsvWriter(buf)
    w.writerow(keys)
    w.writerows([row.get(k, "") for k in keys] for row in history)
    output.write_text(out_dir / "metrics.csv", buf.getvalue())
    output.write_text(out_dir / "metrics.json", json.dumps(history, indent=1) + "\n")


def plot_losses(history, stem):
    """loss.png: the training and validation loss per epoch; beside it, where validation ran, the
    RMSE at the contact points per target against predicting 0 and the grid's floor."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator
    rmse = [k[len("val_contact_rmse_"):] for k in history[0] if k.startswith("val_contact_rmse_")]
    fig, axes = plt.subplots(1, 2 if rmse else 1, figsize=(11 if rmse else 6, 4), squeeze=False)
    ax = axes[0][0]
    epochs = [r["epoch"] for r in history]
    ax.plot(epochs, [r["train_loss"] for r in history], label="training", marker="o", ms=3)
    if "val_loss" in history[0]:
        ax.plot(epochs, [r["val_loss"] for r in history], label="validation", marker="s", ms=3, ls="--")
    if any(r["train_loss"] > 0 for r in history):   # (a log axis needs a positive value)
        ax.set_yscale("log")
        readable_log_ticks(ax.yaxis)
    ax.set_ylabel("loss")
    ax.set_title("Loss")
    if rmse:
        ax = axes[0][1]
        for i, target in enumerate(rmse):
            colour = f"C{i + 2}"
            ax.plot(epochs, [r[f"val_contact_rmse_{target}"] for r in history], color=colour, marker="o", ms=3,
                    label=f"{target}: the network")
            for key, ls, what in (("zero", "--", "predicting 0"), ("floor", ":", "the grid's floor")):
                value = history[-1].get(f"val_{key}_rmse_{target}")
                if value is not None:
                    ax.axhline(value, color=colour, ls=ls, lw=1, label=f"{target}: {what}")
        ax.set_ylabel("validation RMSE at the contacts (N·s)")
        ax.set_title("Against predicting 0")
    for ax in axes[0]:
        ax.set_xlabel("epoch")
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))   # (epochs are whole)
        ax.legend(fontsize=8)
        ax.grid(alpha=0.3)
    fig.tight_layout()
    # through bytes and an atomic write: training writes in place, and an interrupted run must
    # not leave half a picture
    output.write_bytes(f"{stem}.png", output.figure_bytes(fig, "png", dpi=110))
    output.write_bytes(f"{stem}.svg", output.figure_bytes(fig, "svg"))
    plt.close(fig)
