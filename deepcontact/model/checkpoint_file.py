"""What a training folder holds and what a checkpoint file must be before torch reads it, checked
without importing torch: a command refuses a wrong path in a fraction of a second instead of after
torch's import."""
from pathlib import Path

from .. import output
from ..errors import InputError

# Everything a training folder holds: what --overwrite may replace.
MODEL_FILES = output.Owned("training run", [r"(last|best|mid-epoch)\.pt", r"metrics\.(csv|json)", r"loss\.(png|svg)"])


def checkpoint_file(path) -> Path:
    """path as a Path, or InputError for what cannot be a checkpoint: nothing there, a folder, not
    a regular file (a FIFO would block torch.load forever), or a file whose first bytes are not
    torch.save's (its zip format or a legacy pickle)."""
    path = Path(path)
    if not path.exists():
        raise InputError("no such checkpoint", path)
    if path.is_dir():
        raise InputError("a folder, not a checkpoint file", path)
    if not path.is_file():
        raise InputError("not a regular file", path)
    with open(path, "rb") as f:
        magic = f.read(4)
    if not torch_file(magic):
        raise InputError(NOT_TORCH, path)
    return path


NOT_TORCH = "not a checkpoint: not a file torch.save writes (a picture? another file?)"


def torch_file(first: bytes) -> bool:
    """Whether a file's first bytes are torch.save's: its zip format, or a legacy pickle."""
    return first[:2] == b"PK" or first[:1] == b"\x80"
