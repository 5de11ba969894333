# Set-up and the two commands the README promises.
#   make demo   - create .venv (CPU torch from the local wheel) and run `mamma-kit demo`
#   make test   - create .venv if needed and run the test suite
PY ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
# The CPU wheel of torch 2.13.0 lies on this machine's disk; any other request pulls a CUDA build.
# (torch goes in first, so the extras, ray among them, find it installed and pull no other.)
TORCH_SPEC ?= torch==2.13.0
DEMO_OUT ?= demo-out

.PHONY: env demo test browser viewer clean

env: $(VENV)/.installed viewer

$(VENV)/.installed: pyproject.toml constraints.txt
	$(PY) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q "$(TORCH_SPEC)"
	$(BIN)/python -m pip install -q -c constraints.txt -e ".[test,smplx,ray]"
	$(BIN)/python -c "import torch; print('torch', torch.__version__)"
	touch $@

demo: env
	$(BIN)/mamma-kit demo --out $(DEMO_OUT)

# The report test opens the HTML in a real headless Chromium (Debian's package); without
# apt-get (or root) that one test is skipped with its reason.
browser:
	@command -v chromium >/dev/null 2>&1 || { command -v apt-get >/dev/null 2>&1 && [ "$$(id -u)" = 0 ] && \
	  (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null) \
	  || echo "chromium not installed: the report's browser test will be skipped"; }

# three.js for the report's 3D view, from the npm registry (package.json, package-lock.json); without
# npm the report says how to get it and the view's browser test is skipped.
viewer: node_modules/.package-lock.json

node_modules/.package-lock.json: package.json package-lock.json
	@if command -v npm >/dev/null 2>&1; then npm ci --no-audit --no-fund --loglevel=error; \
	  else echo "npm not found: the report's 3D view needs three.js (install Node.js, then make viewer)"; fi

test: env browser
	$(BIN)/python -m pytest

clean:
	rm -rf $(VENV) $(DEMO_OUT) .pytest_cache node_modules
