# Two commands for a new user: `make demo` and `make test`. Both build .venv/ first when missing.
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: venv test lint demo bench clean colcon-test

venv: $(STAMP)

$(STAMP): requirements.txt requirements-ros.txt setup.py setup.cfg package.xml
	test -x $(PY) || python3 -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -r requirements.txt
	$(PY) -m pip install --quiet --no-deps -e .
	touch $(STAMP)

# Tests that claim two computations agree exactly (a copy in groups and whole, the node and a corrected
# copy, live and replay) run again under both OpenBLAS kernel families: FMA kernels (Haswell, most users'
# CPUs) round differently at different matrix sizes, so a claim resting on BLAS fails here too, not only
# on someone else's machine.
EQUALITY_TESTS := test/bag/test_replay_stream.py test/ros/test_one_correction.py test/core/test_session.py \
	test/core/test_recording_feed.py test/core/test_detector_parts.py

# The suite runs in TEST_WORKERS pytest-xdist workers (default: one per CPU, at most 4), each with a DDS
# domain of its own (test/helpers/ros_domain.py); TEST_WORKERS=0 runs it in one process.
TEST_WORKERS ?= $(shell n=$$(nproc 2>/dev/null || echo 2); [ $$n -gt 4 ] && n=4; echo $$n)

test: $(STAMP) lint
	ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST $(PY) -m pytest -q -n $(TEST_WORKERS) test
	for kernel in Haswell Sandybridge; do \
	  echo "OPENBLAS_CORETYPE=$$kernel: the equality tests"; \
	  OPENBLAS_CORETYPE=$$kernel ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST $(PY) -m pytest -q -p no:cacheprovider \
	    -n $(TEST_WORKERS) $(EQUALITY_TESTS) || exit 1; \
	done

# ruff over all Python; mypy over the whole package and msg_tools (not test, bench), strict per pyproject.toml.
# Both always run (one report for each); fails if either finds something. A prerequisite of test.
lint: $(STAMP)
	status=0; \
	$(VENV)/bin/ruff check accel_calibration msg_tools test bench || status=1; \
	$(VENV)/bin/mypy accel_calibration msg_tools || status=1; \
	exit $$status

demo: $(STAMP)
	ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST $(PY) -m accel_calibration.ros.demo

bench: $(STAMP)
	for b in bench/bench_*.py; do $(PY) $$b || exit 1; done

clean:
	rm -rf $(VENV) build *.egg-info

# colcon build, then colcon test (the whole suite, ~5 min), as in a ROS 2 workspace: a fresh one in
# build/colcon-ws from this checkout's files, colcon and ament_package from PyPI in their own virtualenv
# (.venv-colcon: requirements.txt + requirements-colcon.txt). COLCON_BUILD_ARGS=--symlink-install for
# that build; COLCON_TEST_ARGS="--pytest-args test/cli/test_cli.py" for a part of the suite.
COLCON_VENV ?= .venv-colcon
COLCON_WS ?= build/colcon-ws
COLCON_STAMP := $(COLCON_VENV)/.installed

$(COLCON_STAMP): requirements.txt requirements-ros.txt requirements-colcon.txt
	test -x $(COLCON_VENV)/bin/python || python3 -m venv $(COLCON_VENV)
	$(COLCON_VENV)/bin/python -m pip install --quiet --upgrade pip
	$(COLCON_VENV)/bin/python -m pip install --quiet -r requirements.txt -r requirements-colcon.txt
	touch $(COLCON_STAMP)

colcon-test: $(COLCON_STAMP)
	rm -rf $(COLCON_WS) && mkdir -p $(COLCON_WS)/src/accel_calibration
	git ls-files -co --exclude-standard | tar -cf - -T - | tar -xf - -C $(COLCON_WS)/src/accel_calibration
	test ! -d ../shared || ln -s $(abspath ../shared) $(COLCON_WS)/src/shared
	cd $(COLCON_WS) && export PATH="$(abspath $(COLCON_VENV))/bin:$$PATH" && \
	colcon build --base-paths src/accel_calibration $(COLCON_BUILD_ARGS) && \
	{ ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST colcon test --base-paths src/accel_calibration \
	    --return-code-on-test-failure $(COLCON_TEST_ARGS); status=$$?; \
	  colcon test-result --verbose; exit $$status; }
