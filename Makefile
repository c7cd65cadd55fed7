# pointforce_ros set-up, tests and demo on a machine without a ROS install.
# `make demo` and `make test` are the two commands of the README; every target is incremental:
# re-running when nothing changed takes seconds.

SHELL := /bin/bash
.SHELLFLAGS := -o pipefail -c
PYTHON ?= python3
VENV := .venv
VPY := $(VENV)/bin/python
PREFIX := $(abspath $(VENV))
STAMP := $(VENV)/.stamps
IFACE_SRC := $(shell find pointforce_interfaces -type f -not -path '*/build/*')
VENDOR_SRC := $(shell find vendor -type f)
PYTEST_ARGS ?=
# Test processes: 2 gives the test files to two pytest-xdist workers whole (the default and
# what CI runs: 26 -> 16 min on a 2-core machine, session 36); 0 runs the suite in this one
# process (easier to read a native crash in; `make test PYTEST_WORKERS=0`).
PYTEST_WORKERS ?= 2

.PHONY: setup deps interfaces install test demo lint lock clean bench

setup: install

$(VPY):
	$(PYTHON) -m venv $(VENV)
	$(VPY) -m pip install --quiet --upgrade pip==26.3 setuptools==84.2.1 wheel 2>&1 | { grep -v '^WARNING: Location' || true; }

# Debian packages the wheels need at run time (Open3D links libusb-1.0).
$(STAMP)/system: | $(VPY)
	@mkdir -p $(STAMP)
	@if ! ldconfig -p | grep -q 'libusb-1.0.so.0'; then \
	  if [ "$$(id -u)" = 0 ]; then \
	    echo '[setup] installing Debian libusb-1.0-0 (Open3D needs it)'; \
	    (apt-get install -y -qq libusb-1.0-0 >/dev/null 2>&1 || \
	     (apt-get update -qq && apt-get install -y -qq libusb-1.0-0)) ; \
	  else \
	    echo '[setup] Open3D needs libusb-1.0.so.0: run "sudo apt-get install libusb-1.0-0"'; exit 1; \
	  fi; \
	fi
	@touch $@

$(STAMP)/deps: requirements.lock | $(VPY)
	@mkdir -p $(STAMP)
	@echo '[setup] installing pinned Python + ROS 2 Jazzy wheels (requirements.lock)'
	$(VPY) -m pip install --quiet -r requirements.lock 2>&1 | { grep -v '^WARNING: Location' || true; }
	$(VPY) -m pip check >/dev/null || ($(VPY) -m pip check; exit 1)
	@touch $@

deps: $(STAMP)/deps $(STAMP)/system

$(STAMP)/interfaces: $(IFACE_SRC) $(STAMP)/deps
	@echo '[setup] building pointforce_interfaces with cmake + rosidl'
	@rm -rf build/pointforce_interfaces && mkdir -p build/pointforce_interfaces
	cd build/pointforce_interfaces && \
	  cmake $(CURDIR)/pointforce_interfaces -DCMAKE_PREFIX_PATH=$(PREFIX) \
	    -DCMAKE_INSTALL_PREFIX=$(PREFIX) -DPython3_EXECUTABLE=$(PREFIX)/bin/python \
	    -DBUILD_TESTING=OFF > cmake.log 2>&1 || (cat cmake.log; exit 1)
	$(MAKE) -C build/pointforce_interfaces -j2 > build/pointforce_interfaces/make.log 2>&1 \
	  || (tail -50 build/pointforce_interfaces/make.log; exit 1)
	$(MAKE) -C build/pointforce_interfaces install > build/pointforce_interfaces/install.log 2>&1 \
	  || (tail -50 build/pointforce_interfaces/install.log; exit 1)
	$(VPY) -c 'from pointforce_interfaces.srv import ContactWrench; from pointforce_interfaces.action import Poke'
	@touch $@

# tf2_msgs/TFMessage (for /tf and /tf_static): no PyPI wheel carries tf2_msgs, so vendor/tf2_msgs
# defines it as upstream does (the same type hash) and is built only where `import tf2_msgs`
# fails; a machine with ROS's own tf2_msgs keeps that one.
$(STAMP)/tf2_msgs: $(VENDOR_SRC) $(STAMP)/deps
	@if $(VPY) -c 'import tf2_msgs.msg' 2>/dev/null && [ ! -f build/tf2_msgs/install.log ]; then \
	  echo '[setup] tf2_msgs found: not building vendor/tf2_msgs'; \
	else \
	  echo '[setup] building vendor/tf2_msgs (TFMessage) with cmake + rosidl'; \
	  rm -rf build/tf2_msgs && mkdir -p build/tf2_msgs && \
	  (cd build/tf2_msgs && cmake $(CURDIR)/vendor/tf2_msgs -DCMAKE_PREFIX_PATH=$(PREFIX) \
	    -DCMAKE_INSTALL_PREFIX=$(PREFIX) -DPython3_EXECUTABLE=$(PREFIX)/bin/python \
	    -DBUILD_TESTING=OFF > cmake.log 2>&1 || (cat cmake.log; exit 1)) && \
	  ($(MAKE) -C build/tf2_msgs -j2 > build/tf2_msgs/make.log 2>&1 \
	    || (tail -50 build/tf2_msgs/make.log; exit 1)) && \
	  ($(MAKE) -C build/tf2_msgs install > build/tf2_msgs/install.log 2>&1 \
	    || (tail -50 build/tf2_msgs/install.log; exit 1)) && \
	  $(VPY) -c 'from tf2_msgs.msg import TFMessage'; \
	fi
	@touch $@

interfaces: $(STAMP)/interfaces $(STAMP)/tf2_msgs

$(STAMP)/install: setup.py setup.cfg package.xml $(wildcard config/*.yaml config/*/*.yaml) $(STAMP)/interfaces $(STAMP)/tf2_msgs $(STAMP)/system
	@echo '[setup] installing pointforce_ros (editable)'
	$(VPY) -m pip install --quiet --no-deps --no-build-isolation -e . 2>&1 | { grep -v '^WARNING: Location' || true; }
	$(VPY) -c 'import pointforce_ros.bringup.cli'
	@echo '[setup] compiling the single-query contact kernels (numba, cached once per machine)'
	$(VPY) -c 'import pointforce_ros.contact.single_pose'
	@touch $@

install: $(STAMP)/install

test: install
	@mkdir -p out
	@rm -f out/.pytest-phase*
	PYTEST_PHASE_FILE=$(abspath out/.pytest-phase) $(VPY) -m pytest -n $(PYTEST_WORKERS) \
	  --dist loadfile $(PYTEST_ARGS) || { rc=$$?; \
	  if [ $$rc -gt 128 ]; then echo "[test] pytest was killed by signal $$((rc - 128)) in:" \
	    "$$(cat out/.pytest-phase* 2>/dev/null || echo 'no test yet')"; fi; exit $$rc; }

demo: install
	$(VENV)/bin/pointforce demo

bench: install
	$(VENV)/bin/pointforce bench all --json

lint: install
	$(VPY) -m pytest test/test_lint.py

lock:
	$(VPY) tools/make_lock.py > requirements.lock

clean:
	rm -rf build $(VENV) *.egg-info
