#!/usr/bin/env bash
# The Python package's tests on a machine with only Rust and Python ≥ 3.9 + pip: a fresh
# virtualenv, `pip install ./crates/epd-py pytest numpy rosbags` (pip fetches maturin from PyPI,
# which builds the extension in the release profile), the `epd` binary the tests compare
# against (release: it reuses the wheel's compiled crates), then pytest. `rosbags` writes
# the ROS 2 bags of test_bags.py (a bag writer this project did not write); `plyfile`
# reads `--export-fit`'s PLY in test_profile.py (a reader it did not write).
#
#   .ci/python-tests.sh [PYTEST ARGS…]
#
# Environment: PYTHON (default python3), EPD_PY_VENV (default <target dir>/python-venv,
# recreated on every run).
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON=${PYTHON:-python3}
target=$(cargo metadata --format-version 1 --no-deps |
  "$PYTHON" -c 'import json, sys; print(json.load(sys.stdin)["target_directory"])')
venv=${EPD_PY_VENV:-$target/python-venv}
echo "== python venv $venv ($("$PYTHON" --version))"
"$PYTHON" -m venv --clear "$venv"
echo "== pip install ./crates/epd-py pytest numpy rosbags plyfile"
"$venv/bin/python" -m pip install --quiet --disable-pip-version-check ./crates/epd-py pytest numpy rosbags plyfile
echo "== cargo build --release -p epd-cli --bin epd (the tests compare against it)"
cargo build --release -p epd-cli --bin epd
export EPD_BIN="$target/release/epd"
echo "== pytest crates/epd-py/tests"
# From the tests' folder: `import epd` finds the installed package, not a source folder.
cd crates/epd-py/tests
"$venv/bin/python" -c 'import epd; print("epd", epd.__version__, "from", epd.__file__)'
exec "$venv/bin/python" -m pytest -q -p no:cacheprovider "$@" .
