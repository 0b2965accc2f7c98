# The README's commands. `make run` and `make test` install what is missing first
# (Debian packages, then a virtual environment with the project) and are quick when
# everything is already there.

VENV        := .venv
PY          := $(VENV)/bin/python
CASE        ?= cases/impacting_bar.yaml
PYTEST_ARGS ?=
# pytest-xdist workers: the suite's tests are independent (each writes into its own tmp_path); a module
# marked xdist_group runs in one worker (--dist loadgroup), its module fixtures once
TEST_WORKERS ?= 2
APT_PACKAGES := python3-dolfinx-real python3-petsc4py-real python3-slepc4py-real python3-gmsh \
                python3-meshio python3-h5py python3-scipy python3-matplotlib python3-yaml python3-tqdm python3-numba \
                python3-pytest python3-pytest-xdist python3-hypothesis python3-venv python3-pip python3-setuptools python3-wheel \
                python3-sphinx python3-myst-parser \
                openmpi-bin make libopenblas0-pthread \
                paraview xvfb xauth libegl1 libgl1-mesa-dri

.PHONY: setup system-packages run test test-all benchmark docs figures study-charts clean

# The Numba kernels compiled into their cache once here (quick when it is there), not by each test worker or
# run that reaches them first.
setup: system-packages $(VENV)/.installed
	@$(PY) -m fem_impact.app.warm

system-packages:
	@missing=$$(for p in $(APT_PACKAGES); do dpkg-query -W -f='$${Status}\n' $$p 2>/dev/null | grep -q 'install ok installed' || echo $$p; done); \
	if [ -n "$$missing" ]; then \
	  echo "installing Debian packages:" $$missing; \
	  SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
	  $$SUDO apt-get update -q && $$SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -q $$missing; \
	fi

# The venv sees Debian's dolfinx/PETSc/SLEPc (--system-site-packages); pip adds only the project.
$(VENV)/.installed: pyproject.toml
	/usr/bin/python3 -m venv --system-site-packages $(VENV)
	$(PY) -m pip install -q --no-build-isolation -e .
	touch $@

run: setup
	$(VENV)/bin/fem-impact run $(CASE)

test: setup
	$(PY) -m pytest -m "not slow" -n $(TEST_WORKERS) --dist loadgroup $(PYTEST_ARGS)

test-all: setup
	$(PY) -m pytest -n $(TEST_WORKERS) --dist loadgroup $(PYTEST_ARGS)

benchmark: setup
	$(PY) benchmarks/full_model.py
	$(PY) benchmarks/reduced_model.py
	$(PY) benchmarks/small_friction.py
	$(PY) benchmarks/contact_scale.py --sizes 2 4 8

clean:
	rm -rf $(VENV) results .pytest_cache docs/_build docs/_generated

# The documentation site, from docs/ into docs/_build/html (Sphinx with MyST; the case-file reference is
# generated from the schemas as it builds): warnings are errors (-W, --keep-going to list them all), and
# every cross-reference must resolve (-n).
DOCS_BUILD ?= docs/_build
docs: setup
	$(PY) -m sphinx -W --keep-going -n -q -b html docs $(DOCS_BUILD)/html
	@echo "the site: $(DOCS_BUILD)/html/index.html"

# The pictures of the README and the pages: the default case's contact force and energy budget; the
# vibrodrive's history, frequency sweep (about a minute) and a strike; the rigid hammer's force on its rod.
VIBRODRIVE_FREQUENCIES := 16000,16500,17000,17168.8,17600,18000,18500
figures: setup
	$(VENV)/bin/fem-impact run $(CASE) -q
	$(VENV)/bin/fem-impact plot results/impacting_bar -o docs/impacting_bar.png
	$(VENV)/bin/fem-impact run cases/vibrodrive.yaml -q
	$(PY) tests/test_vibrodrive.py results/vibrodrive --plot docs/vibrodrive_history.png
	$(VENV)/bin/fem-impact sweep cases/vibrodrive.yaml --body slider --vary parameters.f=$(VIBRODRIVE_FREQUENCIES) -q
	cp results/vibrodrive-sweep/sweep.png docs/vibrodrive_sweep.png
	$(VENV)/bin/fem-impact run cases/vibrodrive.yaml -o results/vibrodrive-launch -q \
	    --set solver.t_end=6.4e-4 --set output.every=5
	$(VENV)/bin/fem-impact animate results/vibrodrive-launch --time 5.51e-4 --scale 300 --size 1024x576 \
	    -o docs/vibrodrive.png
	$(VENV)/bin/fem-impact run cases/hammer_rod.yaml -q --set solver.t_end=1.2e-4 --set output.vtk=false
	$(PY) tests/test_mixed.py results/hammer_rod --plot docs/hammer_rod.png
	$(PY) tests/test_surface.py --plot docs/hertz_cylinder.png

# The speed-accuracy charts and stability maps of B2a and the free vibroconverter, redrawn into
# docs/ by the study commands (about 5 minutes on 2 cores; completed levels are reused).
STUDY_CASES := impacting_bar vibroconverter_free
study-charts: setup
	for c in $(STUDY_CASES); do for s in pareto stability; do \
	  $(VENV)/bin/fem-impact study $$s cases/$$c.yaml -o results/$$c-$$s -q && \
	  cp results/$$c-$$s/$$s.png docs/$$c-$$s.png || exit 1; done; done
