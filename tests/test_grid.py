"""SPH grids: kernels, splatting, interpolation, datasets and the SPH oracle."""
import json
import shutil

import numpy as np
import pytest
import torch

from conftest import dc
from deepcontact.errors import InputError
from deepcontact.grid.dataset import DatasetSettings, GridDataset, write_dataset
from deepcontact.grid.interpolate import bilinear
from deepcontact.grid.kernels import KERNELS, weight
from deepcontact.grid.spec import GridSpec, scene_box
from deepcontact.grid.splat import splat_points
from deepcontact.scene.generators import generate


@pytest.mark.parametrize("kernel", sorted(KERNELS))
@pytest.mark.parametrize("h", [0.1, 0.5, 1.3])
def test_kernels_integrate_to_one(kernel, h):
    x = np.linspace(-h, h, 1601)
    X, Y = np.meshgrid(x, x)
    dx = x[1] - x[0]
    assert weight(kernel, np.hypot(X, Y), h).sum() * dx * dx == pytest.approx(1.0, abs=2e-3)
    # and the native splatter agrees: one particle, no renormalisation, integral over a fine grid
    spec = GridSpec.over((-2 * h, -2 * h, 2 * h, 2 * h), h / 200, h, kernel, renormalize=False)
    g = splat_points(spec, np.array([[0.013 * h, -0.021 * h]]), np.array([[1.0]]))
    assert g.sum() * spec.cell ** 2 == pytest.approx(1.0, abs=2e-3)


def brute_force(spec, points, values):
    xs = spec.x0 + spec.cell * np.arange(spec.nx)
    ys = spec.y0 + spec.cell * np.arange(spec.ny)
    X, Y = np.meshgrid(xs, ys)
    out = np.zeros((values.shape[1], spec.ny, spec.nx))
    for p, v in zip(points, values):
        w = weight(spec.kernel, np.hypot(X - p[0], Y - p[1]), spec.h)
        if spec.renormalize:
            w = w / w.sum() if w.sum() > 0 else w
        out += v[:, None, None] * w[None]
    return out


@pytest.mark.parametrize("kernel", sorted(KERNELS))
@pytest.mark.parametrize("renormalize", [False, True])
@pytest.mark.parametrize("d, h", [(0.5, 0.5), (0.25, 0.6), (1.0, 0.71)])
def test_splat_equals_the_brute_force_sum(kernel, renormalize, d, h):
    rng = np.random.default_rng(1)
    spec = GridSpec.over((0, 0, 10, 8), d, h, kernel, renormalize)
    points = rng.uniform(-0.5, 10.5, size=(60, 2))
    values = rng.normal(size=(60, 3))
    got = splat_points(spec, points, values)
    want = brute_force(spec, points, values)
    assert got.shape == (3, spec.ny, spec.nx)
    assert np.allclose(got, want, rtol=1e-5, atol=1e-5 * np.abs(want).max())


def test_renormalised_grid_conserves_the_total():
    rng = np.random.default_rng(2)
    spec = GridSpec.over((0, 0, 30, 30), 0.5, 0.5)
    points = rng.uniform(0, 30, size=(200, 2))
    values = rng.uniform(0, 5, size=(200, 2))
    g = splat_points(spec, points, values)
    assert g.sum(axis=(1, 2)) == pytest.approx(values.sum(axis=0), rel=1e-5)


def test_bilinear_is_exact_for_bilinear_functions():
    spec = GridSpec.over((-3, 2, 7, 9), 0.5, 0.5)
    xs = spec.x0 + spec.cell * np.arange(spec.nx)
    ys = spec.y0 + spec.cell * np.arange(spec.ny)
    X, Y = np.meshgrid(xs, ys)

    def f(x, y):
        return 1.5 - 2.0 * x + 0.25 * y + 0.75 * x * y
    pts = np.random.default_rng(3).uniform([-3, 2], [7, 9], size=(500, 2))
    got, outside = bilinear(f(X, Y), spec, pts)
    assert outside == 0 and np.allclose(got, f(pts[:, 0], pts[:, 1]), rtol=0, atol=1e-9)
    _, outside = bilinear(f(X, Y), spec, np.array([[-4.0, 3.0], [0.0, 0.0], [1.0, 3.0]]))
    assert outside == 2


def test_the_thesis_grid_is_61_by_61():
    box = scene_box(generate("pile", 0))
    assert box == (0.0, 0.0, 30.0, 30.0)
    spec = GridSpec.over(box, 0.5, 0.5)
    assert spec.shape == (61, 61)
    assert spec.rule_warnings(1.0) == []
    assert len(GridSpec.over(box, 0.5, 0.3).rule_warnings(1.0)) == 1     # h < 0.71 d
    assert len(GridSpec.over(box, 2.0, 2.0).rule_warnings(1.0)) == 1     # d > r


def test_bad_grids_are_errors():
    for d, h in [(0.0, 0.5), (-1, 0.5), (0.5, 0.0), (float("nan"), 0.5)]:
        with pytest.raises(InputError):
            GridSpec.over((0, 0, 30, 30), d, h)
    with pytest.raises(InputError, match="exceeds the limit of 16,777,216 nodes"):
        GridSpec.over((0, 0, 3000, 3000), 0.1, 0.1)


@pytest.fixture(scope="module")
def two_runs(tmp_path_factory):
    base = tmp_path_factory.mktemp("grid")
    small = ["--param", "count=30", "--param", "box=16", "--param", "sigma=4", "--steps", "100"]
    for name, seeds in (("a", "0..2"), ("b", "3..3")):
        r = dc("simulate", "pile", *small, "--seeds", seeds, "-q", "-o", str(base / name))
        assert r.returncode == 0, r.stderr
    return base


def test_dataset_layout_split_and_loader(two_runs, tmp_path):
    out = tmp_path / "ds"
    meta = write_dataset([two_runs / "a", two_runs / "b"], out, DatasetSettings(validation_fraction=0.25, seed=1))
    ds = GridDataset(out)
    n = len(ds)
    assert n == meta["samples"] > 100
    assert ds.arrays["inputs"].shape == (n, 6, 33, 33) and ds.arrays["labels"].shape == (n, 2, 33, 33)
    assert ds.arrays["inputs"].dtype == np.float32 and isinstance(ds.arrays["inputs"], np.memmap)
    assert meta["grid"]["kernel"] == "poly6" and meta["grid"]["renormalize"] is True
    assert meta["inputs"] == ["mass", "vx", "vy", "spin", "nx", "ny"]
    assert all(len(s["manifest_sha256"]) == 64 for s in meta["sources"])
    train, val = ds.indices("train"), ds.indices("validation")
    assert len(train) + len(val) == n and len(val) > 0
    sims_train = set(ds.arrays["simulation"][train])
    sims_val = set(ds.arrays["simulation"][val])
    assert not sims_train & sims_val                 # split by simulation, never by step
    x, y = ds.torch_dataset("train")[0]
    assert isinstance(x, torch.Tensor) and x.shape == (6, 33, 33) and y.dtype == torch.float32
    # the label grid sums to the step's impulses (renormalised), and the contacts are kept
    pos, imp = ds.contacts(int(train[-1]))
    assert ds.arrays["labels"][train[-1], 0].sum() == pytest.approx(imp[:, 0].sum(), rel=1e-4)
    assert json.loads((out / "metadata.json").read_text())["split"] == meta["split"]


def test_dataset_cli_refuses_and_leaves_nothing_partial(two_runs, tmp_path):
    out = tmp_path / "ds"
    r = dc("rasterize", str(two_runs / "a"), "-o", str(out), "--inputs", "mass,vx", "--labels",
           "normal_impulse", "-q")
    assert r.returncode == 0, r.stderr
    assert GridDataset(out).arrays["labels"].shape[1] == 1
    r = dc("rasterize", str(two_runs / "a"), "-o", str(out))
    assert r.returncode == 1 and "--overwrite" in r.stderr
    bad_run = tmp_path / "bad"
    shutil.copytree(two_runs / "a", bad_run)
    step = sorted(bad_run.glob("seed-*/step-*.xml"))[-1]
    step.write_bytes(step.read_bytes()[:9000])        # truncated
    r = dc("rasterize", str(bad_run), "-o", str(tmp_path / "ds2"))
    assert r.returncode == 1 and str(step) in r.stderr and len(r.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "ds2").exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".ds2")]
    step.write_text((two_runs / "a" / step.relative_to(bad_run)).read_text().replace(
        '<spin omega="', '<spin omega="nan', 3))
    r = dc("rasterize", str(bad_run), "-o", str(tmp_path / "ds3"))
    # (held to the schema as it is read: the XSD's own words for a value that is not a finite number)
    assert r.returncode == 1 and ("not a number" in r.stderr or "not finite" in r.stderr
                                  or "not a valid value of the atomic type 'finite'" in r.stderr), r.stderr
    r = dc("rasterize", str(two_runs / "a"), "--cell", "0", "-o", str(tmp_path / "ds4"))
    assert r.returncode == 2 and "--cell" in r.stderr   # bad option values exit 2
    r = dc("rasterize", str(two_runs / "a"), "--inputs", "mass,colour", "-o", str(tmp_path / "ds5"))
    assert r.returncode == 2 and "colour" in r.stderr
    r = dc("rasterize", str(tmp_path), "-o", str(tmp_path / "ds6"))
    assert r.returncode == 1 and "manifest" in r.stderr


def test_different_boxes_need_a_window(two_runs, tmp_path):
    other = tmp_path / "wide"
    r = dc("simulate", "pile", "--param", "count=20", "--param", "box=20", "--param", "sigma=4", "--steps", "80",
           "-q", "-o", str(other))
    assert r.returncode == 0
    with pytest.raises(InputError, match="different boxes"):
        write_dataset([two_runs / "a", other], tmp_path / "ds")
    meta = write_dataset([two_runs / "a", other], tmp_path / "ds", DatasetSettings(window=(0, 0, 20, 20)))
    assert meta["grid"]["nx"] == 41


def test_numpy_and_torch_bilinear_read_the_same_values():
    """The two readers of a grid at points (the start's, numpy; the training loss's, torch) agree,
    inside the grid, on its edges and outside it (clamped to the edge)."""
    import torch
    from deepcontact.grid.interpolate import bilinear
    from deepcontact.grid.spec import GridSpec
    from deepcontact.model.losses import bilinear_torch
    spec = GridSpec(x0=-1.5, y0=2.0, cell=0.25, nx=13, ny=9, h=0.25)
    rng = np.random.default_rng(5)
    grid = rng.normal(size=(2, spec.ny, spec.nx))
    points = np.concatenate([rng.uniform([spec.x0, spec.y0], [spec.x1, spec.y1], (200, 2)),
                             [[spec.x0, spec.y0], [spec.x1, spec.y1], [spec.x1, spec.y0]],
                             rng.uniform([spec.x0 - 1, spec.y0 - 1], [spec.x1 + 1, spec.y1 + 1], (50, 2))])
    ours, outside = bilinear(grid, spec, points)
    theirs = bilinear_torch(torch.as_tensor(grid), spec, torch.as_tensor(points)).numpy()
    np.testing.assert_allclose(ours, theirs, rtol=1e-12, atol=1e-12)
    assert outside == int(spec.outside(points).sum()) > 0
