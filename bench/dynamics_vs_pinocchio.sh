#!/usr/bin/env bash
# ciflow's rigid-body dynamics vs Pinocchio's compiled C++, side by side in one run, on
# the Panda URDF: RNEA, CRBA, g(q), C q̇ + g, the Coriolis matrix and forward dynamics
# (Pinocchio's ABA and its CRBA + Cholesky). Both programs first compute every algorithm
# on the same random states and must agree to 1e-9; then they are timed in alternating
# runs and the table gives ns/call and the ratio ciflow / Pinocchio (< 1: ciflow faster).
#
# Pinocchio side: bench/pinocchio/timing.cpp against the headers of the PyPI `pin` wheel
# (site-packages/cmeel.prefix, Eigen from `cmeel-eigen`), all templates instantiated in
# the program itself with PIN_CXXFLAGS (default `-O3 -DNDEBUG`, the flags of Pinocchio's
# own CMake Release benchmarks, plus `-march=$MARCH`). Both sides compile for the same
# CPU: the Rust side is built with `-C target-cpu=$MARCH` (MARCH, default `native`) into
# its own target directory, so the workspace's portable build is left alone. No Pinocchio library is linked, so
# no ABI is mixed; the model comes from Pinocchio's URDF parser via Python
# (bench/pinocchio/compare.py). Compiling those templates takes ~3 CPU-minutes once; the
# binary is kept in $CARGO_TARGET_DIR/pinocchio-bench and rebuilt only when the source,
# the flags or the Pinocchio version change.
#
# Environment: CARGO_TARGET_DIR, PYTHON, CXX, MARCH, PIN_CXXFLAGS, URDF; ROUNDS, BATCH_MS,
# STATES, SEED (see compare.py).
set -euo pipefail
cd "$(dirname "$0")/.."
export CARGO_TARGET_DIR=${CARGO_TARGET_DIR:-$PWD/target}
PYTHON=${PYTHON:-$PWD/.venv/bin/python}
CXX=${CXX:-g++}
MARCH=${MARCH:-native}
PIN_CXXFLAGS=${PIN_CXXFLAGS:--O3 -DNDEBUG -march=$MARCH}
URDF=${URDF:-$PWD/engine/assets/panda.urdf}

prefix=$("$PYTHON" -m cmeel cmake 2>/dev/null)
if [[ ! -f $prefix/include/pinocchio/multibody.hpp || ! -f $prefix/include/eigen3/Eigen/Core ]]; then
  echo "Pinocchio or Eigen headers missing under '$prefix': run scripts/setup-python.sh" >&2
  exit 1
fi
pin_version=$("$PYTHON" -c 'import pinocchio; print(pinocchio.__version__)')

build=$CARGO_TARGET_DIR/pinocchio-bench
pinocchio_bin=$build/pinocchio_timing
# Pinocchio's interface definitions (lib/cmake/pinocchio/pinocchioTargets.cmake).
defines="-DBOOST_MPL_LIMIT_LIST_SIZE=30 -DBOOST_MPL_LIMIT_VECTOR_SIZE=30 -DBOOST_MPL_CFG_NO_PREPROCESSED_HEADERS -DBOOST_FUSION_INVOKE_MAX_ARITY=12"
compile=("$CXX" -std=c++17 $PIN_CXXFLAGS $defines -isystem "$prefix/include" -isystem "$prefix/include/eigen3"
  bench/pinocchio/timing.cpp -o "$pinocchio_bin")
stamp=$( (cat bench/pinocchio/timing.cpp; echo "${compile[*]} $pin_version $("$CXX" --version | head -1)") | sha256sum | cut -d' ' -f1)
mkdir -p "$build"
if [[ ! -x $pinocchio_bin || "$(cat "$build/stamp" 2>/dev/null)" != "$stamp" ]]; then
  echo "== compiling Pinocchio $pin_version's templates ($CXX $PIN_CXXFLAGS; one-off, minutes)"
  # GCC's -Wstringop-overread fires on Eigen's AVX-512 code in joint types unused here.
  "${compile[@]}" 2> "$build/compile.log" || { cat "$build/compile.log" >&2; exit 1; }
  echo "$stamp" > "$build/stamp"
fi
rust_target=$CARGO_TARGET_DIR/cpu-$MARCH
RUSTFLAGS="-C target-cpu=$MARCH" CARGO_TARGET_DIR=$rust_target \
  cargo build --release --quiet -p ciflow-engine --example dynamics_timing

workdir=$(mktemp -d)
trap 'rm -rf "$workdir"' EXIT
echo "== ciflow (Rust, release, -C target-cpu=$MARCH) vs Pinocchio $pin_version ($CXX $PIN_CXXFLAGS) on $(nproc) CPUs: $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs)"
"$PYTHON" bench/pinocchio/compare.py "$URDF" "$rust_target/release/examples/dynamics_timing" "$pinocchio_bin" "$workdir"
