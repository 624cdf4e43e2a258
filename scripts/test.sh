#!/usr/bin/env bash
# The tests (the README's test command): the Rust workspace, then the Python package, tested with
# pytest against the same data.
#
#   scripts/test.sh             # everything
#   scripts/test.sh --python    # only the Python package (after a cargo test)
#
# The extension module is the one `cargo build --workspace --all-targets` makes (the workspace's
# features, so nothing that `cargo test` built is built again); it is put beside the package's
# Python sources, as `maturin develop` would, and pytest runs from a virtual environment
# (target/pyenv) with numpy, pytest and dask.distributed. Users build wheels with maturin
# (docs/python.md).
set -euo pipefail
cd "$(dirname "$0")/.."
if [ "${1:-}" != "--python" ]; then
  cargo test --workspace
fi
cargo build --quiet --workspace --all-targets
cp target/debug/lib_handheld.so crates/python/python/handheld/_handheld.abi3.so
env=$PWD/target/pyenv
if [ ! -x "$env/bin/python" ]; then
  "${PYTHON:-python3}" -m venv "$env"
fi
"$env/bin/python" -m pip install --quiet --disable-pip-version-check pytest numpy dask distributed
PYTHONPATH="$PWD/crates/python/python${PYTHONPATH:+:$PYTHONPATH}" "$env/bin/python" -m pytest -q -p no:cacheprovider crates/python/tests
