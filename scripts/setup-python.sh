#!/usr/bin/env bash
# Creates the project-local Python environment `.venv` and the libtorch directory that
# tch links against. Idempotent: a second run only checks stamps and exits in well under
# a second.
#
# libtorch comes from the PyTorch 2.13.0 wheel (the version tch 0.26 expects). Its CPU
# library needs libcudart/libcupti to load, so those two small NVIDIA runtime wheels come
# along; the CUDA libraries themselves are never linked (see `.libtorch/lib`).
set -euo pipefail
cd "$(dirname "$0")/.."

VENV=.venv
LIBTORCH_DIR=.libtorch
REQUIREMENTS=scripts/requirements.txt
STAMP=$VENV/.ciflow-stamp

want_stamp="$(sha256sum "$REQUIREMENTS" "$0" | sha256sum | cut -d' ' -f1)"
if [[ -f $STAMP && "$(cat "$STAMP")" == "$want_stamp" && -e $LIBTORCH_DIR/lib/libtorch_cpu.so ]]; then
  exit 0
fi

PYTHON=${PYTHON:-python3}
if [[ ! -x $VENV/bin/python ]]; then
  echo "setup: creating $VENV with $($PYTHON --version)"
  "$PYTHON" -m venv "$VENV"
fi
# No download cache: the torch wheel alone would keep about a gigabyte of a machine's disk
# that the build needs (a CI machine once ran out of space compiling).
pip_install=("$VENV/bin/python" -m pip install -q --no-cache-dir)
"${pip_install[@]}" --upgrade pip
echo "setup: installing Python packages (torch wheel is large; first run takes minutes)"
"${pip_install[@]}" --no-deps torch==2.13.0
"${pip_install[@]}" -r "$REQUIREMENTS"

site=$("$VENV/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')
torch_dir=$site/torch
rm -rf "$LIBTORCH_DIR"
mkdir -p "$LIBTORCH_DIR/lib"
# torch-sys links libtorch_cuda whenever it is present: expose only the CPU libraries.
for lib in libtorch_cpu.so libtorch.so libc10.so libgomp.so.1; do
  src=$(ls "$torch_dir"/lib/$lib 2>/dev/null || ls "$torch_dir"/../torch.libs/${lib%%.so*}*.so* 2>/dev/null | head -1)
  [[ -n $src ]] || { echo "setup: $lib not found in the torch wheel" >&2; exit 1; }
  ln -sf "$(readlink -f "$src")" "$LIBTORCH_DIR/lib/$lib"
done
ln -sfn "$(readlink -f "$torch_dir/include")" "$LIBTORCH_DIR/include"
cuda_lib=$(readlink -f "$site/nvidia/cu13/lib")
[[ -d $cuda_lib ]] || { echo "setup: $site/nvidia/cu13/lib missing" >&2; exit 1; }
ln -sfn "$cuda_lib" "$LIBTORCH_DIR/cuda-lib"
echo "$want_stamp" > "$STAMP"
echo "setup: Python environment ready"
