"""What every benchmark script starts with: its options, and a line saying how its times are taken."""
import argparse

from deepcontact.protocol import current, protocol_line


def arguments(doc, **defaults):
    """The script's options (--name for each keyword, typed by its default), parsed, after the
    protocol line (threads, -j, versions, CPU, load, command) is printed."""
    ap = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    for name, default in defaults.items():
        ap.add_argument("--" + name.replace("_", "-"), type=type(default), default=default)
    args = ap.parse_args()
    print(protocol_line(current()) + "\n")   # how these times were taken
    return args
