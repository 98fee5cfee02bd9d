# Every target bootstraps .venv (stdlib venv) when it is missing or older than pyproject.toml.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: demo test bench lint recordings model mutation clean clean-cache aot

# PYTHONWARNINGS: setuptools' "Editable installation" notice is information, not a warning about this project
# $(PIP): the venv, installed when pyproject.toml changed. $(STAMP): that, and the kernels below fresh:
# every target that runs the commands (demo, test, bench, recordings, model, and `make .venv/.installed`
# itself) rebuilds stale kernels; when fresh, that is make's look at file times. `lint` needs only $(PIP).
PIP := $(VENV)/.pip
$(PIP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	PYTHONWARNINGS="ignore:Editable installation" $(BIN)/python -m pip install --quiet -e '.[dev]'
	touch $(PIP)
$(STAMP): $(PIP) evstream/_aot.json
	touch $(STAMP)

# The everyday commands' kernels compiled ahead of time for this machine (evstream/aot.py): they start without
# numba. Rebuilt when any source file changed (an edit or a `git pull` sets the old module aside: numba
# compiles instead, right but slower to start).
# Not fatal: without a C compiler the kernels compile with numba at first use, as before.
# After it (| .numba-cache), numba's cache is emptied when a source changed: the build runs the commands under
# numba, whose cached kernels would otherwise miss an edit to a helper they inlined (after a `git pull` the
# stale ones crashed the build with a segmentation fault).
SOURCES := $(shell find evstream sources sinks -name '*.py' -not -path '*/__pycache__/*')
BUILD_AOT = $(BIN)/python -m evstream.aot || echo "evstream.aot failed: numba will compile the kernels at first use"
aot: evstream/_aot.json
evstream/_aot.json: $(SOURCES) pyproject.toml | $(PIP) $(VENV)/.numba-cache
	$(BUILD_AOT)

demo: $(STAMP)
	$(BIN)/evstream replay recordings/turntable.npz --framer fw --save out/turntable.rrd

test: $(STAMP) aot $(VENV)/.numba-cache
	$(BIN)/python -m pytest -q

# numba keys a cached kernel on its own file only: after an edit to a helper it inlines from another file the
# old kernel would still run, so the tests start from an empty cache whenever a source file changed.
$(VENV)/.numba-cache: $(SOURCES)
	$(MAKE) --no-print-directory clean-cache
	touch $@

# Mutation testing (docs/testing.md), not part of CI: hours for all modules on 2 cores.
# `make mutation MODULES="testing codecs"` for some; scores and survivors under out/mutation/.
MODULES ?=
mutation: $(STAMP)
	$(BIN)/python -m pip install --quiet -e '.[mutation]'
	$(BIN)/python tests/mutation.py $(MODULES)

bench: $(STAMP)
	$(BIN)/python -m benchmarks

lint: $(PIP)
	$(BIN)/ruff check evstream sources sinks tests benchmarks examples

# The shipped synthetic recordings (deterministic: same seeds, same files).
recordings: $(STAMP)
	$(BIN)/evstream synth turntable recordings/turntable.npz --duration-ms 1000 --noise-ratio 0.5 --seed 1
	$(BIN)/evstream synth ball recordings/ball.npz --duration-ms 1000 --noise-ratio 0.5 --seed 2
	$(BIN)/evstream synth bar recordings/bar.npz --duration-ms 500 --noise-ratio 0.5 --seed 3

# The shipped learned model (docs/learned.md): the synthetic scenes and the MIT-licensed real recordings
# only (no GPL or share-alike data in the weights); seeded, so the same bytes each time. --thin: their
# signal thinned to 30/10/3 % (sparser scenes) sets the operating point, so that the threshold transfers
# to sensors unlike them; the weights are fitted on the recordings as they are and (--time-scale 2) on
# their copies twice as slow, which ranks better on slow, sparse scenes (DVS Gesture).
# --without: the DC features stay out of the score (trained on this data they cost the transfer to
# unseen sensors, docs/learned.md); the stage's DC hot-pixel rule still uses them.
REAL ?= $(or $(EVSTREAM_REAL_DATA),../shared/data/real)
model: $(STAMP)
	$(BIN)/evstream train recordings/turntable.npz recordings/ball.npz recordings/bar.npz \
	    $(REAL)/davis346_frames_imu_evlib.aedat4 $(REAL)/prophesee_gen3_vga_evt2_faery.raw \
	    --thin 0.3,0.1,0.03 --time-scale 2 --without dc_own,dc_nb8 --seed 0 --out evstream/denoise/learned/default_model.npz

clean: clean-cache
	rm -rf $(VENV) out .pytest_cache evstream/_aot.* evstream/.aot-build-*

# numba's compiled kernels (its cache misses edits to a helper another module's kernel inlined)
clean-cache:
	find . -path ./$(VENV) -prune -o \( -name '*.nbi' -o -name '*.nbc' \) -exec rm -f {} +
