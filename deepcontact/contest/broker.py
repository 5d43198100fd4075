"""Contestants of a fenced job, started by the judge's process on the job's behalf.

A job (a study) runs in a sandbox of its own (sandbox.JobSandbox: fence.JOB), which cannot build the
namespaces of a contestant's sandbox: bubblewrap inside bubblewrap cannot mount the contestant's
own /proc. So, as flatpak's portal spawns a sandboxed process for an application already inside
one, the job asks the process that started it, over a socket it inherits: that process starts
the contestant's sandbox (with its control group, its limits, its seccomp), passes it the job's
end of the contestant's socket, and answers the job's questions about it (its CPU, its
processes, how it ended); the job never holds the contestant's process. Every sandbox a job
asked for ends with the job.

The job's side is RemoteSandbox, the same members as sandbox.Sandbox; the judge's side is Broker.
"""
import json
import os
import socket
import threading
import time

from dataclasses import replace

from . import grants, machine, sandbox, shape, zygote
from .fence import PROFILES

ENV = "DC_SANDBOX_BROKER"   # the job's end of the broker's socket (a descriptor number)
LIVE_LIMIT = 64             # sandboxes a job may hold at once
MESSAGE_MAX = 1 << 20


class BrokerError(RuntimeError):
    """The broker refused a request (said in one line) or is gone."""


# --- The job's side --------------------------------------------------------------------------------

_lock = threading.Lock()
_conn = None   # (this process's own line to the broker: a forked worker makes its own)


def _after_fork():
    global _lock, _conn
    _lock, _conn = threading.Lock(), None


os.register_at_fork(after_in_child=_after_fork)


def inside():
    """Whether this process is a fenced job whose contestants the judge's process starts."""
    return os.environ.get(ENV, "").isdigit()


def remote(op, fds=(), **fields):
    """One request to the broker and its answer (a dict); BrokerError if it refused or is gone."""
    with _lock:   # (one request at a time: an answer belongs to the request before it)
        try:
            sock = _connection()
            socket.send_fds(sock, [json.dumps({"op": op, **fields}).encode()], list(fds))
            answer = sock.recv(MESSAGE_MAX)
        except OSError as e:
            raise BrokerError(f"the judge's process that starts contestants is gone ({e.strerror or e})") from None
    if not answer:
        raise BrokerError("the judge's process that starts contestants is gone")
    answer = json.loads(answer)
    if "error" in answer:
        raise BrokerError(answer["error"])
    return answer


def _connection():
    """This process's own line to the broker. The inherited socket carries only requests for a
    line (each with its end, one message each, never answered there): a job's processes (a
    forked worker, say) share it, and answers on it could reach the wrong one."""
    global _conn
    if _conn is None:
        shared = socket.socket(fileno=os.dup(int(os.environ[ENV])))
        try:
            ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
            try:
                socket.send_fds(shared, [b'{"op": "connect"}'], [theirs.fileno()])
            finally:
                theirs.close()
        finally:
            shared.close()
        _conn = ours
    return _conn


def new(grant, threads=1, name=None, profile="contestant"):
    """A contestant's sandbox for what it runs (a grants.Grant): this process's own, or, in a
    fenced job, one the judge's process starts and owns on the job's behalf (RemoteSandbox). Its
    start_guest(channel, torch) starts the guest with its line to the judge; name: how its
    relayed output is named; profile: its fence's (fence.PROFILES: "contestant", "engine")."""
    return RemoteSandbox(grant, threads) if inside() else guest_sandbox(grant, threads, name, profile)


def guest_sandbox(grant, threads=1, name=None, profile="contestant"):
    """A contestant's sandbox (fence.PROFILES[profile]) in this process, granted what it runs."""
    fence = replace(PROFILES[profile].with_paths(readable=grant.readable()), threads=threads)
    return GuestSandbox(fence, name)


class GuestSandbox(sandbox.Sandbox):
    """A contestant's sandbox in this process, running the guest and nothing else (the same
    fence as any: only its command is the guest's)."""

    def start_guest(self, channel, torch=False):
        """The guest on `channel`: a fork of the zygote where this machine lends one (zygote.py),
        else a fresh interpreter; the same fence either way."""
        if zygote.usable(self.fence, torch) and zygote.forked_start(
                self, lambda: zygote.live(torch), lambda used: self.start_forked(used, channel),
                lambda e: zygote.refused(e, torch)):
            return self.process
        return self.start(grants.guest_argv(channel, torch), pass_fds=[channel])


def fences():
    """{fence: True/False} of what a contestant gets here: this machine's (machine.fences), or, in
    a fenced job, what the judge's process that starts its contestants lends."""
    return remote("fences")["fences"] if inside() else machine.fences()


def missing_fences():
    """The names of the fences refused here (empty when every fence holds)."""
    return [name for name, held in fences().items() if not held]


def describe_fences():
    """One phrase for reports: the fences used, and any missing (machine.describe_fences)."""
    return remote("fences")["describe"] if inside() else machine.describe_fences()


class RemoteProcess:
    """The part of a Popen a contestant's client uses, answered by the broker."""

    def __init__(self, box):
        self.box = box
        self.returncode = None

    def poll(self):
        if self.returncode is None and self.box.id is not None:
            self.returncode = remote("poll", id=self.box.id)["code"]
        return self.returncode

    def wait(self, timeout=None):
        due = None if timeout is None else time.monotonic() + timeout
        while self.poll() is None:
            if due is not None and time.monotonic() > due:
                import subprocess
                raise subprocess.TimeoutExpired("contestant", timeout)
            time.sleep(0.01)
        return self.returncode


class RemoteSandbox:
    """A contestant's sandbox that the judge's process starts and owns for this job: the members
    of sandbox.Sandbox that a contestant's client uses."""

    def __init__(self, grant, threads=1):
        self.grant, self.threads = grant, threads
        self.id, self.process, self._how = None, None, ""

    def start_guest(self, channel, torch=False):
        """Asks the judge's process for a contestant's sandbox running the guest, its line to the
        judge the descriptor channel (passed on): a typed request (what the contestant runs),
        from which the judge grants and builds what it would for its own contestant."""
        sandbox._registered()
        answer = remote("start", fds=[channel], grant=self.grant.as_request(), torch=bool(torch), threads=self.threads)
        self.id = answer["id"]
        self.process = RemoteProcess(self)
        sandbox._live.add(self)
        return self.process

    def _ask(self, op, default=None):
        if self.id is None:
            return default
        try:
            return remote(op, id=self.id)
        except BrokerError:
            return default

    def cpu_seconds(self):
        answer = self._ask("cpu")
        return None if answer is None else answer["value"]

    def processes(self):
        answer = self._ask("processes")
        return None if answer is None or answer["value"] is None else tuple(answer["value"])

    def exit_description(self):
        answer = self._ask("poll")
        return "" if answer is None else answer["how"]

    def kill(self):
        if self.id is not None:
            self._ask("kill")
            if self.process is not None and self.process.returncode is None:
                self.process.returncode = -9
            self.id = None
        sandbox._live.discard(self)


def _receive(sock, size, most_fds):
    """(message, descriptors) from sock, or (None, ()) when its other end is closed or gone."""
    try:
        data, fds, _, _ = socket.recv_fds(sock, size, most_fds)
    except OSError:
        return None, ()
    if not data:
        for fd in fds:
            os.close(fd)
        return None, ()
    return data, fds


# --- The judge's side ------------------------------------------------------------------------------

class Broker:
    """Serves one job's requests for contestants' sandboxes from a thread of the judge's process.
    `job_fd` is the descriptor the job inherits (its number in ENV); `close()` ends every sandbox
    it started."""

    def __init__(self, writable=()):
        self.writable = list(writable)   # (the job's own folders: nothing there is granted to a contestant)
        self._ours, self._theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        self.job_fd = self._theirs.fileno()
        self.boxes, self._count, self._lines = {}, 0, []
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._accept, name="dc-broker", daemon=True)
        self._thread.start()

    def job_started(self):
        """The job holds its end now: ours is closed, so that its end is the only one."""
        self._theirs.close()

    def _accept(self):
        """The job's requests for a line of their own (one per process), each served by a thread."""
        while True:
            data, fds = _receive(self._ours, 4096, 4)
            if data is None:
                return
            if len(fds) != 1 or len(self._lines) >= LIVE_LIMIT:
                for fd in fds:
                    os.close(fd)
                continue
            line = socket.socket(fileno=fds[0])
            with self._lock:
                self._lines.append(line)
            threading.Thread(target=self._serve, args=(line,), name="dc-broker-line", daemon=True).start()

    def _serve(self, line):
        while True:
            data, fds = _receive(line, MESSAGE_MAX, 16)
            if data is None:   # (the process that held it is gone: its line no longer counts)
                with self._lock:
                    if line in self._lines:
                        self._lines.remove(line)
                line.close()
                return
            try:
                request = shape.parsed(data, "broker request", MESSAGE_MAX)   # (every field typed and bounded)
                with self._lock:
                    answer = self._answer(request, fds)
            except shape.ShapeError as e:   # (a request the job made up: refused naming its field)
                answer = {"error": f"refused: {e}"}
            except Exception as e:   # (one the form allows that cannot be done: refused in one line, the broker goes on)
                answer = {"error": f"refused: {type(e).__name__}: {e}"}
            finally:
                for fd in fds:
                    os.close(fd)
            try:
                line.send(json.dumps(answer).encode())
            except OSError:
                return

    def _answer(self, request, fds):
        op = request.get("op")
        if op == "fences":
            return {"fences": machine.fences(), "describe": machine.describe_fences()}
        if op == "start":
            return self._start(request, fds)
        box = self.boxes.get(request.get("id"))
        if box is None:
            raise ValueError("no such sandbox")
        if op == "cpu":
            return {"value": box.cpu_seconds()}
        if op == "processes":
            return {"value": box.processes()}
        if op == "poll":
            return {"code": box.process.poll(), "how": box.exit_description()}
        if op == "kill":
            box.kill()
            del self.boxes[request["id"]]
            return {}
        raise ValueError(f"no such request {op!r}")

    def _start(self, request, fds):
        """A contestant's sandbox for the job: granted and commanded as the judge would its own
        (grants.py), from a typed request; no argument, option or path of the job's reaches
        bubblewrap, and exactly one descriptor (the contestant's line) is passed on."""
        grant = grants.Grant.from_request(request.get("grant") if isinstance(request.get("grant"), dict) else {},
                                          self.writable)
        torch, threads = request.get("torch", False), request.get("threads", 1)
        if type(torch) is not bool:
            raise ValueError("torch must be true or false")
        if type(threads) is not int or not 1 <= threads <= sandbox.PROCESS_LIMIT:
            raise ValueError(f"threads must be a whole number from 1 to {sandbox.PROCESS_LIMIT}")
        if len(fds) != 1:
            raise ValueError("one descriptor, the contestant's line, must be passed")
        if len(self.boxes) >= LIVE_LIMIT:
            raise ValueError(f"at most {LIVE_LIMIT} contestants' sandboxes at once")
        channel = os.dup(fds[0])
        try:
            box = guest_sandbox(grant, threads, f"a job's contestant {self._count + 1}")
            box.start_guest(channel, torch)
        finally:
            os.close(channel)
        self._count += 1
        self.boxes[self._count] = box
        return {"id": self._count}

    def close(self):
        """Ends every sandbox the job started, and the job's line to us."""
        try:
            self._ours.shutdown(socket.SHUT_RDWR)   # (wakes the serving thread: it ends)
        except OSError:
            pass
        self._thread.join(5)
        with self._lock:
            for line in self._lines:
                try:
                    line.shutdown(socket.SHUT_RDWR)
                except OSError:
                    pass
            for box in list(self.boxes.values()):
                box.kill()
            self.boxes.clear()
        for s in (self._ours, self._theirs, *self._lines):
            try:
                s.close()
            except OSError:
                pass
