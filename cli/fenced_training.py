"""dc train with a plug-in network (--arch pkg.mod:Net, or an installed one): the network's code
runs in every batch, so the whole training runs fenced (deepcontact/contest/job.py), as a study
does. This process keeps the output: it checks and locks it as every training run does, gives the
training a copy of what it resumes from in a folder of its own, and writes back what it wrote
(checkpoints, metrics, the loss plot: nothing else, no link), in place or swapped in, by the
rules of an unfenced run; the user's stop ends the training at once and keeps its last whole
epoch, as an unfenced run does."""
import glob
import os
import re
import shutil
import stat
from contextlib import ExitStack
from pathlib import Path

import click

INSIDE = "DC_TRAIN_FENCED"   # set for the fenced training's own process (to the user's output): it trains in place


class RawArgsCommand(click.Command):
    """A click command that keeps the arguments it was given (ctx.meta["raw_args"]), to hand them on."""

    def parse_args(self, ctx, args):
        ctx.meta["raw_args"] = list(args)
        return super().parse_args(ctx, args)


def fenced(model):
    """Whether training with the network `model` runs fenced here."""
    from deepcontact.model.arch import BUILTIN
    return model not in BUILTIN and not os.environ.get(INSIDE)


def _written(folder):
    """{name: path} of the files the fenced training wrote that a training run owns (MODEL_FILES);
    InputError for anything else a run never writes there (a link, a device, another name)."""
    from deepcontact.errors import InputError
    from deepcontact.model.checkpoint_file import MODEL_FILES
    from deepcontact import output
    found = {}
    for entry in os.listdir(folder) if os.path.isdir(folder) else ():
        path = os.path.join(folder, entry)
        if entry == output.RECORD or output.temporary_name(entry):   # (its record, a file being written)
            continue
        mode = os.lstat(path).st_mode
        if not stat.S_ISREG(mode) or not any(re.fullmatch(p, entry) for p in MODEL_FILES.patterns):
            raise InputError(f"the training of a plug-in network wrote {entry!r}, which a training run never writes: "
                             f"nothing of it was kept", folder)
        found[entry] = path
    return found


class _Sync:
    """Writes what the fenced training wrote and changed since the last call into the output, and
    removes there what it wrote and removed since (a mid-epoch checkpoint once its epoch is whole)."""

    def __init__(self, staged, work):
        self.staged, self.work, self.seen = staged, work, {}

    def __call__(self):
        from deepcontact import output
        written = _written(self.staged)
        for name in [n for n in self.seen if n not in written]:
            (self.work / name).unlink(missing_ok=True)
            del self.seen[name]
        for name, path in written.items():
            try:
                st = os.stat(path)
                key = (st.st_ino, st.st_mtime_ns, st.st_size)
                if self.seen.get(name) != key:
                    with open(path, "rb") as f:   # (a file replaced meanwhile is read whole, old or new)
                        data = f.read()
                    output.write_bytes(self.work / name, data)
                    self.seen[name] = key
            except FileNotFoundError:
                continue


def run(ctx, model, out, overwrite, resume, device):
    """Runs the training fenced; returns its exit status."""
    from deepcontact import output, protocol
    from deepcontact.contest import job, result
    from deepcontact.errors import InputError
    from deepcontact.model.checkpoint_file import MODEL_FILES
    if os.environ.get("WORLD_SIZE") or os.environ.get("RANK"):
        raise InputError("a plug-in network trains in a sandbox of its own, where torchrun's processes cannot reach "
                         "one another: train it in one process (without torchrun)")
    out = Path(out)
    replace = overwrite and out.is_dir() and any(out.iterdir())
    with ExitStack() as stack:
        private = Path(stack.enter_context(output.private_folder("train")))
        work = Path(stack.enter_context(output.output_folder(
            out, MODEL_FILES, overwrite, command="train", in_place=not replace, existing_ok=resume,
            hint="use --resume to continue a run there or --overwrite to replace it")))
        staged = private / "run"
        if resume and out.is_dir():   # (a copy: the user's files are not the training's to change)
            staged.mkdir()
            for entry in os.listdir(out):
                if os.path.isfile(out / entry) and not os.path.islink(out / entry):
                    shutil.copyfile(out / entry, staged / entry)
        args = list(ctx.meta["raw_args"])
        where, prefix, _, _ = job.output_argument(args)   # (-o is required: it is there)
        args[where] = prefix + str(staged)
        devices = [] if device == "cpu" else sorted(glob.glob("/dev/nvidia*") + glob.glob("/dev/dri/*"))
        # kept in place as it is written (an unfenced run keeps each whole epoch as it ends: a stop
        # or a failure leaves the last one), or swapped in once it has finished (replacing a run)
        sync = _Sync(staged, work)
        code = job.run(["train", *args], [private], private, {INSIDE: str(out)}, protocol.command_line, devices,
                       poll=None if replace else sync, who=f"the training of the network {model!r}")
        record = job.ended(private)
        if not replace or result.ended_in_order(record, code) and code == 0:
            sync()
        job.refuse_unordered(code, record, f"the training of the network {model!r}")
        if code != 0:
            raise click.exceptions.Exit(code)   # (its own line said why; an earlier run replaced is as it was)
    return 0
