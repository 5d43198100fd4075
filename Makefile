# deepcontact: set-up, demo, tests and benchmarks. `make demo` and `make test` work from a clean
# clone on Debian: they install Box2D (libbox2d-dev), the package and its dependencies as needed.

PYTHON ?= python3
SUDO := $(shell [ "$$(id -u)" = 0 ] || echo sudo)
STAMPS := .stamps
NATIVE := $(wildcard deepcontact/native/*.cpp deepcontact/native/*.hpp)
RUNS ?= runs
# The installed entry point of $(PYTHON), whatever `dc` is first on PATH.
DC := $(PYTHON) -m deepcontact.cli.main

DEBIAN_PACKAGES := libbox2d-dev libeigen3-dev libxml2-dev zlib1g-dev pkg-config libxml2-utils g++ python3-siconos \
	python3-h5py ffmpeg chromium bubblewrap libseccomp2

.PHONY: setup demo test test-quick test-slow test-packaging bench studies stability smoke smoke-pipeline study study-pipeline clean

# Debian packages: Box2D 2.4.1, Eigen (header-only sparse factorizations), libxml2 and zlib (the
# native step-file reader) and pkg-config to build against them, a C++ compiler, xmllint (an
# independent schema validator the tests use), Siconos with h5py for Debian's own python3 (the
# peer solver the tests compare against), ffmpeg (dc render to MP4/WebM) and chromium (the tests
# open the HTML pages in a real headless browser), bubblewrap and libseccomp (each contestant of dc
# evaluate in a sandbox of its own: deepcontact/contest/sandbox.py).
$(STAMPS)/system:
	@mkdir -p $(STAMPS)
	@if ! pkg-config --exists box2d eigen3 libxml-2.0 zlib 2>/dev/null || ! command -v xmllint >/dev/null || ! command -v g++ >/dev/null \
			|| ! command -v ffmpeg >/dev/null || ! command -v chromium >/dev/null || ! command -v bwrap >/dev/null \
			|| ! /usr/bin/python3 -c "import siconos.numerics, h5py" 2>/dev/null; then \
		echo "installing Debian packages: $(DEBIAN_PACKAGES)"; \
		$(SUDO) apt-get update -qq && \
		DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -qq $(DEBIAN_PACKAGES) >/dev/null; \
	fi
	@touch $@

# torch first, pinned to its CPU build (2.13.0+cpu: PyPI's plain 2.13.0 for Linux is the CUDA build,
# gigabytes of CUDA packages; no CUDA build matches +cpu): from the indexes pip is set up with where
# one has it (a local wheel), else from PyTorch's CPU index beside PyPI; never CUDA either way.
# Then what the build needs, pyb2d3 (Box2D v3.1.1's headers and library: the second engine) and the
# peer engines' pinned wheels (pymunk, MuJoCo: --engine pymunk, --engine mujoco), in one pip run.
TORCH := torch==2.13.0+cpu
TORCH_INDEX := https://download.pytorch.org/whl/cpu
# This tree and the trees $(PYTHON)'s editable installs of deepcontact and its studies name (their
# direct_url.json; the current folder left off the path, whose egg-info names none), read as the
# Makefile is read, against what the install's stamp recorded: where they differ (another clone
# installed into the same Python since, this tree copied or moved: an editable install names one
# tree, and this one's `dc` and tests would import the other's code), this tree is installed again.
INSTALLED_TREES = $(PYTHON) -c "import json, os, sys; sys.path[:] = [p for p in sys.path if p not in ('', '.', os.getcwd())]; \
	from importlib.metadata import distribution as d; from pathlib import Path; \
	print(Path.cwd().resolve().as_uri(), *(json.loads(d(n).read_text('direct_url.json') or '{}').get('url') \
	for n in ('deepcontact', 'deepcontact-studies')))"
ifneq ($(shell $(INSTALLED_TREES) 2>/dev/null),$(file < $(STAMPS)/installed-trees))
$(STAMPS)/install: FORCE
endif

.PHONY: FORCE
FORCE:

$(STAMPS)/install: $(STAMPS)/system setup.cfg setup.py pyproject.toml studies/pyproject.toml $(NATIVE)
	$(PYTHON) -m pip install -q $(TORCH) 2>/dev/null || $(PYTHON) -m pip install -q $(TORCH) --extra-index-url $(TORCH_INDEX)
	$(PYTHON) -m pip install -q "setuptools>=64" wheel "pybind11>=2.11" pyb2d3==0.11.1 pymunk==7.3.1 mujoco==4.0.1
	@echo "installing deepcontact: building its native module (about a minute on 2 cores the first time)"
	$(PYTHON) -m pip install -q --no-build-isolation -e ".[test]"
	$(PYTHON) -m pip install -q --no-build-isolation --no-deps -e studies/
	@$(INSTALLED_TREES) > $(STAMPS)/installed-trees
	@touch $@

setup: $(STAMPS)/install


# The main job on the built-in default scene: the thesis pile, simulated, validated and drawn.
demo: setup
	$(DC) simulate pile --overwrite -o $(RUNS)/demo
	$(DC) validate -q $(RUNS)/demo
	$(DC) render $(RUNS)/demo/seed-000000/step-000599.xml --overwrite -q -o $(RUNS)/demo-last-step.png
	$(DC) render $(RUNS)/demo --every 4 --fps 25 --size 480 --overwrite -q -o $(RUNS)/demo.gif
	@echo "demo: 600 steps of the thesis pile (100 circles) in $(RUNS)/demo/seed-000000/, one XML file per step;"
	@echo "      the run's manifest is $(RUNS)/demo/manifest.json. Look at it:"
	@echo "      $(RUNS)/demo-last-step.png (the last step, contacts and impulses) and $(RUNS)/demo.gif (the run)"

# Two test processes, always (not one per core: the same run on any machine); the pipeline group's
# wheel and smoke pipeline run beside them, started once (tests/conftest.py). The 25 slowest tests
# are listed at the end, so that CI's log records where the suite's time goes.
test: setup
	$(PYTHON) -m pytest -q -m "not slow and not packaging" -n 2 --durations=25

# The inner loop: everything but the audits, the studies, the pipeline group and the tests that
# need a process of their own; stops at the first failure (tests/conftest.py marks the groups).
test-quick: setup
	$(PYTHON) -m pytest -q -x -m "not slow and not pipeline and not audit and not process and not study"

test-slow: setup
	$(PYTHON) -m pytest -q -m slow

# The README's pip lines, each in a fresh venv from the package indexes (minutes; needs PyPI).
test-packaging: setup
	$(PYTHON) -m pytest -q -m packaging

bench: setup
	$(PYTHON) benchmarks/bench_startup.py
	$(PYTHON) benchmarks/bench_simulate.py
	$(PYTHON) benchmarks/bench_solver.py
	$(PYTHON) benchmarks/bench_rasterize.py
	$(PYTHON) benchmarks/bench_checking.py
	$(PYTHON) benchmarks/bench_scale.py
	$(PYTHON) benchmarks/bench_render.py
	$(PYTHON) benchmarks/bench_predict.py
	$(PYTHON) benchmarks/bench_engines.py
	$(PYTHON) benchmarks/bench_peers.py
	$(PYTHON) benchmarks/bench_peers.py --orders
	sh benchmarks/bench_loop_scale.sh
	$(PYTHON) benchmarks/bench_bodyspace.py
	$(PYTHON) benchmarks/bench_contest.py
	$(PYTHON) benchmarks/bench_jobs.py
	$(PYTHON) benchmarks/bench_loop_path.py --pieces 1000 --doorbell 5000 --halves 300 --instructions 100 --in-path 2
	$(PYTHON) benchmarks/bench_loop_path.py --runs 2 --calls 2 --pinned 1
	$(PYTHON) benchmarks/bench_charge_lag.py
	$(PYTHON) benchmarks/bench_loop_parts.py
	$(PYTHON) benchmarks/bench_step_price.py
	$(PYTHON) benchmarks/bench_step_price.py --count 10000 --steps 60
	$(PYTHON) benchmarks/bench_step_price.py --glue 5000
	$(PYTHON) benchmarks/bench_equal_time.py
	$(PYTHON) benchmarks/bench_equal_time.py --scene confined --count 625
	$(PYTHON) benchmarks/bench_sweep_order.py
	$(PYTHON) benchmarks/bench_sweep_order.py --scene pile --samples 16
	$(PYTHON) benchmarks/bench_loop_steps.py --methods none,bodyspace,lagged
	$(PYTHON) benchmarks/bench_converged_piles.py
	$(PYTHON) benchmarks/bench_report.py
	$(PYTHON) benchmarks/bench_reference_cache.py

# The measured studies behind docs/results/'s tables that `make study` does not make (minutes each).
studies: setup
	$(DC) study exact --siconos
	$(DC) study exact --scene hard --every 1
	$(DC) study peer
	$(DC) study engines -o $(RUNS)/engines --overwrite
	$(DC) study frontier -o $(RUNS)/frontier --overwrite
	$(DC) study scale --samples 2 --sizes 100,1000

# The whole pipeline on a tiny scene: simulate -> validate -> rasterize -> train -> evaluate.
# The test suite runs smoke-pipeline (tests/test_evaluate.py: test_the_smoke_pipeline).
SMOKE ?= $(RUNS)/smoke
smoke: setup
	$(MAKE) --no-print-directory smoke-pipeline

smoke-pipeline:
	$(DC) simulate pile --param count=30 --param box=16 --param sigma=4 --steps 120 --seeds 0..1 \
		--skip-contactless -q --overwrite -o $(SMOKE)/run
	$(DC) validate -q $(SMOKE)/run
	$(DC) validate --replay -q $(SMOKE)/run
	$(DC) rasterize $(SMOKE)/run -o $(SMOKE)/data --validation 0.5 -q --overwrite
	$(DC) train $(SMOKE)/data -o $(SMOKE)/model --epochs 1 --width 4 --depth 2 --batch-size 32 --optimizer adam \
		-q --overwrite
	$(DC) evaluate $(SMOKE)/run --starts zero,builtin,copy,sph,cnn,guarded --checkpoint $(SMOKE)/model/best.pt \
		--every 10 -q --overwrite -o $(SMOKE)/report
	@echo "smoke: report in $(SMOKE)/report/report.md"

# The thesis-scale study: 150 pile simulations, the grid dataset, the network, and every start
# evaluated on held-out simulations, plus the thesis's figures 5.4-5.7. File targets: `make -j2`
# runs independent steps together, and an interrupted study resumes where it stopped (the
# manifest and dataset are written last, training resumes from last.pt).
STUDY ?= $(RUNS)/study
STUDY_EPOCHS ?= 30
study: setup
	$(MAKE) --no-print-directory study-pipeline

study-pipeline: $(STUDY)/report/report.md $(STUDY)/figures/figures.md

$(STUDY)/run/manifest.json:
	$(DC) simulate pile --seeds 0..149 -j 2 -q --overwrite -o $(STUDY)/run

$(STUDY)/heldout/manifest.json:
	$(DC) simulate pile --seeds 1000..1001 -q --overwrite -o $(STUDY)/heldout

$(STUDY)/data/metadata.json: $(STUDY)/run/manifest.json
	$(DC) rasterize $(STUDY)/run -o $(STUDY)/data -j 2 -q --overwrite

$(STUDY)/model/done: $(STUDY)/data/metadata.json
	if [ -f $(STUDY)/model/last.pt ]; then $(DC) train $(STUDY)/data -o $(STUDY)/model --resume; \
	else $(DC) train $(STUDY)/data -o $(STUDY)/model --epochs $(STUDY_EPOCHS) --patience 5 --optimizer adam; fi
	touch $@

$(STUDY)/report/report.md: $(STUDY)/model/done $(STUDY)/heldout/manifest.json
	$(DC) evaluate $(STUDY)/heldout --starts zero,builtin,copy,copy2,copy0,sph,cnn,random,bad,guarded,cnn-new \
		--checkpoint $(STUDY)/model/best.pt --stop-on thesis --tolerance 1e-4 --max-iterations 1000 --every 5 \
		--overwrite -o $(STUDY)/report

$(STUDY)/figures/figures.md: $(STUDY)/heldout/manifest.json
	$(DC) study figures $(STUDY)/heldout -o $(STUDY)/figures --stop-on thesis --every 10 --overwrite

# The hard-scene stability table of the README (about a minute).
stability: setup
	$(DC) study stability -o $(RUNS)/stability.md --overwrite

clean:
	rm -rf $(STAMPS) build *.egg-info deepcontact/*.so $(RUNS)/demo $(RUNS)/demo-last-step.png $(RUNS)/demo.gif
