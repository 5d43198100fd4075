"""A run (one simulation of it) as frames: the step files every k-th, each drawn by a Painter,
and the frames written as GIF (Pillow) or MP4/WebM (Debian's ffmpeg, fed raw frames on a pipe).
With a second run, the two are drawn side by side, step for step, with the largest distance
between the same body in both."""
import io
import os
import shutil
import subprocess
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import output, workers
from ..errors import InputError, count
from ..step.reader import check_origin, read_step
from ..step.run_folder import read_run, step_index
from .draw import Painter, Window, impulse_scale_for
from .shapes import read_shapes

VIDEO = {".mp4": ("mp4", ["-c:v", "libx264", "-pix_fmt", "yuv420p", "-preset", "veryfast"]),
         ".webm": ("webm", ["-c:v", "libvpx-vp9", "-pix_fmt", "yuv420p", "-b:v", "0", "-crf", "40", "-deadline",
                            "realtime", "-cpu-used", "8"])}


@dataclass
class Clip:
    """The step files of one simulation to draw, and what every frame shares."""
    path: Path           # the run folder
    scene: str
    seed: int
    files: list          # every k-th step file
    total: int           # step files in the simulation
    all_files: list = None   # every step file of the simulation (the impulse scale is the run's)
    engine: str = None   # the run's engine, which each step file must name (None: not known)


def simulation_files(run_dir, seed=None, every=1):
    """The chosen simulation (by seed; the first by default) of a run folder, or the simulation
    folder itself, as a Clip."""
    run_dir = Path(run_dir)
    if run_dir.name.startswith("seed-") and not (run_dir / "manifest.json").exists():
        run = read_run(run_dir.parent, unfinished=True)
        sims = [s for s in run.simulations if s.dir == run_dir.name]
    else:
        sims = read_run(run_dir, unfinished=True).simulations
        if seed is not None:
            sims = [s for s in sims if s.seed == seed]
            if not sims:
                raise InputError(f"the run has no simulation of seed {seed}", run_dir)
    if not sims or not sims[0].files:
        raise InputError("no step files here (expected seed-NNNNNN/step-NNNNNN.xml)", run_dir)
    s = sims[0]
    return Clip(path=run_dir, scene=s.scene, seed=s.seed, files=s.files[::every], total=len(s.files),
                all_files=list(s.files), engine=s.engine)


def read_frame(clip, path):
    header, bodies, contacts = read_step(path)
    if clip.scene is not None:
        check_origin(header, clip.scene, clip.seed, path, clip.engine)
    return header, bodies, contacts


def title(header, bodies, contacts, extra=""):
    solve = header.get("solve")
    solved = f" · {count(int(solve['iterations']), 'sweep')}, residual {float(solve['residual']):.1e}" if solve else ""
    return (f"{header['scene']} · seed {header['seed']} · step {header['index']} · t = {float(header['time']):.2f} s\n"
            f"{len(bodies['index'])} bodies · {len(contacts['manifold'])} contact points{solved}"
            + (f"\n{extra}" if extra else ""))


def window_for(shapes, frames):
    """Around every body of the first and last frames (static geometry included)."""
    bounds = [shapes.bounds(b) for _, b, _ in frames]
    bounds = [b for b in bounds if b is not None]
    if not bounds:
        raise InputError("nothing to draw: the step has no bodies with shapes")
    return Window.around((min(b[0] for b in bounds), min(b[1] for b in bounds),
                          max(b[2] for b in bounds), max(b[3] for b in bounds)))


SCALE_SAMPLE = 48   # step files read for a run's impulse scale, spread evenly over the run


def run_impulse_scale(files):
    """One impulse scale (metres of arrow per N·s) for every picture of a simulation: PNG, movie
    and viewer alike, whatever their window or --every. From the normal impulses of up to
    SCALE_SAMPLE of its step files, spread evenly, against the window around its first and last
    steps (draw.impulse_scale_for)."""
    files = list(files)
    if not files:
        return 0.0
    picked = [files[round(i)] for i in np.linspace(0, len(files) - 1, min(SCALE_SAMPLE, len(files)))]
    steps = {f: read_step(f) for f in dict.fromkeys([files[0], files[-1], *picked])}
    window = window_for(read_shapes(files[0]), [steps[files[0]], steps[files[-1]]])
    return impulse_scale_for([steps[f][2]["normal_impulse"] for f in picked], window)


def painter_for(clip, width, contacts=True, color_by="type", window=None, panels=1, impulse_scale=None):
    """A Painter for a clip: shapes from its first step file, the window around its first and
    last steps, the run's impulse scale (run_impulse_scale) unless one is given."""
    shapes = read_shapes(clip.files[0])
    ends = [read_frame(clip, clip.files[0]), read_frame(clip, clip.files[-1])]
    window = window or window_for(shapes, ends)
    speeds = [np.hypot(*b["velocity"].T).max(initial=0.0) for _, b, _ in ends]
    scale = impulse_scale or run_impulse_scale(clip.all_files or clip.files)
    return Painter(shapes, window, width, contacts=contacts, color_by=color_by, impulse_scale=scale,
                   speed_max=max(max(speeds), 1e-6), panels=panels)


def distance(a, b):
    """The largest distance between the same body in two steps (bodies in both)."""
    common, ia, ib = np.intersect1d(a["index"], b["index"], return_indices=True)
    if not len(common):
        return float("nan")
    return float(np.max(np.hypot(*(a["position"][ia] - b["position"][ib]).astype(np.float64).T)))


def _others(compare):
    return {} if compare is None else {step_index(f): f for f in compare.files}


def _draw(clip, painter, k, compare, others):
    """Frame k of the clip, drawn by the painter, as RGB."""
    header, bodies, contacts = read_frame(clip, clip.files[k])
    progress = (k + 1) / len(clip.files)
    extra = ""
    if compare is not None:
        other = others.get(header["index"])
        if other is None:
            raise InputError(f"the run compared has no step {header['index']}", compare.path)
        h2, b2, c2 = read_frame(compare, other)
        extra = f"max distance between the runs {distance(bodies, b2):.3g} m"
        painter.draw(b2, c2, title(h2, b2, c2, extra) + f"\n{compare.path}", panel=1, progress=progress)
    painter.draw(bodies, contacts, title(header, bodies, contacts, extra) + (f"\n{clip.path}" if compare else ""),
                 panel=0, progress=progress)
    return painter.rgb()


_worker_painter = {}   # in a worker process: the painter it draws with, built once from its spec


def _draw_task(task):
    """A worker's frame: (clip, painter spec, k, compare, gif fps or None) -> RGB, or a GIF chunk."""
    clip, spec, k, compare, gif_fps = task
    if not _worker_painter:   # (a worker serves one command: one painter)
        _worker_painter.update(painter=Painter(**spec), others=_others(compare))
    rgb = _draw(clip, _worker_painter["painter"], k, compare, _worker_painter["others"])
    workers.progress(1)
    return rgb if gif_fps is None else gif_chunk(rgb, gif_fps, first=k == 0)


def drawn(clip, painter, compare=None, jobs=1, gif_fps=None, progress=None):
    """The clip's frames in order, drawn by `jobs` worker processes (each with a painter like this
    one): RGB arrays, or with gif_fps the GIF chunks write_gif joins. The same frames with any
    jobs. progress(n): n more frames drawn."""
    if jobs <= 1 or len(clip.files) < 2:
        others = _others(compare)
        for k in range(len(clip.files)):
            rgb = _draw(clip, painter, k, compare, others)
            if progress is not None:
                progress(1)
            yield rgb if gif_fps is None else gif_chunk(rgb, gif_fps, first=k == 0)
        return
    spec = painter.spec()
    tasks = [(clip, spec, k, compare, gif_fps) for k in range(len(clip.files))]
    with workers.pool(max(1, min(jobs, len(tasks))), progress) as pool:
        yield from pool.imap(_draw_task, tasks)


def gif_chunk(rgb, fps, first):
    """One frame's bytes in an animated GIF (its own 128-colour palette)."""
    from PIL import Image
    frame = Image.fromarray(rgb).convert("P", palette=Image.ADAPTIVE, colors=128)
    buf = io.BytesIO()
    frame.save(buf, format="GIF", duration=round(1000 / fps), optimize=False)
    return _gif_frame(buf.getvalue(), first=first)


def write_gif(out, chunks):
    """An animated GIF from its frames' chunks (gif_chunk), each written as it comes: memory
    holds one frame, whatever the run's length."""
    written = 0
    with output.open_for_write(out) as f:
        for chunk in chunks:
            f.write(chunk)
            written += 1
        if not written:
            raise InputError("no frames to write", out)
        f.write(b"\x3b")   # the trailer
    return written


def _gif_frame(data, first):
    """The bytes one single-frame GIF contributes to an animation: for the first frame its header,
    screen, palette and a loop-forever extension; for every frame its blocks, the palette moved
    into the image descriptor (a local colour table) after the first."""
    packed = data[10]
    table = 3 * 2 ** ((packed & 7) + 1) if packed & 0x80 else 0
    palette, pos = data[13:13 + table], 13 + table
    out = bytearray()
    if first:
        out += data[:pos] + b"\x21\xff\x0bNETSCAPE2.0\x03\x01\x00\x00\x00"
    while data[pos] != 0x3b:
        if data[pos] == 0x21:                        # an extension: label, then sub-blocks to a 0
            end = pos + 2
            while data[end]:
                end += data[end] + 1
            out += data[pos:end + 1]
            pos = end + 1
        elif data[pos] == 0x2c:                      # an image: descriptor, LZW size, sub-blocks to a 0
            descriptor = bytearray(data[pos:pos + 10])
            if descriptor[9] & 0x80:
                raise ValueError("unexpected local colour table in a single-frame GIF")
            pos += 10
            if not first and table:
                descriptor[9] |= 0x80 | (packed & 7)
                descriptor += palette
            end = pos + 1
            while data[end]:
                end += data[end] + 1
            out += descriptor + data[pos:end + 1]
            pos = end + 1
        else:
            raise ValueError(f"unexpected GIF block 0x{data[pos]:02x}")
    return bytes(out)


def write_video(out, frames_iter, fps, size):
    out = Path(out)
    fmt, codec = VIDEO[out.suffix.lower()]
    ffmpeg = shutil.which("ffmpeg")
    if ffmpeg is None:
        raise InputError(f"{out.suffix} needs ffmpeg, which is not installed: install Debian's ffmpeg "
                         f"(apt-get install ffmpeg), or write a .gif", out)
    tmp = output.new_temporary(out)   # (noted in the lock: a killed run's copy is removed by the next)
    w, h = size
    cmd = [ffmpeg, "-loglevel", "error", "-y", "-f", "rawvideo", "-pix_fmt", "rgb24", "-s", f"{w}x{h}", "-r", str(fps),
           "-i", "-", *codec, "-f", fmt, str(tmp)]
    proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stderr=subprocess.PIPE)
    count = 0
    try:
        for f in frames_iter:
            proc.stdin.write(np.ascontiguousarray(f).tobytes())
            count += 1
        proc.stdin.close()
        err = proc.stderr.read().decode(errors="replace")
        if proc.wait() != 0:
            raise InputError(f"ffmpeg failed: {err.strip()[-300:]}", out)
        os.replace(tmp, out)
    except BaseException:
        proc.kill()
        proc.wait()
        if tmp.exists():
            tmp.unlink()
        raise
    return count
