# Two entry points (see README): `make demo` runs the main job, `make test` runs the suite.
# Each sets up what it needs first: Debian packages (when run as root) and a virtual environment.
PY := .venv/bin/python
STAMP := .venv/.installed

.PHONY: demo up test lint setup
setup: $(STAMP)

$(STAMP): pyproject.toml .ci/setup
	bash .ci/setup
	touch $(STAMP)

demo: $(STAMP)
	.venv/bin/eca demo

up: $(STAMP)
	.venv/bin/eca up

test: $(STAMP)
	$(PY) -m ruff check .
	$(PY) -m mypy eca/agent eca/protocol
	$(PY) -m pytest -n 2 -q

lint: $(STAMP)
	$(PY) -m ruff check .
	$(PY) -m mypy eca/agent eca/protocol
