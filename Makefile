# One-command set-up and jobs. `make check`: set up and run the CI gate;
# `make test`: set up and run the tests (what .ci/run runs).
PY ?= python3
VENV ?= .venv
BIN = $(VENV)/bin

.PHONY: setup check test test-slow bench clean

setup: $(VENV)/.installed

$(VENV)/.installed: pyproject.toml
	$(PY) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q -e '.[test]'
	@# Mitsuba's llvm_ad_rgb variant needs libLLVM >= 16 (Debian: libllvm19); without it
	@# mcverify falls back to scalar_rgb with a notice, so a failure here is not fatal.
	@if command -v apt-get >/dev/null 2>&1 && [ "$$(id -u)" = 0 ] && ! ls /lib/x86_64-linux-gnu/libLLVM.so.19* >/dev/null 2>&1; then \
	  (apt-get install -y -q libllvm19 >/dev/null 2>&1 || (apt-get update -q >/dev/null 2>&1 && apt-get install -y -q libllvm19 >/dev/null 2>&1)) \
	  || echo "notice: could not install libllvm19; Mitsuba will use scalar_rgb"; fi
	touch $@

check: setup
	$(BIN)/mcverify check

test: setup
	$(BIN)/python -m pytest -m "not slow" -q

test-slow: setup
	$(BIN)/python -m pytest -m slow -q -s

clean:
	rm -rf $(VENV) .pytest_cache .hypothesis build *.egg-info

bench: setup
	$(BIN)/python -m pytest benchmarks -q -o python_files="bench_*.py" --benchmark-only \
	  --benchmark-columns=min,median,rounds --benchmark-group-by=group $(BENCH_ARGS)
