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

## make demo: the pipeline on the built-in sample: mesh, normalized eyes, augmented eye patches, tracking
demo: $(STAMP)
	$(VENV)/bin/facemesh build -o $(OUT)/astronaut.glb --preview $(OUT)/astronaut_preview.png
	$(VENV)/bin/facemesh info $(OUT)/astronaut.glb
	$(VENV)/bin/facemesh render $(OUT)/astronaut.glb --yaw 25 --pitch 15 -o $(OUT)/astronaut_yaw25_pitch15.png
	$(VENV)/bin/gazeaug normalize -o $(OUT)/astronaut_normalized.npz
	$(VENV)/bin/gazeaug render $(OUT)/astronaut.glb --yaw 0 --pitch 30 -o $(OUT)/astronaut_yaw0_pitch30.npz
	$(VENV)/bin/gazeaug preview $(OUT)/astronaut.glb -n 16 -o $(OUT)/astronaut_augmented.png
	$(VENV)/bin/gazeaug simulate --sequence 4 --fps 15 --rig data_samples/rigs/wheelchair_objects.yaml -o $(OUT)/sequence --overwrite --quiet
	$(VENV)/bin/gazeaug track $(OUT)/sequence -o $(OUT)/track --rig data_samples/rigs/wheelchair_objects.yaml --quiet
	@echo "demo: wrote $(OUT)/astronaut.glb, the eye patches (.npz), the pictures beside them, a simulated gaze sequence and $(OUT)/track/overlay.mp4 (the demo model's gaze on it)"

## make test: the whole tox suite (tests on every installed Python, lint, type)
test: $(STAMP)
	WITH_VALIDATOR=1 PYTHON="$(PYTHON)" VENV="$(VENV)" bash tools/bootstrap.sh
	$(VENV)/bin/tox

clean:
	rm -rf $(VENV) .tox out .tools
