# facesim: `make demo` renders an expression, `make test` runs the tests; both set up
# everything first (Debian packages, a virtual environment, the package).
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
# eSpeak NG's library and voices: `facesim say` and a spec's speech: track (facesim.speech)
APT_PACKAGES := libosmesa6 libegl1 libegl-mesa0 libgl1-mesa-dri libespeak-ng1
# the export tests' outside tools: headless Chromium (three.js plays the GLB), Blender
# with Debian's NumPy (it imports the GLB and plays the point cache) and Node.js (the
# Khronos glTF-Validator, three.js: tests/js, from the npm registry)
TEST_APT_PACKAGES := chromium blender python3-numpy
SUDO := $(shell [ "$$(id -u)" = 0 ] || echo sudo)

.PHONY: setup system-packages test-packages apt demo test bench kernels realism mesh docs clean

system-packages:
	@$(MAKE) --no-print-directory apt PACKAGES="$(APT_PACKAGES)"

# Node.js with npm: Debian's nodejs and npm, unless a Node.js with its own npm is there already
test-packages: system-packages
	@$(MAKE) --no-print-directory apt PACKAGES="$(TEST_APT_PACKAGES) $$(command -v npm >/dev/null || echo nodejs npm)"

apt:
	@missing=""; for p in $(PACKAGES); do dpkg -s $$p >/dev/null 2>&1 || missing="$$missing $$p"; done; \
	if [ -n "$$missing" ]; then \
		echo "installing Debian packages:$$missing"; \
		$(SUDO) apt-get update -qq && DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -qq $$missing; \
	fi

tests/js/node_modules/.installed: tests/js/package.json tests/js/package-lock.json | test-packages
	cd tests/js && npm ci --silent --no-audit --no-fund
	@touch $@

# the packages installed by uv (from PyPI, into the venv, as pip would: the same versions),
# which links them from its cache where pip unpacks every wheel: a fresh clone's setup
# for `make test` took 22.7 s with pip, 9.4 s with uv (2026-12-08, with npm ci); `pip install .`
# works as ever (tests/test_install.py)
$(BIN)/python:
	$(PYTHON) -m venv $(VENV)

$(BIN)/uv: | $(BIN)/python
	$(BIN)/pip install -q uv

INSTALL := $(BIN)/uv pip install -q --python $(BIN)/python

$(BIN)/facesim: pyproject.toml | $(BIN)/uv
	$(INSTALL) -e '.[test]'
	@touch $@

# MediaPipe (for building meshes from photos) is optional and heavy; the tests use it to
# rebuild the default face, so `make test` and `make mesh` install it, in one run with
# the rest, leaving Python to compile the bytecode of what is imported when it first is
# (a fresh clone's `make test` installed twice, compiling all of it: 65 s; then 26 s, and
# the first imports about 8 s more, once)
$(VENV)/.photo: pyproject.toml | $(BIN)/uv
	$(INSTALL) -e '.[test,photo]'
	@touch $@ $(BIN)/facesim

setup: system-packages $(BIN)/facesim

demo: setup
	$(BIN)/facesim render expressions/happy.yaml -o out/happy.mp4 --force
	@echo "open out/happy.mp4"

# OpenBLAS on one thread: two workers on two cores, each with OpenBLAS's spinning threads, took
# 8% longer (tests of the head, the command line and the kernels: 86-87 s against 80 s, side by side)
# and Python's bytecode cached, as a user's machine does (a sandbox that sets
# PYTHONDONTWRITEBYTECODE compiled facesim's source again in each of the suite's hundreds of
# processes: a warm render's imports 0.84 s against 0.67 s)
# (the Python packages and the tests' npm packages installed side by side: one waits on
# the network and the disk while the other unpacks)
test:
	@$(MAKE) --no-print-directory -j2 test-packages $(VENV)/.photo tests/js/node_modules/.installed
	OPENBLAS_NUM_THREADS=1 PYTHONDONTWRITEBYTECODE= $(BIN)/python -m pytest -n 2 --dist loadscope --no-loadscope-reorder --durations=15

bench: setup
	$(BIN)/python scripts/bench.py

# the kernels that ship compiled (facesim/compiled): run after any change to a file with kernels,
# and the capture basis that ships beside them: after any change to facesim/capture/solver.py
# (with the photo extra: a photo's first commands ship compiled too)
kernels: setup $(VENV)/.photo
	$(BIN)/python scripts/build_kernels.py

# facesim's action units against ICT FaceKit's scanned FACS shapes (../shared/ict-facekit)
realism: setup
	$(BIN)/python scripts/realism.py

mesh: system-packages $(VENV)/.photo
	$(BIN)/python scripts/build_face_mesh.py -o meshes/face.obj

THESIS_SPECS := $(addprefix expressions/,$(addsuffix .yaml,happy sad angry fear disgust surprise disgusted_anger happy_surprise))

docs: test-packages $(VENV)/.photo tests/js/node_modules/.installed
	$(BIN)/facesim sheet $(THESIS_SPECS) $(addprefix expressions/,duchenne_smile.yaml blink.yaml look_left.yaml) \
		-o docs/expressions.png --columns 4 --force
	$(BIN)/facesim muscles --plot docs/muscles.png > /dev/null
	$(BIN)/facesim render expressions/sequence.yaml -o docs/sequence.gif --size 256x256 --fps 25 --force
	mkdir -p out
	$(BIN)/python -c "import imageio.v3 as iio; from skimage import data; iio.imwrite('out/astronaut.png', data.astronaut())"
	$(BIN)/facesim mesh from-photo out/astronaut.png -o out/astronaut.obj --force
	# a second face; a spec that fails there gets an empty cell naming the frame, and exit 1
	-$(BIN)/facesim sheet $(THESIS_SPECS) --mesh out/astronaut.obj -o docs/astronaut.png --size 320x320 --force
	rm -rf out/dataset-docs
	$(BIN)/facesim dataset --n 12 --seed 3 --jitter --size 192x192 -o out/dataset-docs --sheet docs/dataset.png
	# your own face: docs/own_face.png and docs/animated_photo.gif (face from-photo, --look photo, --onto)
	$(BIN)/python scripts/own_face_docs.py
	# the face in other tools: three.js and Blender (docs/export.md)
	$(BIN)/python scripts/export_docs.py
	# a face that talks: docs/speech.mp4 (with its sound) and docs/speech.png (docs/speech.md)
	$(BIN)/python scripts/speech_docs.py
	$(BIN)/python scripts/capture_docs.py

clean:
	rm -rf $(VENV) out .pytest_cache tests/js/node_modules
