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
    with a prefix (a name), line by line, each line after it and escaped (_printable), the names
    counted in the cap (_Named). What is over the cap is read, counted and said once, at the end,
    as "N bytes more not shown"."""
    t = threading.Thread(target=_relay, args=(fd, to, prefix, cap), name="dc-relay", daemon=True)
    t.start()
    return t


def _relay(fd, to, prefix, cap):
    stream = _Named(prefix.encode(), cap) if prefix else _Raw(cap)
    try:
        while True:
            chunk = os.read(fd, CHUNK)
            if not chunk:
                break
            _write(to, stream.feed(chunk))
    except OSError:
        pass
    finally:
        os.close(fd)
    _write(to, stream.end())


class _Raw:
    """A stream relayed as it is (a job's, the command's own output): its first `cap` bytes."""

    def __init__(self, cap):
        self.room, self.over = cap, 0

    def feed(self, chunk):
        kept = chunk[:max(0, self.room)]
        self.room -= len(kept)
        self.over += len(chunk) - len(kept)
        return kept

    def end(self):
        return f"{self.over} bytes more not shown\n".encode() if self.over else b""


class _Named:
    """A contestant's stream as dc shows it: whole lines, each after its name, at most `cap` bytes
    written, names and newlines counted (64 KiB of empty lines made 64 Ki lines of names: 1.3 MB);
    a line longer than what is left, cut."""

    def __init__(self, prefix, cap):
        self.prefix, self.room, self.over, self.pending = prefix, cap, 0, b""

    def feed(self, chunk):
        if self.room <= 0:
            self.over += len(chunk)
            return b""
        lines = (self.pending + chunk).split(b"\n")
        self.pending = lines.pop()
        out = [self._line(line, 1) for line in lines]
        if len(self.prefix) + len(self.pending) + 1 > self.room:   # (a line longer than what is left)
            out.append(self._line(self.pending, 0))
            self.pending = b""
        return b"".join(out)

    def _line(self, line, ended):
        """One line, after the name, as much of it as is left room for (`ended`: its newline read)."""
        keep = self.room - len(self.prefix) - 1
        if keep < min(len(line), 1):   # (no room for its name and one byte of it)
            self.over += len(line) + ended
            return b""
        self.room -= len(self.prefix) + min(len(line), keep) + 1
        self.over += max(0, len(line) - keep)
        return self.prefix + _printable(line[:keep]) + b"\n"

    def end(self):
        out = self._line(self.pending, 0) if self.pending else b""
        return out + (self.prefix + f"{self.over} bytes more not shown\n".encode() if self.over else b"")


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
