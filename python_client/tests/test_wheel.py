"""The wheel that ``make python`` builds stands on its own: installed into an empty
virtual environment with only the dependencies the package declares, ``import ciflow``
and ``gymnasium.make`` work, with an engine embedded in the process. It is one wheel for
every CPython from 3.10 on (the stable ABI) and carries no debug information."""

import os
import pathlib
import struct
import subprocess
import sys
import zipfile

ROOT = pathlib.Path(__file__).resolve().parents[2]

# Runs in the fresh environment: one episode step of a task served by an embedded engine.
SCRIPT = """
import importlib.metadata
import gymnasium, ciflow
env = gymnasium.make("ciflow/LimitCycle-v0")
observation, _ = env.reset(seed=0)
env.step(env.action_space.sample())
env.close()
ciflow.shutdown_embedded_engine()
print("stepped", observation.shape)
print("extras", sorted(importlib.metadata.metadata("ciflow").get_all("Provides-Extra")))
"""


def built_wheel() -> pathlib.Path:
    wheels = pathlib.Path(os.environ.get("CARGO_TARGET_DIR", ROOT / "target")) / "wheels"
    found = sorted(wheels.glob("ciflow-*.whl"))
    assert len(found) == 1, f"expected the one wheel `make python` builds in {wheels}: {found}"
    return found[0]


def section_names(elf: bytes) -> list[str]:
    """Section names of a 64-bit little-endian ELF file (its section header table)."""
    assert elf[:4] == b"\x7fELF" and elf[4] == 2 and elf[5] == 1, "not a 64-bit LE ELF"
    shoff, = struct.unpack_from("<Q", elf, 0x28)
    entry_size, count, names_index = struct.unpack_from("<HHH", elf, 0x3A)

    def header(i):
        name, _, _, _, offset, size = struct.unpack_from("<IIQQQQ", elf, shoff + i * entry_size)
        return name, offset, size

    _, table, table_size = header(names_index)
    strings = elf[table:table + table_size]
    return [strings[n:strings.index(b"\0", n)].decode() for n, _, _ in map(header, range(count))]


def test_the_wheel_is_abi3_and_stripped():
    wheel = built_wheel()
    assert "-cp310-abi3-" in wheel.name, wheel.name
    with zipfile.ZipFile(wheel) as archive:
        [library] = [n for n in archive.namelist() if n.endswith(".so")]
        names = section_names(archive.read(library))
    assert ".text" in names, names
    debug = [n for n in names if n.startswith(".debug")]
    assert not debug, f"{library} carries debug sections {debug}"


def test_the_wheel_installs_and_runs_in_an_empty_environment(tmp_path, private_default_endpoint):
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", venv], check=True)
    python = venv / "bin" / "python"
    install = subprocess.run([python, "-m", "pip", "install", "-q", built_wheel()],
                             capture_output=True, text=True, timeout=900)
    assert install.returncode == 0, install.stderr
    # Outside the repository, so nothing of it is importable but the installed package.
    run = subprocess.run([python, "-c", SCRIPT], capture_output=True, text=True, timeout=300,
                         cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    assert "stepped (" in run.stdout, run.stdout
    assert "extras ['convert', 'plot', 'view']" in run.stdout, run.stdout
