"""Training and inference: shapes, losses, overfitting, exact resume, determinism, bad input."""
import json
import sys

import numpy as np
import pytest
import torch

from conftest import dc
from deepcontact.errors import InputError
from deepcontact.grid.dataset import DatasetSettings, write_dataset
from deepcontact.model import losses
from deepcontact.model.inference import Predictor
from deepcontact.model.networks import build, parameter_count
from deepcontact.model.checkpoint import load_checkpoint
from deepcontact.model.config import TrainConfig, thesis_lr
from deepcontact.model.train import train
from deepcontact.scene.generators import generate
from deepcontact.simulate.build import build_world


def test_thesis_network_has_the_thesis_weight_count_and_shapes():
    m = build(dict(model="thesis", in_channels=5, out_channels=2, height=61, width=61))
    assert parameter_count(m)[0] == 64_498_866        # Table 5.1 / Appendix C on 61 x 61 x 5
    m6 = build(dict(model="thesis", in_channels=6, out_channels=1, height=33, width=33, final_relu=False))
    assert m6(torch.randn(3, 6, 33, 33)).shape == (3, 1, 33, 33)
    assert (m(torch.randn(2, 5, 61, 61)) >= 0).all()   # the thesis's final ReLU: no negative impulses


def test_fcn_shapes_and_size():
    for h, w in [(61, 61), (33, 40), (7, 9)]:
        f = build(dict(model="fcn", in_channels=6, out_channels=2, fcn_width=8, fcn_depth=2))
        assert f(torch.randn(2, 6, h, w)).shape == (2, 2, h, w)
    full = build(dict(model="fcn", in_channels=6, out_channels=2))
    assert parameter_count(full)[0] < 1_000_000


def test_masked_loss_ignores_zero_label_nodes():
    target = torch.zeros(1, 1, 4, 4)
    target[0, 0, 1, 2] = 3.0
    pred = torch.full((1, 1, 4, 4), 100.0)
    pred[0, 0, 1, 2] = 1.0
    assert losses.masked_mse(pred, target).item() == pytest.approx(4.0)
    assert losses.mse(pred, target).item() > 1000


def test_thesis_schedule():
    assert [thesis_lr(e) for e in (0, 99, 100, 299, 300, 499, 500, 999)] == \
        [5e-3, 5e-3, 2e-3, 2e-3, 1e-3, 1e-3, 2e-4, 2e-4]


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """A tiny dataset: a few steps of a small pile, 2 simulations (one for validation)."""
    base = tmp_path_factory.mktemp("train")
    r = dc("simulate", "pile", "--param", "count=12", "--param", "box=12", "--param", "sigma=2.5", "--steps", "60",
           "--seeds", "0..1", "--skip-contactless", "-q", "-o", str(base / "run"))
    assert r.returncode == 0, r.stderr
    write_dataset([base / "run"], base / "ds", DatasetSettings(cell=1.0, h=1.0, validation_fraction=0.5))
    return base / "ds"


SMALL = dict(model="fcn", fcn_width=4, fcn_depth=2, batch_size=8, optimizer="adam", lr=3e-3, weight_decay=0.0)


def test_a_tiny_model_overfits_a_tiny_dataset(tiny, tmp_path):
    torch.set_num_threads(2)
    history = train(tiny, tmp_path / "m", TrainConfig(**dict(SMALL, epochs=120, batch_size=32, lr=1e-2)), plots=False)
    first, last = history[0]["train_loss"], min(r["train_loss"] for r in history)
    assert last < first / 100, (first, last)


def test_resume_gives_the_uninterrupted_weights_and_same_seed_same_weights(tiny, tmp_path):
    cfg = dict(SMALL, epochs=4, seed=7)
    train(tiny, tmp_path / "whole", TrainConfig(**cfg))
    train(tiny, tmp_path / "part", TrainConfig(**dict(cfg, epochs=2)))
    ck = load_checkpoint(tmp_path / "part" / "last.pt")          # resume as if stopped after epoch 1
    ck["train_config"]["epochs"] = 4
    torch.save(ck, tmp_path / "part" / "last.pt")
    train(tiny, tmp_path / "part", resume=True)
    again = tmp_path / "again"
    train(tiny, again, TrainConfig(**cfg))
    a = load_checkpoint(tmp_path / "whole" / "last.pt")["model"]
    b = load_checkpoint(tmp_path / "part" / "last.pt")["model"]
    c = load_checkpoint(again / "last.pt")["model"]
    for k in a:
        assert torch.equal(a[k], b[k]), k
        assert torch.equal(a[k], c[k]), k
    metrics = json.loads((tmp_path / "part" / "metrics.json").read_text())
    assert [r["epoch"] for r in metrics] == [0, 1, 2, 3]
    assert (tmp_path / "whole" / "loss.png").exists() and (tmp_path / "whole" / "metrics.csv").exists()


def test_a_stop_within_an_epoch_resumes_from_its_mid_epoch_checkpoint_to_the_uninterrupted_weights(tiny, tmp_path):
    """A run stopped within its second epoch (its caller's stop, after the third batch) keeps
    mid-epoch.pt, the place in that epoch; --resume continues there, and the weights, optimizer,
    metrics and losses are those of the run never stopped. The whole epoch's last.pt takes
    mid-epoch.pt's place."""
    cfg = dict(SMALL, epochs=3, seed=5, batch_size=4)
    whole = train(tiny, tmp_path / "whole", TrainConfig(**cfg), plots=False, keep_every=None)

    def stop_at(stop_epoch, stop_done):   # (the caller's stop, as Ctrl-C raises it, after a batch)
        def heartbeat(epoch, done, total):
            if (epoch, done) == (stop_epoch, stop_done):
                raise KeyboardInterrupt
        return heartbeat
    with pytest.raises(KeyboardInterrupt):
        train(tiny, tmp_path / "part", TrainConfig(**cfg), plots=False, keep_every=0, heartbeat=stop_at(1, 12))
    mid = load_checkpoint(tmp_path / "part" / "mid-epoch.pt")
    assert (mid["epoch"], mid["position"]["next"], len(mid["history"])) == (1, 12, 1)
    assert load_checkpoint(tmp_path / "part" / "last.pt")["epoch"] == 0
    resumed = train(tiny, tmp_path / "part", resume=True, plots=False, keep_every=0)
    assert not (tmp_path / "part" / "mid-epoch.pt").exists()
    a, b = (load_checkpoint(tmp_path / run / "last.pt") for run in ("whole", "part"))
    for k in a["model"]:
        assert torch.equal(a["model"][k], b["model"][k]), k
    assert torch.equal(a["optimizer"]["state"][0]["exp_avg"], b["optimizer"]["state"][0]["exp_avg"])
    losses_of = [[r["train_loss"], r["val_loss"]] for r in whole], [[r["train_loss"], r["val_loss"]] for r in resumed]
    assert losses_of[0] == losses_of[1]
    # a stop in the first epoch, before any last.pt: mid-epoch.pt alone is resumed
    with pytest.raises(KeyboardInterrupt):
        train(tiny, tmp_path / "first", TrainConfig(**cfg), plots=False, keep_every=0, heartbeat=stop_at(0, 8))
    assert sorted(p.name for p in (tmp_path / "first").glob("*.pt")) == ["mid-epoch.pt"]
    r = dc("train", str(tiny), "-o", str(tmp_path / "first"), "--resume", "--checkpoint-every", "0", "--no-plots", "-q")
    assert r.returncode == 0, r.stderr
    c = load_checkpoint(tmp_path / "first" / "last.pt")
    assert all(torch.equal(a["model"][k], c["model"][k]) for k in a["model"])
    # a mid-epoch checkpoint's place is checked before anything is built from it
    mid["position"]["next"] = len(mid["position"]["order"]) + 1
    torch.save(mid, tmp_path / "bad.pt")
    with pytest.raises(InputError, match="'position' must hold"):
        load_checkpoint(tmp_path / "bad.pt")


def test_one_map_models_and_the_contacts_loss(tiny, tmp_path):
    h = train(tiny, tmp_path / "n", TrainConfig(**dict(SMALL, epochs=1, targets=["normal_impulse"], loss="contacts")),
              plots=False)
    assert "val_contact_rmse_normal" in h[0] and "val_contact_rmse_tangent" not in h[0]
    ck = load_checkpoint(tmp_path / "n" / "best.pt")
    assert ck["network"]["out_channels"] == 1 and ck["targets"] == ["normal_impulse"]


def test_inference_returns_feasible_impulses_for_every_contact(tiny, tmp_path):
    train(tiny, tmp_path / "m", TrainConfig(**dict(SMALL, epochs=1)), plots=False)
    predictor = Predictor(tmp_path / "m" / "best.pt")
    scene = generate("pile", 5, dict(count=12, box=12.0, sigma=2.5))
    world = build_world(scene)
    for _ in range(60):
        bodies, contacts = world.step(scene.dt, 8, 3, record=True)
    start = predictor.predict(bodies, contacts)
    n = len(contacts["manifold"])
    assert n > 0 and start.normal.shape == (n,) and start.tangent.shape == (n,)
    assert np.all(start.normal >= 0) and np.all(np.isfinite(start.normal))
    assert np.all(np.abs(start.tangent) <= contacts["friction"] * start.normal + 1e-12)
    assert set(start.seconds) == {"rasterize", "model", "interpolate"}


def test_bad_checkpoints_and_mismatched_datasets(tiny, tmp_path):
    train(tiny, tmp_path / "m", TrainConfig(**dict(SMALL, epochs=1)), plots=False)
    good = tmp_path / "m" / "last.pt"
    broken = tmp_path / "broken.pt"
    broken.write_bytes(good.read_bytes()[:1000])
    with pytest.raises(InputError, match="truncated or damaged"):
        Predictor(broken)
    r = dc("train", str(tiny), "-o", str(tmp_path / "m"), "--epochs", "1")
    assert r.returncode == 1 and "--resume" in r.stderr
    r = dc("train", str(tiny), "-o", str(tmp_path / "x"), "--targets", "colour")
    assert r.returncode == 1 and "no colour" in r.stderr
    r = dc("train", str(tmp_path), "-o", str(tmp_path / "y"))
    assert r.returncode == 1 and "not a dataset" in r.stderr
    other = tmp_path / "other"
    write_dataset([tiny.parent / "run"], other, DatasetSettings(cell=0.5, h=0.5))
    ck = load_checkpoint(good)
    from deepcontact.grid.dataset import GridDataset
    from deepcontact.model.checkpoint import check_compatible
    with pytest.raises(InputError, match="grid"):
        check_compatible(ck, GridDataset(other).metadata, good)


def test_a_nan_loss_stops_with_a_clear_message_and_keeps_the_checkpoint(tiny, tmp_path):
    out = tmp_path / "m"
    train(tiny, out, TrainConfig(**dict(SMALL, epochs=1)))
    before = (out / "last.pt").read_bytes()
    ck = load_checkpoint(out / "last.pt")
    ck["train_config"]["epochs"] = 3
    next(iter(ck["model"].values())).fill_(float("nan"))      # diverges at once
    torch.save(ck, out / "last.pt")
    before = (out / "last.pt").read_bytes()
    r = dc("train", str(tiny), "-o", str(out), "--resume")
    assert r.returncode == 1 and "the loss became nan" in r.stderr.lower() and "Traceback" not in r.stderr
    assert (out / "last.pt").read_bytes() == before


def test_solver_loss_is_zero_at_the_solution_and_trains(tiny, tmp_path):
    from deepcontact.grid.dataset import GridDataset
    from deepcontact.solver.problem import StepProblem
    from deepcontact.solver.reference import reference_solution
    ds = GridDataset(tiny)
    loss = losses.SolverLoss(ds)
    i = int(ds.indices("train")[-1])
    p = loss.problem(i)
    problem = StepProblem.from_step_file(loss.ds.step_file(i))
    exact = reference_solution(problem)
    at_solution = loss.residual(torch.as_tensor(exact.normal_impulse), torch.as_tensor(exact.tangent_impulse), p)
    at_zero = loss.residual(torch.zeros(problem.points, dtype=torch.float64),
                            torch.zeros(problem.points, dtype=torch.float64), p)
    assert at_solution.abs().max() < 1e-9 < at_zero.abs().max()
    relaxed = losses.SolverLoss(ds, sweeps=5).residual(torch.zeros(problem.points, dtype=torch.float64),
                                                      torch.zeros(problem.points, dtype=torch.float64), p)
    assert (relaxed ** 2).sum() < (at_zero ** 2).sum()
    h = train(tiny, tmp_path / "s", TrainConfig(**dict(SMALL, epochs=2, loss="solver")), plots=False)
    assert np.isfinite(h[-1]["train_loss"])


@pytest.mark.process
def test_data_parallel_training_under_torchrun(tiny, tmp_path):
    import subprocess
    # (torchrun's own module, by this interpreter: its script is where torch was installed, which a
    # venv made with --system-site-packages does not hold, and a venv need not be activated)
    torchrun = [sys.executable, "-m", "torch.distributed.run"]
    out = tmp_path / "ddp"
    r = subprocess.run([*torchrun, "--nproc_per_node", "2", "-m", "deepcontact.cli.main", "train", "--no-plots",
                        str(tiny), "-o", str(out), "--epochs", "2", "--width", "4", "--depth", "2", "--batch-size", "8",
                        "--optimizer", "adam"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stderr.count("best.pt and last.pt written") == 1          # rank 0 alone reports and writes
    ck = load_checkpoint(out / "last.pt")
    assert ck["epoch"] == 1 and len(json.loads((out / "metrics.json").read_text())) == 2


def test_the_training_residual_is_the_solvers_residual(tiny):
    """One residual: the solver loss's (torch) equals the local problem's (numpy) and the native
    solver's, at any impulses, on the same assembly."""
    from deepcontact.grid.dataset import GridDataset
    from deepcontact.solver.local import local_problem, residual
    from deepcontact.solver.methods import judge
    from deepcontact.solver.problem import StepProblem
    ds = GridDataset(tiny)
    loss = losses.SolverLoss(ds)
    rng = np.random.default_rng(3)
    for i in ds.indices()[::7]:
        problem = StepProblem.from_step_file(ds.step_file(int(i)))
        if not problem.points:
            continue
        lp = local_problem(problem)
        mu = problem.contacts["friction"].astype(np.float64)
        normal = rng.uniform(0, 2, problem.points)
        tangent = rng.uniform(-1, 1, problem.points) * mu * normal
        torch_residual = loss.residual(torch.as_tensor(normal), torch.as_tensor(tangent), loss.problem(int(i)))
        numpy_residual = residual(lp, lp.reaction(normal, tangent))
        assert float(torch_residual.abs().max()) == pytest.approx(numpy_residual, rel=1e-9)
        assert judge(problem, normal, tangent).residual == pytest.approx(numpy_residual, rel=1e-3)


def test_no_plots_trains_without_the_loss_plot_and_a_resume_keeps_them_agreeing(dataset, tmp_path):
    """--no-plots: the checkpoints and metrics alone; resuming a run that has a loss plot with
    --no-plots is refused (the plot would no longer match the metrics), and without it the plot
    is redrawn."""
    from conftest import dc
    args = ["--epochs", "1", "--width", "4", "--depth", "2", "-q"]
    r = dc("train", dataset, "--no-plots", *args, "-o", tmp_path / "bare")
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "bare" / "last.pt").exists() and not list((tmp_path / "bare").glob("loss.*"))
    assert dc("train", dataset, *args, "-o", tmp_path / "drawn").returncode == 0
    r = dc("train", dataset, "--resume", "--epochs", "2", "--no-plots", "-q", "-o", tmp_path / "drawn")
    assert r.returncode == 2 and "--no-plots" in r.stderr
    before = (tmp_path / "drawn" / "loss.svg").read_bytes()
    assert dc("train", dataset, "--resume", "--epochs", "2", "-q", "-o", tmp_path / "drawn").returncode == 0
    assert (tmp_path / "drawn" / "loss.svg").read_bytes() != before
