#!/usr/bin/env bash
# Runs every Python test of the repository (files named test_*.py outside .venv/target)
# with the project's interpreter. pytest's exit code 5 ("no tests collected") is a failure
# whenever test files exist: a silently empty run must not pass.
set -euo pipefail
cd "$(dirname "$0")/.."

PYTHON=${PYTHON:-$PWD/.venv/bin/python}
mapfile -t dirs < <(find . \( -path ./.venv -o -path ./target -o -path ./.libtorch -o -path '*/node_modules' -o -path './.git' \) -prune \
  -o -type f -name 'test_*.py' -printf '%h\n' | sort -u)
if [[ ${#dirs[@]} -eq 0 ]]; then
  echo "run-pytest: no Python test files in the repository"
  exit 0
fi
echo "run-pytest: ${dirs[*]}"
set +e
"$PYTHON" -m pytest -q --import-mode=importlib "$@" "${dirs[@]}"
status=$?
set -e
if [[ $status -eq 5 ]]; then
  echo "run-pytest: pytest collected no tests although test files exist" >&2
  exit 1
fi
exit $status
