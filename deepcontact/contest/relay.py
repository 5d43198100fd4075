"""A sandbox's standard output and error: pipes dc owns, relayed to dc's own streams by a thread,
bounded. No descriptor of dc's stream is ever a sandbox's: reopening its own through /proc gives a
contestant its own pipe, never dc's log nor a channel shared with a rival."""
import os
import sys
import threading

CHUNK = 65536


def start(fd, to, prefix, cap):
    """A thread relaying what the pipe's read end `fd` carries to dc's stream `to` ("stdout" or
    "stderr", looked up as each piece is written: a caller's buffer too), at most `cap` bytes;
    with a prefix (a name), line by line, each line after it and escaped (_printable). What is
    over the cap is read, counted and said once, at the end, as "N bytes more not shown"."""
    t = threading.Thread(target=_relay, args=(fd, to, prefix, cap), name="dc-relay", daemon=True)
    t.start()
    return t


def _relay(fd, to, prefix, cap):
    shown, over, pending = 0, 0, b""
    try:
        while True:
            chunk = os.read(fd, CHUNK)
            if not chunk:
                break
            room = max(0, cap - shown)
            kept, over = chunk[:room], over + max(0, len(chunk) - room)
            shown += len(kept)
            if not prefix:
                _write(to, kept)
                continue
            lines = (pending + kept).split(b"\n")
            pending = lines.pop()
            _write(to, b"".join(prefix.encode() + _printable(line) + b"\n" for line in lines))
    except OSError:
        pass
    finally:
        os.close(fd)
    _write(to, (prefix.encode() + _printable(pending) + b"\n") if prefix and pending else b"")
    if over:
        _write(to, f"{prefix}{over} bytes more not shown\n".encode())


def _printable(line):
    """A named line as dc shows it: what a terminal would act on (a carriage return, an escape
    sequence, a byte no text holds) escaped, so that nothing a contestant says can rub out the
    name before it or pass for one of dc's own lines."""
    text = line.decode("utf-8", errors="backslashreplace")
    return "".join(c if c.isprintable() or c == "\t" else c.encode("unicode_escape").decode()
                   for c in text).encode()


def _write(to, data):
    """data written to dc's stream `to` (its bytes where it has them, else its text)."""
    if not data:
        return
    stream = getattr(sys, to)
    if stream is None or type(stream).__name__ == "ClosedStdout":   # (the shell closed it)
        return
    try:
        buffer = getattr(stream, "buffer", None)
        if buffer is not None:
            stream.flush()
            buffer.write(data)
            buffer.flush()
        else:
            stream.write(data.decode(errors="replace"))
            stream.flush()
    except (OSError, ValueError):
        pass
