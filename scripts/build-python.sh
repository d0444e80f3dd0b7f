#!/usr/bin/env bash
# Builds the Python extension `ciflow._native` (python_client/) and installs the `ciflow`
# package into .venv. Uses $CARGO_TARGET_DIR (the Makefile's) so nothing is compiled twice,
# and skips in well under a second when no input changed since the last install.
set -euo pipefail
cd "$(dirname "$0")/.."

VENV=${VENV:-.venv}
PYTHON=$VENV/bin/python
STAMP=$VENV/.ciflow-python-stamp
export CARGO_TARGET_DIR=${CARGO_TARGET_DIR:-$PWD/target}

# Everything the extension is built from: its crate, the crates it links, the lock file.
inputs=(python_client bridge envs engine/src engine/Cargo.toml Cargo.toml Cargo.lock)
if [[ -f $STAMP ]] && "$PYTHON" -c 'import ciflow._native' 2>/dev/null \
  && [[ -z $(find "${inputs[@]}" -newer "$STAMP" -type f \
            -not -path '*/__pycache__/*' -not -path '*/.pytest_cache/*' -print -quit) ]]; then
  exit 0
fi

wheels=$CARGO_TARGET_DIR/wheels
rm -rf "$wheels"
echo "build-python: building the ciflow extension (release)"
touch "$STAMP.new"
VIRTUAL_ENV=$PWD/$VENV "$VENV/bin/maturin" build --release --quiet \
  --manifest-path python_client/Cargo.toml --interpreter "$PYTHON" --out "$wheels"
"$PYTHON" -m pip install --quiet --force-reinstall --no-deps "$wheels"/ciflow-*.whl
mv "$STAMP.new" "$STAMP"
echo "build-python: ciflow installed into $VENV"
