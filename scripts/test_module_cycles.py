"""The module-cycle check finds a cycle when there is one, and only then: a sibling
cycle, a child using its parent's own item, a facade that only re-exports (no cycle),
`super::` inside an inline module (the file's own module), and the repository itself."""

import importlib.util
import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).with_name("module_cycles.py")
spec = importlib.util.spec_from_file_location("module_cycles", SCRIPT)
module_cycles = importlib.util.module_from_spec(spec)
spec.loader.exec_module(module_cycles)


def crate(tmp_path, files):
    for name, text in files.items():
        path = tmp_path / "src" / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return module_cycles.cycles(module_cycles.Crate(tmp_path).edges())


def test_siblings_that_use_each_other_are_a_cycle(tmp_path):
    found = crate(tmp_path, {
        "lib.rs": "mod a;\nmod b;\n",
        "a.rs": "use crate::b::B;\npub struct A;\n",
        "b.rs": "pub struct B;\npub fn f() { let _ = crate::a::A; }\n",
    })
    assert found == [[("a",), ("b",)]]


def test_a_child_using_an_item_of_its_re_exporting_parent_is_a_cycle(tmp_path):
    found = crate(tmp_path, {
        "lib.rs": "pub mod m;\n",
        "m/mod.rs": "mod child;\npub use child::C;\npub fn helper() {}\n",
        "m/child.rs": "use super::helper;\npub struct C;\n",
    })
    assert found == [[("m",), ("m", "child")]]


def test_a_facade_that_only_re_exports_is_not_a_cycle(tmp_path):
    found = crate(tmp_path, {
        "lib.rs": "pub mod m;\n",
        "m/mod.rs": "mod a;\nmod b;\npub use a::A;\npub use b::*;\n",
        "m/a.rs": "use super::B;\npub struct A;\n",
        "m/b.rs": "pub struct B;\n",
    })
    assert found == []


def test_super_in_an_inline_module_and_unit_tests_are_not_cycles(tmp_path):
    found = crate(tmp_path, {
        "lib.rs": "mod a;\nmod b;\n",
        "a.rs": "mod kernel { use super::Item; }\npub struct Item;\nuse crate::b::B;\n",
        "b.rs": "pub struct B;\n#[cfg(test)]\nmod tests { use crate::a::Item; }\n",
    })
    assert found == []


def test_the_repository_has_no_module_cycles():
    result = subprocess.run([sys.executable, str(SCRIPT)], capture_output=True, text=True)
    assert result.returncode == 0, result.stdout
