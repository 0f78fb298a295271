# The README's two commands:
#   make demo   -- run the demo, writing to outputs/demo
#   make test   -- run the test suite, one pytest-xdist worker per core, a test file on one
#                  worker (its module fixtures built once); extra pytest
#                  arguments via make test PYTEST_ARGS="-m 'not slow' -x"
# Both first run `setup` (scripts/setup.sh): venv at .venv, editable install,
# Vulkan for SAPIEN.  setup is cheap when nothing changed.

VENV        := .venv
PYTEST_ARGS ?=

.PHONY: setup demo test

setup:
	bash scripts/setup.sh

demo: setup
	$(VENV)/bin/drem-maniskill demo --out outputs/demo

test: setup
	$(VENV)/bin/python -m pytest -q -n auto --dist loadscope --durations=20 $(PYTEST_ARGS)
