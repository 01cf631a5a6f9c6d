# Two commands for a new user: `make demo` and `make test`. Both build .venv/ first when missing.
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: venv test lint demo bench clean

venv: $(STAMP)

$(STAMP): requirements.txt setup.py setup.cfg package.xml
	test -x $(PY) || python3 -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -r requirements.txt
	$(PY) -m pip install --quiet --no-deps -e .
	touch $(STAMP)

# Tests that claim two computations agree exactly (a copy in groups and whole, the node and a corrected
# copy, live and replay) run again under both OpenBLAS kernel families: FMA kernels (Haswell, most users'
# CPUs) round differently at different matrix sizes, so a claim resting on BLAS fails here too, not only
# on someone else's machine.
EQUALITY_TESTS := test/test_replay_stream.py test/test_one_correction.py test/test_session.py \
	test/test_recording_feed.py test/test_detector_parts.py

test: $(STAMP) lint
	ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST $(PY) -m pytest -q test
	for kernel in Haswell Sandybridge; do \
	  echo "OPENBLAS_CORETYPE=$$kernel: the equality tests"; \
	  OPENBLAS_CORETYPE=$$kernel ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST $(PY) -m pytest -q -p no:cacheprovider \
	    $(EQUALITY_TESTS) || exit 1; \
	done

# ruff over all Python; mypy over the ROS-free core, strict per pyproject.toml. Both always run (one
# report for each); fails if either finds something. Not yet a prerequisite of test.
lint: $(STAMP)
	status=0; \
	$(VENV)/bin/ruff check accel_calibration msg_tools test bench || status=1; \
	$(VENV)/bin/mypy accel_calibration/core || status=1; \
	exit $$status

demo: $(STAMP)
	ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST $(PY) -m accel_calibration.ros.demo

bench: $(STAMP)
	for b in bench/bench_*.py; do $(PY) $$b || exit 1; done

clean:
	rm -rf $(VENV) build *.egg-info
