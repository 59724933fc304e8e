#!/usr/bin/env bash
# The Python package's tests: the package built from this checkout in a fresh
# virtual environment (maturin, dev profile, the checkout's target folder so
# the library is not built twice), then its pytest suite, which compares with
# the CLI. Needs python3 with venv and pip; packages come from PyPI.
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
repo=$(dirname "$here")
export CARGO_TARGET_DIR="${CARGO_TARGET_DIR:-$repo/target}"

venv=$(mktemp -d)
trap 'rm -rf "$venv"' EXIT
python3 -m venv "$venv"
"$venv/bin/pip" install --quiet --disable-pip-version-check maturin pytest pandas numpy "dask[distributed]" scipy pillow

# The CLI the tests compare with.
(cd "$repo" && cargo build --quiet --bin grainforce)
export GRAINFORCE_BIN="$CARGO_TARGET_DIR/debug/grainforce"

# --locked: python/Cargo.lock must already name every crate (no silent
# rewrite of the lock file during a build).
(cd "$here" && VIRTUAL_ENV="$venv" PATH="$venv/bin:$PATH" maturin develop --quiet --locked)
# pytest's status is the script's (5, no tests collected, fails too).
cd "$here" && "$venv/bin/python" -m pytest tests -q
