# The two commands a newcomer needs: `make demo` and `make test`.
# Each creates .venv when missing and installs drivecal into it first.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
DOCS_STAMP := $(VENV)/.installed-docs

.PHONY: demo test test-long docs bench install browser clean

$(STAMP): pyproject.toml constraints.txt
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet -c constraints.txt -e '.[dev]'
	touch $(STAMP)

install: $(STAMP)

# The HTML report's browser test needs headless Chromium and its driver (Debian
# packages chromium, chromium-driver). Installed when missing and possible
# (root, or password-less sudo); otherwise the test skips and says why.
browser:
	@if command -v chromium >/dev/null 2>&1 && command -v chromedriver >/dev/null 2>&1; then \
		: ; \
	elif ! command -v apt-get >/dev/null 2>&1; then \
		echo "note: no chromium/chromedriver and no apt-get: the browser test will be skipped"; \
	elif [ "$$(id -u)" = 0 ]; then \
		apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium chromium-driver; \
	elif command -v sudo >/dev/null 2>&1 && sudo -n true 2>/dev/null; then \
		sudo apt-get update -qq && sudo DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium chromium-driver; \
	else \
		echo "note: chromium/chromedriver missing and no root or sudo: the browser test will be skipped"; \
	fi

demo: $(STAMP)
	$(BIN)/drivecal demo --out demo-output

test: $(STAMP) browser
	$(BIN)/python -m pytest -q -n 2 --dist loadfile -m "not long"

# The tests marked `long` (about 3 min or more each on 2 cores; ~105 min of the two workers' time): the corpus
# end to end, the SyRM's and the PM-SyRM's default selections and plans, the saturating and dead-time
# coverage, the backward step on a PWM bench, the bench-effects page's examples.
test-long: $(STAMP)
	$(BIN)/python -m pytest -q -n 2 --dist loadfile -m long

# The manual (mkdocs.yml, docs/) as a website in site/: the docs extra installed into .venv first.
# --strict: a broken link or anchor, or a docstring the API reference cannot render, fails the build.
$(DOCS_STAMP): $(STAMP)
	$(BIN)/python -m pip install --quiet -c constraints.txt -e '.[dev,docs]'
	touch $(DOCS_STAMP)

docs: $(DOCS_STAMP)
	$(BIN)/mkdocs build --strict --site-dir site

bench: $(STAMP)
	$(BIN)/python benchmarks/bench_core.py

clean:
	rm -rf $(VENV) demo-output site .pytest_cache
