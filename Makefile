# forearm_dynamics: `make demo` and `make test` set everything up themselves.
SHELL := /bin/bash
VENV ?= .venv
PY := $(VENV)/bin/python
PYTHON ?= python3
# DDS stays on this machine; each target has its own domain.
export ROS_AUTOMATIC_DISCOVERY_RANGE := LOCALHOST
export HOME ?= /tmp
EXTRAS ?= test,reference,plots

.PHONY: setup browser test test-unit test-hosts test-ros-tools demo demo-closed-loop lint bench bench-estimation bench-rate soak reference muscle-reference reproduce clean

setup: $(VENV)/.installed browser

# The HTML report's test opens it in Debian's chromium (no network needed); CI runs as root.
# A second make test (or the hosts tier's nftables) installing at the same time waits for
# this one (the same flock file as test/hostkit.py), and apt for any other apt's lock.
APT_LOCKED = DEBIAN_FRONTEND=noninteractive flock -w 900 /tmp/forearm_dynamics-apt.lock
APT_WAIT = -o DPkg::Lock::Timeout=600
browser:
	@command -v chromium >/dev/null || { test "$$(id -u)" = 0 && $(APT_LOCKED) sh -c \
	  'apt-get $(APT_WAIT) update -qq && apt-get $(APT_WAIT) install -y -qq chromium >/dev/null'; } || \
	  echo "warning: chromium is missing (test_html_report needs it): apt-get install chromium" >&2

$(VENV)/.installed: setup.py setup.cfg .ci/requirements.lock forearm_dynamics/estimation/_kalman_step.c forearm_dynamics/estimation/_practice_step.c forearm_dynamics/estimation/_kalman_step.h forearm_dynamics/_buffers.h forearm_dynamics/estimation/_noise_step.c forearm_dynamics/estimation/_noise_evaluations.c forearm_dynamics/estimation/_noise_step.h forearm_dynamics/muscles/_muscle_step.c
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --disable-pip-version-check --upgrade "pip==25.3"
	$(PY) -m pip install -q --disable-pip-version-check -c .ci/requirements.lock -e ".[$(EXTRAS)]"
	@touch $@

test: setup
	$(VENV)/bin/ruff check .
	ROS_DOMAIN_ID=71 $(PY) -m pytest -q -m "not hosts and not ros_tools" test

# Two hosts on one machine (network namespaces + a veth pair; root: CI runs as root).
# Installs nftables (apt) when a loss test needs it. docs/two-hosts.md
test-hosts: setup
	ROS_DOMAIN_ID=71 $(PY) -m pytest -q -m hosts test

# The package under the upstream ROS 2 tools (docs/testing.md): colcon build, ros2 launch of
# every launch file, ros2 lifecycle. Needs the installer of the upstream ros2 CLI, which is
# not on PyPI: make test-ros-tools ROS2CLI_INSTALL=<path to its install.sh> (CI passes it).
# It builds a venv of its own (ROS2CLI_VENV, kept for the next run; ~3-15 min to build).
ROS2CLI_INSTALL ?=
ROS2CLI_VENV ?= build/ros2cli-venv
test-ros-tools:
	@test -n "$(ROS2CLI_INSTALL)" || { echo "make test-ros-tools: give ROS2CLI_INSTALL=<the ros2 CLI's install.sh>" >&2; exit 2; }
	@if test -x $(ROS2CLI_VENV)/bin/ros2; then $(ROS2CLI_VENV)/bin/pip install -q --disable-pip-version-check --no-deps -e .; \
	  else $(ROS2CLI_INSTALL) $(ROS2CLI_VENV); fi
	ROS_DOMAIN_ID=76 $(ROS2CLI_VENV)/bin/python -m pytest -q -m ros_tools test/test_ros_tools.py

# the fast tier (docs/testing.md): no processes, no DDS; run it on every change
test-unit: setup
	$(PY) -m pytest -q -m unit test

# Another domain: make demo ROS_DOMAIN_ID=42 (or exported); unset or 0 (everyone's
# default): 73. Held while it runs, moved to the next free one if another run holds it.
DEMO_DOMAIN = $(if $(filter-out 0,$(ROS_DOMAIN_ID)),$(ROS_DOMAIN_ID),73)
demo: setup
	ROS_DOMAIN_ID=$(DEMO_DOMAIN) $(VENV)/bin/demo --out demo_out

# The virtual arm in closed loop (docs/virtual-arm.md): trajectory_publisher + torque_node +
# arm_sim + a computed-torque controller; prints the tracking error, draws
# demo_out/closed_loop/closed_loop.png. CLOSED_LOOP_ARGS="--lockstep" runs it on arm_sim's clock.
# ROS_DOMAIN_ID as for make demo (unset or 0: 74; held, moved on if another run holds it).
CLOSED_LOOP_ARGS ?=
CLOSED_LOOP_DOMAIN = $(if $(filter-out 0,$(ROS_DOMAIN_ID)),$(ROS_DOMAIN_ID),74)
demo-closed-loop: setup
	$(PY) examples/closed_loop.py --movements 1,26,51 --domain $(CLOSED_LOOP_DOMAIN) --out demo_out/closed_loop --plot $(CLOSED_LOOP_ARGS)

lint: setup
	$(VENV)/bin/ruff check .

# benchmarks/ is not part of the installed package: run from the repository root
bench: setup
	ROS_DOMAIN_ID=75 $(PY) -m benchmarks --out benchmarks/results.json
	ROS_DOMAIN_ID=75 $(PY) benchmarks/torque_node_rate.py --out benchmarks/results.json
	ROS_DOMAIN_ID=75 $(PY) -m benchmarks.realtime --out benchmarks/results.json
	$(PY) benchmarks/estimation.py
	$(PY) benchmarks/estimation_zoo.py

# torque_node output_rate_hz 1000 from 100 Hz, and live model changes at 1 kHz (~1 min)
bench-rate: setup
	ROS_DOMAIN_ID=79 $(PY) benchmarks/torque_node_rate.py --out benchmarks/results.json

# The torque path under 0, 1, 2 CPU hogs, normal vs realtime_priority 50 + lock_memory,
# alternating runs; output_rate_hz 1000 jitter (~8 min; docs/realtime.md)
bench-realtime: setup
	ROS_DOMAIN_ID=83 $(PY) -m benchmarks.realtime --out benchmarks/results.json

# 10 min of looping replay at 1 kHz (make soak SOAK_MINUTES=2 for a shorter run)
SOAK_MINUTES ?= 10
soak: setup
	ROS_DOMAIN_ID=77 $(PY) -m benchmarks.soak --minutes $(SOAK_MINUTES) --out benchmarks/soak.json

clean:
	rm -rf $(VENV) build install log .pytest_cache

reference: setup
	$(VENV)/bin/make_reference

# OpenSim's StaticOptimization of 13 library movements with the shipped muscles, and the
# exact-geometry solve (MuJoCo, the muscles-fit extra): the cached muscle reference the tests
# and benchmarks/muscle_node.py compare with (~10-25 min on 2 cores). docs/muscles.md
muscle-reference: setup
	$(PY) -m pip install -q --disable-pip-version-check -e ".[muscles-fit]"
	$(PY) -m forearm_dynamics.cli.make_muscle_reference

reproduce: setup
	$(VENV)/bin/reproduce_paper --out results/paper --docs docs/paper.md --blocks docs/paper-discussion.md

# Offline estimator benchmark (no ROS, a few minutes): the `estimation` key of
# benchmarks/results.json and benchmarks/estimation.png
bench-estimation: setup
	$(PY) benchmarks/estimation.py
	$(PY) benchmarks/estimation_zoo.py
