# Set-up is two commands: `make demo` and `make test`. Both create .venv on a fresh machine.
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
DEMO_OUT ?= demo_out

.PHONY: install demo test lint bench clean

$(STAMP): pyproject.toml Makefile
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	# torch is pinned exactly: the CPU wheel is cached on these machines; a range would pull CUDA wheels.
	$(PY) -m pip install --quiet "torch==2.13.0"
	# oidn: the tests exercise the optional denoiser too (the runtime imports and renders without it).
	$(PY) -m pip install --quiet -e ".[train,test,oidn,view,browser-test,formats]"
	# The viewer's browser test drives Debian's chromium (never a downloaded browser); skipped where absent.
	@if [ ! -x /usr/bin/chromium ] || [ ! -x /usr/bin/chromedriver ]; then \
	  if command -v apt-get >/dev/null 2>&1 && [ "$$(id -u)" = 0 ]; then \
	    (apt-get update -qq && apt-get install -y -qq chromium chromium-driver >/dev/null) \
	      || echo "chromium not installed: the viewer's browser test will be skipped"; \
	  else echo "no apt-get or not root: chromium not installed, the viewer's browser test will be skipped"; fi; \
	fi
	touch $(STAMP)

install: $(STAMP)

# Trace, train, export, render (neural, photon map, path-traced reference) and compare: ~3-5 min on 2 cores.
# demo_out/ is this target's own folder: each `make demo` replaces the previous one (--force).
demo: $(STAMP)
	$(VENV)/bin/pfn-demo --scene vortex --out $(DEMO_OUT) --force
	@echo "demo outputs: $(DEMO_OUT)/ (comparison.png, summary.txt, neural.exr/.png, run/field.pfn, run/loss.png)"

# Two pytest workers (pytest-xdist), one file each at a time: the suite is bound by numba's cold compiles, which
# are single-threaded, so two workers use both cores of a CI machine where one pytest left one idle.
test: $(STAMP)
	$(PY) -m ruff check api runtime train models_spec tests bench
	$(PY) -m pytest -q -n 2 --dist loadfile

bench: $(STAMP)
	$(PY) bench/bench_tracking.py
	$(PY) bench/bench_pathtracer.py
	$(PY) bench/bench_photons.py
	$(PY) bench/bench_knn.py
	$(PY) bench/bench_hashgrid.py
	$(PY) bench/bench_runtime_hashgrid.py
	$(PY) bench/bench_field.py
	$(PY) bench/bench_render.py
	$(PY) bench/bench_training.py
	$(PY) bench/bench_targets.py

clean:
	rm -rf $(VENV) $(DEMO_OUT) .pytest_cache
