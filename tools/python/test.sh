#!/usr/bin/env bash
# The Python package's tests, as a new user would meet the package: a fresh virtual environment,
# `pip install ./tools/python`, pytest. Run after `cargo test` (the README's test command does): the
# wheel is built in the dev profile, so it reuses that build instead of compiling everything in
# release. Needs python3 with venv and pip, and PyPI for maturin, numpy and pytest, and the archive
# extra's dask[distributed], pyarrow, fsspec and matplotlib.
set -euo pipefail
cd "$(dirname "$0")/../.."
venv="$(realpath -m "${ASBUILT_VENV:-target/python-venv}")"
python3 -m venv --clear "$venv"
export MATURIN_PEP517_ARGS="${MATURIN_PEP517_ARGS:---profile dev}"
"$venv/bin/pip" install --quiet --disable-pip-version-check "./tools/python[test,archive]"
cd tools/python
exec "$venv/bin/pytest" -q tests "$@"
