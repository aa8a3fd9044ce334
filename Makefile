# The whole setup on a fresh machine: `make demo` and `make test` (see README.md).
VENV   ?= .venv
PYTHON ?= python3
PY      = $(VENV)/bin/python
# Extras of pyproject.toml installed: dev (tests, lint) for everyone; add cluster for the Ray executor
# (`make install EXTRAS=dev,cluster`; its tests skip without it).
EXTRAS ?= dev
STAMP   = $(VENV)/.installed.$(subst $(comma),-,$(EXTRAS))
comma  := ,
export MUJOCO_GL ?= egl

.PHONY: install system-deps hw-deps demo demo-cameras test lint format docs docs-figures bench clean

# Headless MuJoCo rendering needs EGL + Mesa; installed from Debian only when missing.
system-deps:
	@if ! ldconfig -p | grep -q 'libEGL.so.1'; then \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
	    apt-get update -qq && apt-get install -y -qq libegl1 libgl1-mesa-dri libegl-mesa0 >/dev/null; \
	  else echo "warning: libEGL not found; install libegl1 libgl1-mesa-dri for depth rendering"; fi; \
	fi

# ROS 1 from Debian 12 for the hardware bridge only (docs/hardware.md): rospy, roscore, the
# sensor_msgs/std_msgs Python messages, genpy (generates kinova_msgs/JointVelocity at run time), rosbag (replay).
# The core project installs and tests without it; tests/hardware skips when it is missing.
HW_DEBS = python3-rospy python3-rosmaster python3-roslaunch python3-rostopic python3-rosbag python3-sensor-msgs \
          python3-std-msgs python3-genpy python3-genmsg
hw-deps:
	@if dpkg -s $(HW_DEBS) >/dev/null 2>&1 && command -v roscore >/dev/null; then \
	  echo "hw-deps: ROS 1 packages already installed"; \
	elif [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
	  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends $(HW_DEBS) >/dev/null; \
	else \
	  echo "hw-deps: needs root and apt-get (Debian 12): apt-get install $(HW_DEBS)" >&2; exit 1; \
	fi

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e ".[$(EXTRAS)]"
	touch $(STAMP)

# The numba kernels compiled once, cached beside their sources (__pycache__), so that no run and
# no test pays the ~50 s cold compile: a 0.3 s run of every method with one and two depth cameras
# (dynamic simulation, decoupled drive). Redone when a kernel's source changes.
KERNELS    = $(VENV)/.kernels
KERNEL_SRC := $(shell grep -rl --include='*.py' 'cache=True' robots tpik qp_baseline compare)
KERNEL_RUN = $(VENV)/bin/tpik-compare run --duration 0.3 --no-plots --quiet --overwrite \
             -m tpik -m tpik-paper -m hqp-daqp -m mink -m mink-hard --out $(VENV)/kernel-warmup

$(KERNELS): $(STAMP) $(KERNEL_SRC)
	@echo "compiling the numba kernels (once, ~1 min)"
	$(KERNEL_RUN) configs/case1_two_cameras.toml >/dev/null
	$(KERNEL_RUN) configs/case1.toml >/dev/null
	rm -rf $(VENV)/kernel-warmup
	touch $@

install: system-deps $(STAMP) $(KERNELS)

# The paper's two case studies with TPIK, HQP (DAQP) and mink, depth sensing, plots (~3 min).
# --overwrite: the demo regenerates its results on purpose (without it a second run is refused).
demo: install
	$(VENV)/bin/tpik-compare run configs/case1.toml --out results/case1 --overwrite
	$(VENV)/bin/tpik-compare run configs/case2.toml --out results/case2 --overwrite
	@echo "replay the case studies headless (video ~1 min each, docs/replay.md):"
	@echo "  $(VENV)/bin/tpik-compare replay results/case1 --video results/case1.mp4 --rerun results/case1.rrd"
	@echo "  $(VENV)/bin/tpik-compare replay results/case2 --video results/case2.mp4 --rerun results/case2.rrd"
	@echo "  open a recording with: $(VENV)/bin/rerun results/case2.rrd"

# The same two case studies seen by two depth cameras, fused (docs/sensing.md); reruns regenerate them.
demo-cameras: install
	$(VENV)/bin/tpik-compare run configs/case1_two_cameras.toml --out results/case1_two_cameras --overwrite
	$(VENV)/bin/tpik-compare run configs/case2_two_cameras.toml --out results/case2_two_cameras --overwrite

# mypy checks the packages listed in pyproject.toml ([tool.mypy] files): robots, tpik, qp_baseline.
lint: install
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .
	$(VENV)/bin/mypy
	$(VENV)/bin/lint-imports  # the layers of [tool.importlinter] in pyproject.toml: no circle, no upward import

format: install
	$(VENV)/bin/ruff check --fix .
	$(VENV)/bin/ruff format .

# The real-time ROS runs go last and alone: their timing (and so what they check) must not
# depend on how many other tests share the cores with them.
test: lint
	$(VENV)/bin/pytest -m "not realtime"
	$(VENV)/bin/pytest -m realtime -n 0

# docs/config.md from the config models (tests/compare/test_config_doc.py fails when it is stale).
docs: install
	$(PY) -m compare.config_doc

# The result tables of README.md and docs/ between <!-- figures:NAME --> markers, from the results files
# committed in docs/ (tests/test_readme_figures.py fails when one is stale).
docs-figures: install
	$(PY) -m compare.analysis.readme_figures

bench: install
	$(VENV)/bin/tpik-compare bench

clean:
	rm -rf $(VENV) results .pytest_cache .ruff_cache .mypy_cache
