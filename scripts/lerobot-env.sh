#!/usr/bin/env bash
# LeRobot's own environment, apart from the project's .venv (lerobot pins a torch the
# project does not use), for the scripts that check compatibility with LeRobot itself:
# python_client/tests/lerobot/write_fixture.py writes the committed LeRobot fixture.
# Not part of `make test`: the tests read the committed fixture with pyarrow.
set -euo pipefail
cd "$(dirname "$0")/.."
VENV=${VENV:-.venv-lerobot}
LEROBOT=${LEROBOT:-lerobot==0.4.4}
[[ -x $VENV/bin/python ]] || python3 -m venv "$VENV"
"$VENV/bin/pip" install --quiet "$LEROBOT"
echo "lerobot-env: $("$VENV/bin/python" -c 'import lerobot; print(lerobot.__version__)') in $VENV"
