# Sourced by the bench scripts: the workspace's build directory, its libtorch (the
# `ciflow` binary links it, as the Makefile sets it up) and its Python.
export CARGO_TARGET_DIR=${CARGO_TARGET_DIR:-$PWD/target}
export LIBTORCH=${LIBTORCH:-$PWD/.libtorch} LIBTORCH_CXX11_ABI=1
export LD_LIBRARY_PATH=$LIBTORCH/lib:$LIBTORCH/cuda-lib${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}
PYTHON=${PYTHON:-$PWD/.venv/bin/python}
