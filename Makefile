# The two commands of the README. Both set up what is missing first.
SHELL := /bin/bash
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
STAMP := $(VENV)/.installed
OUT := out/demo

.PHONY: demo test setup lint type clean

$(STAMP): pyproject.toml tools/bootstrap.sh
	PYTHON="$(PYTHON)" VENV="$(VENV)" bash tools/bootstrap.sh
	touch $(STAMP)

setup: $(STAMP)

## make demo: build the textured face mesh of the built-in sample and a preview picture
demo: $(STAMP)
	$(VENV)/bin/facemesh build -o $(OUT)/astronaut.glb --preview $(OUT)/astronaut_preview.png
	$(VENV)/bin/facemesh info $(OUT)/astronaut.glb
	$(VENV)/bin/facemesh render $(OUT)/astronaut.glb --yaw 25 --pitch 15 -o $(OUT)/astronaut_yaw25_pitch15.png
	@echo "demo: wrote $(OUT)/astronaut.glb and the pictures beside it"

## make test: the whole tox suite (tests on every installed Python, lint, type)
test: $(STAMP)
	WITH_VALIDATOR=1 PYTHON="$(PYTHON)" VENV="$(VENV)" bash tools/bootstrap.sh
	$(VENV)/bin/tox

clean:
	rm -rf $(VENV) .tox out .tools
