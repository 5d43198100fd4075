"""dc render and the HTML reports: pictures are checked, not assumed. A body is drawn where its
step file puts it (the pixel at its centre has its fill), pictures differ between steps, a GIF
has its frames, and the HTML pages are opened in a real headless browser (Debian's chromium)."""
import json
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest
from PIL import Image

from deepcontact.render.draw import FILL, Window
from deepcontact.step.reader import read_step

from conftest import dc, one_line_error, option_error, written

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
needs_browser = [pytest.mark.process,
                 pytest.mark.skipif(CHROMIUM is None, reason="Debian's chromium is not installed (make setup)")]
needs_ffmpeg = pytest.mark.skipif(shutil.which("ffmpeg") is None, reason="Debian's ffmpeg is not installed")


def hex_rgb(colour):
    return np.array([int(colour[k:k + 2], 16) for k in (1, 3, 5)])


def steps_of(run):
    return sorted(run.glob("seed-000000/step-*.xml"))


def dynamic_circle_centres(step):
    """World centres of the step's dynamic circle bodies (the pile's circles sit at their origin)."""
    _, bodies, _ = read_step(step)
    dynamic = bodies["type"] == 2
    return bodies["position"][dynamic].astype(np.float64)


def window_of(step_file, width):
    """The window and size the renderer chose for a step, recomputed the renderer's way."""
    from deepcontact.render.frames import window_for
    from deepcontact.render.shapes import read_shapes
    w = window_for(read_shapes(step_file), [read_step(step_file)])
    return w, w.size(width)


def assert_bodies_where_the_file_puts_them(picture, window, size, centres, fill=FILL[2], tolerance=40):
    hits = 0
    for x, y in centres:
        c, r = window.pixel(x, y, size)
        pixel = picture[int(r), int(c), :3].astype(int)
        hits += int(np.abs(pixel - hex_rgb(fill)).max() <= tolerance)
    assert hits >= 0.9 * len(centres), f"{hits} of {len(centres)} body centres show the body's fill"


def test_a_step_is_drawn_where_the_step_file_puts_it(pile_run, tmp_path):
    steps = steps_of(pile_run)
    a, b = steps[40], steps[-1]
    pictures = []
    for step in (a, b):
        out = written(tmp_path / f"{step.stem}.png", "render", str(step), "--no-contacts", "--size", "400")
        picture = np.asarray(Image.open(out).convert("RGB"))
        window, size = window_of(step, 400)
        assert picture.shape == (size[1], size[0], 3)
        assert (picture != 255).any(axis=2).mean() > 0.05   # not blank
        assert_bodies_where_the_file_puts_them(picture, window, size, dynamic_circle_centres(step))
        pictures.append(picture)
    assert (pictures[0] != pictures[1]).any(axis=2).mean() > 0.01   # the bodies moved
    with_contacts = np.asarray(Image.open(written(tmp_path / "c.png", "render", str(b), "--size", "400")).convert("RGB"))
    assert (with_contacts != pictures[1]).any()   # contact points and impulse arrows drawn


def test_svg_is_a_well_formed_picture_and_reproducible(pile_run, tmp_path):
    from lxml import etree
    step = steps_of(pile_run)[-1]
    one = written(tmp_path / "a.svg", "render", str(step), "--color-by", "speed")
    two = written(tmp_path / "b.svg", "render", str(step), "--color-by", "speed")
    root = etree.parse(str(one)).getroot()
    assert root.tag.endswith("svg") and len(root.findall(".//{http://www.w3.org/2000/svg}path")) > 50
    assert one.read_bytes() == two.read_bytes()


def test_a_gif_has_a_frame_for_every_kth_step(pile_run, tmp_path):
    out = written(tmp_path / "run.gif", "render", str(pile_run), "--every", "10", "--size", "240", "--fps", "20")
    gif = Image.open(out)
    files = steps_of(pile_run)
    assert gif.n_frames == len(files[::10])
    gif.seek(0)
    first = np.asarray(gif.convert("RGB"))
    gif.seek(gif.n_frames - 1)
    last = np.asarray(gif.convert("RGB"))
    assert (first != last).any(axis=2).mean() > 0.01
    assert gif.info["duration"] == 50


def test_compare_draws_two_runs_side_by_side(pile_run, tmp_path):
    out = written(tmp_path / "both.gif", "render", str(pile_run), "--compare", str(pile_run), "--every", "30",
                  "--size", "200")
    gif = Image.open(out)
    window, (w, h) = window_of(steps_of(pile_run)[0], 200)
    assert gif.size == (2 * w, h)
    frame = np.asarray(gif.convert("RGB"))
    # the same run twice: the two halves match, except the title naming each run
    assert (frame[h // 4:, :w] != frame[h // 4:, w:]).any(axis=2).mean() < 0.01


@needs_ffmpeg
def test_an_mp4_holds_the_frames(pile_run, tmp_path):
    out = written(tmp_path / "run.mp4", "render", str(pile_run), "--every", "15", "--size", "200")
    probe = subprocess.run(["ffprobe", "-v", "error", "-count_frames", "-select_streams", "v:0", "-show_entries",
                            "stream=nb_read_frames,codec_name", "-of", "json", str(out)],
                           capture_output=True, text=True, check=True)
    stream = json.loads(probe.stdout)["streams"][0]
    assert stream["codec_name"] == "h264" and int(stream["nb_read_frames"]) == len(steps_of(pile_run)[::15])


@pytest.mark.process
def test_video_without_ffmpeg_names_the_package(pile_run, tmp_path):
    env = dict(os.environ, PATH=str(tmp_path))   # no ffmpeg on this PATH
    r = subprocess.run([sys.executable, "-m", "deepcontact.cli.main", "render", str(pile_run), "-o",
                        str(tmp_path / "run.mp4")], capture_output=True, text=True, env=env)
    one_line_error(r, "ffmpeg", "apt-get install ffmpeg")
    assert not (tmp_path / "run.mp4").exists() and not list(tmp_path.glob(".run.mp4*"))


def test_a_dataset_sample_and_the_model_beside_it(dataset, model, tmp_path):
    plain = written(tmp_path / "s.png", "render", str(dataset), "--sample", "3")
    with_model = written(tmp_path / "m.png", "render", str(dataset), "--sample", "3", "--checkpoint",
                         str(model / "best.pt"))
    a, b = Image.open(plain), Image.open(with_model)
    assert b.size[1] > 1.7 * a.size[1]   # two more rows: prediction and error
    assert np.asarray(a.convert("L")).std() > 5
    meta = json.loads((dataset / "metadata.json").read_text())
    one_line_error(dc("render", str(dataset), "--sample", str(meta["samples"]), "-o", str(tmp_path / "x.png")),
                   "out of range")


def test_bad_requests(pile_run, tmp_path):
    step = steps_of(pile_run)[-1]
    option_error(dc("render", str(step), "-o", str(tmp_path / "a.bmp")), "unknown extension", ".bmp")
    option_error(dc("render", str(step), "-o", str(tmp_path / "a.gif")), "drawn as .png or .svg")
    one_line_error(dc("render", str(tmp_path / "missing.xml"), "-o", str(tmp_path / "a.png")), "no such file")
    out = written(tmp_path / "a.png", "render", str(step))
    before = out.read_bytes()
    one_line_error(dc("render", str(steps_of(pile_run)[0]), "-o", str(out)), "--overwrite")
    assert out.read_bytes() == before
    bad = tmp_path / "bad.xml"
    bad.write_text(step.read_text().replace('<spin omega="', '<spin omega="x', 1))
    one_line_error(dc("render", str(bad), "-o", str(tmp_path / "b.png")), f"{bad}:",
                   "is not a valid value of the atomic type 'finite'")   # (the schema's words: read through it)
    assert not (tmp_path / "b.png").exists()


def screenshot(page, size, tmp_path, fragment=""):
    shot = tmp_path / f"shot-{page.stem}.png"
    subprocess.run([CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
                    "--force-device-scale-factor=1", f"--window-size={size[0]},{size[1]}", f"--screenshot={shot}",
                    page.resolve().as_uri() + fragment], capture_output=True, text=True, timeout=120, check=True)
    return np.asarray(Image.open(shot).convert("RGB"))


@needs_browser[0]
@needs_browser[1]
def test_the_run_viewer_in_a_real_browser(pile_run, tmp_path):
    page = written(tmp_path / "run.html", "render", str(pile_run), "--every", "5", "--size", "480")
    text = page.read_text()
    assert "http://" not in text and "https://" not in text   # nothing fetched: one file, offline
    files = steps_of(pile_run)[::5]
    window, size = window_of(files[0], 480)
    for k in (len(files) // 2, len(files) - 1):
        # (arrows at 1/8 of their length: the check reads the pixel at each body's centre)
        picture = screenshot(page, (size[0] + 340, size[1] + 40), tmp_path, f"#frame={k}&arrows=-3")
        assert (picture[:size[1], :size[0]] != 255).any(axis=2).mean() > 0.05
        assert_bodies_where_the_file_puts_them(picture, window, size, dynamic_circle_centres(files[k]))


@needs_browser[0]
@needs_browser[1]
def test_the_evaluate_report_page_in_a_real_browser(run, tmp_path):
    report = written(tmp_path / "r", "evaluate", str(run), "--starts", "zero,builtin", "--every", "20")
    page = report / "report.html"
    text = page.read_text()
    assert "<table>" in text and text.count("<svg") == 3 and "http://www" not in text.replace(
        "http://www.w3.org", "")   # the SVG namespaces are names, not fetches
    picture = screenshot(page, (1000, 1400), tmp_path)
    assert (picture != 255).any(axis=2).mean() > 0.03   # the tables and plots drew
    md = (report / "report.md").read_text()
    assert md.count("|") > 20 and "convergence.png" in md


def test_the_viewer_carries_the_solvers_numbers_where_the_run_recorded_them(tmp_path):
    run = written(tmp_path / "pgs", "simulate", "pile", "--param", "count=12", "--param", "box=12", "--param",
                  "sigma=2.5", "--steps", "60", "--solver", "pgs", "--tolerance", "1e-4", "--max-iterations", "200")
    page = written(tmp_path / "pgs.html", "render", str(run), "--every", "10").read_text()
    data = json.loads(page.split('<script id="data" type="application/json">', 1)[1].split("</script>", 1)[0])
    assert len(data["frames"]) == 6 and all(f["solve"] is not None for f in data["frames"])
    last = data["frames"][-1]
    header = read_step(steps_of(run)[::10][-1])[0]["solve"]
    assert last["solve"] == {"iterations": int(header["iterations"]), "residual": float(header["residual"])}


def viewer_data(page):
    import re
    return json.loads(re.search(r'<script id="data" type="application/json">(.*?)</script>', page.read_text(),
                                flags=re.S).group(1))


def test_one_impulse_scale_per_run_shared_by_step_movie_and_viewer(pile_run, tmp_path):
    from deepcontact.render.frames import run_impulse_scale
    files = steps_of(pile_run)
    scale = run_impulse_scale(files)
    # a robust statistic: at rest the median arrow is a readable length, not a pixel
    _, _, contacts = read_step(files[-1])
    window, size = window_of(files[-1], 640)
    resting = np.median(np.abs(contacts["normal_impulse"])) * scale / (window.x1 - window.x0) * size[0]
    assert resting > 8, resting
    # the viewer carries the run's scale whatever --every, and a legend value
    for every in ("3", "7"):
        data = viewer_data(written(tmp_path / f"v{every}.html", "render", str(pile_run), "--every", every))
        assert data["scale"] == pytest.approx(scale) and data["legend"] > 0
    # a step PNG and a GIF frame drawn by default are the pictures drawn at the run's scale, given
    step = files[len(files) // 2]
    default = written(tmp_path / "a.png", "render", str(step)).read_bytes()
    given = written(tmp_path / "b.png", "render", str(step), "--impulse-scale", repr(scale)).read_bytes()
    assert default == given
    other = written(tmp_path / "c.png", "render", str(step), "--impulse-scale", repr(4 * scale)).read_bytes()
    assert other != default
    gif = [written(tmp_path / f"{k}.gif", "render", str(pile_run), "--every", "40", *extra).read_bytes()
           for k, extra in enumerate([(), ("--impulse-scale", repr(scale))])]
    assert gif[0] == gif[1]
    data = viewer_data(written(tmp_path / "g.html", "render", str(pile_run), "--impulse-scale", "0.5"))
    assert data["scale"] == 0.5
    option_error(dc("render", str(step), "--no-contacts", "--impulse-scale", "1", "-o", str(tmp_path / "n.png")),
                 "--impulse-scale")


@needs_browser[0]
@needs_browser[1]
def test_the_viewers_arrow_control_lengthens_the_arrows(pile_run, tmp_path):
    page = written(tmp_path / "run.html", "render", str(pile_run), "--every", "10", "--size", "480")
    files = steps_of(pile_run)[::10]
    _, size = window_of(files[0], 480)
    red = []
    for arrows in ("0", "2"):
        picture = screenshot(page, (size[0] + 340, size[1] + 40), tmp_path, f"#frame={len(files) - 1}&arrows={arrows}")
        canvas = picture[:size[1], :size[0]].astype(int)
        red.append(int(((canvas[..., 0] > 150) & (canvas[..., 1] < 80) & (canvas[..., 2] < 80)).sum()))
    assert red[1] > 1.5 * red[0] > 0, red


def test_comparing_different_simulations_warns(pile_run, tmp_path):
    other = tmp_path / "other"
    steps = str(len(steps_of(pile_run)))
    assert dc("simulate", "pile", "--seed", "5", "--steps", steps, "-q", "-o", str(other)).returncode == 0
    r = dc("render", str(pile_run), "--compare", str(other), "--every", "10", "--size", "200", "-o",
           str(tmp_path / "both.gif"))
    assert r.returncode == 0 and "different simulations" in r.stderr, r.stderr


def test_a_dataset_sample_shares_one_colour_range_names_its_split_and_warns_nothing(dataset, model):
    import warnings
    from deepcontact.render import panels
    meta = json.loads((dataset / "metadata.json").read_text())
    assert panels._split_of(meta, meta["split"]["validation"][0]) == "validation"
    assert panels._split_of(meta, meta["split"]["train"][0]) == "train"
    assert panels._range([np.array([0.0, 45.0]), np.array([-2.0, 7.0])]) == (-2.0, 45.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert panels.sample_panels(dataset, 0, model / "best.pt")[:4] == b"\x89PNG"


def test_a_picture_keeps_room_for_its_title_and_legend():
    """A fallen stack was drawn 640x78 px with its legend cut off; the demo's title sat on the
    box's top wall. A window around bodies is at least half as high as wide, grown upwards, with a
    band above the bodies for the title and the legend."""
    from deepcontact.render.draw import MIN_ASPECT, TITLE_BAND, Window
    flat = Window.around((0.0, 0.0, 100.0, 1.0))
    assert flat.size(640) == (640, 320) and flat.y0 < 0.0 and flat.y1 > 1.0
    box = Window.around((0.0, 0.0, 10.0, 10.0))
    assert box.y1 - 10.0 >= TITLE_BAND * (box.y1 - box.y0) * 0.9 and box.y1 - box.y0 >= MIN_ASPECT * (box.x1 - box.x0)
