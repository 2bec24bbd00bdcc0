# make demo   set everything up (.venv, Debian EGL packages when root) and run the main job
# make test   set everything up and run the tests
# make bench  set everything up and run the benchmarks (results/*.json, docs/RESULTS.md)
VENV ?= .venv
STAMP := $(VENV)/.binpick-installed
export MUJOCO_GL ?= egl

.PHONY: demo test bench setup clean

demo: $(STAMP)
	$(VENV)/bin/binpick demo

test: $(STAMP)
	$(VENV)/bin/python -m pytest -q -n 3 --dist worksteal --durations=15  # 3 test processes on 2 cores: the third computes while another waits (Ray, ROS, a peer's timeout); the 15 slowest named

bench: $(STAMP)
	$(VENV)/bin/python benchmarks/env_speed.py
	$(VENV)/bin/python experiments/random_policy.py
	$(VENV)/bin/python benchmarks/gp_cost.py

setup: $(STAMP)

$(STAMP): pyproject.toml scripts/setup.sh
	bash scripts/setup.sh $(VENV)

clean:
	rm -rf $(VENV) $(VENV)-ros2 runs .pytest_cache
