# make demo | make test   (as root on a fresh Debian 12; idempotent)
SHELL := /bin/bash
DEMO_ARGS ?=
PYTEST_ARGS ?=
.DEFAULT_GOAL := test
.PHONY: setup test demo clean

setup:
	@bash scripts/bootstrap.sh

test: setup
	@scripts/env.sh python -m pytest test -q -p no:cacheprovider $(PYTEST_ARGS)

demo: setup
	@scripts/env.sh bash scripts/demo.sh "$(DEMO_ARGS)"

clean:
	rm -rf .ws .venv
