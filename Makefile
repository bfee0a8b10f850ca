# Two commands for a newcomer: `make demo` and `make test`. Both set up .venv from scratch.
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: setup demo live-demo test bench lint docs system-deps clean clean-cache

$(STAMP): pyproject.toml
	bash scripts/ensure_system_deps.sh
	test -x $(PY) || python3 -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e ".[dev,peers,ouster]"
	# ouster-sdk's own pins clash with rerun-sdk and typer (see pyproject.toml): no deps
	$(PY) -m pip install --quiet --no-deps "ouster-sdk>=0.15,<2"
	touch $(STAMP)

setup: $(STAMP)

system-deps:
	bash scripts/ensure_system_deps.sh

demo: setup
	$(VENV)/bin/prc-slam demo

# the live tour: a simulated HDL-32E capture (made once) replayed over loopback into `prc-slam live`
LIVE_DIR ?= out/live-demo
LIVE_PORT ?= 2368
live-demo: setup
	test -f $(LIVE_DIR)/capture.pcap || $(VENV)/bin/prc-slam simulate --sensor hdl32 --frames 150 \
		--out $(LIVE_DIR)/sim --pcap $(LIVE_DIR)/capture.pcap
	( sleep 8; $(VENV)/bin/prc-slam replay $(LIVE_DIR)/capture.pcap --to udp://127.0.0.1:$(LIVE_PORT) ) & \
	trap 'kill $$! 2>/dev/null' EXIT; \
	$(VENV)/bin/prc-slam live velodyne://127.0.0.1:$(LIVE_PORT) --timeout 12 --rrd $(LIVE_DIR)/live.rrd \
		--poses-out $(LIVE_DIR)/poses.txt --out $(LIVE_DIR)/filtered.mcap --json $(LIVE_DIR)/live.json
	@echo "live tour written to $(LIVE_DIR): live.rrd (rerun $(LIVE_DIR)/live.rrd), poses.txt, filtered.mcap, live.json"

test: setup
	$(VENV)/bin/pytest -q

bench: setup
	$(VENV)/bin/prc-slam bench --json out/bench.json

# the documentation site (mkdocs.yml), into out/site; `make test` builds it too (tests/docs/test_docs.py)
docs: setup
	NO_MKDOCS_2_WARNING=1 $(VENV)/bin/mkdocs build --strict --site-dir out/site

lint: setup
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .

clean: clean-cache
	rm -rf $(VENV) out .pytest_cache

# numba's on-disk cache does not notice changes in a kernel's callees in other modules
clean-cache:
	find prc_slam data_tools -name '*.nbi' -delete -o -name '*.nbc' -delete
