"""``bench.codedeps``: a task's code version hashes the library modules it can import and the harness
modules that compute a cell, and only those."""

from __future__ import annotations

import pytest

from bench import codedeps
from bench.tasks import Task
from moegs.data import dataset_module

FILES = {
    "moegs/__init__.py": "",
    "moegs/a.py": "def f():\n    from moegs import b  # imported inside a function\n",
    "moegs/b.py": "from .c import x\n",
    "moegs/c.py": "x = 1\n",
    "moegs/unused.py": "import moegs.a\n",
    "moegs/sub/__init__.py": "",
    "moegs/sub/e.py": "from .. import c\n",
    "moegs/experts/__init__.py": "",
    "moegs/experts/one.py": "",
    "moegs/experts/two.py": "",
    "moegs/uses.py": 'from moegs.experts import get\nBASE = get("one")\n',
    "moegs/mentions.py": 'NAME = "two"  # not the registry: a plain string\n',
    "moegs/kernels/__init__.py": "",
    "moegs/kernels/k.c": "int k;\n",
    "bench/__init__.py": "",
    "bench/run.py": "import moegs.a\nimport numpy\nimport bench.cells.kind\n",
    "bench/cells/__init__.py": "",
    "bench/cells/kind.py": "import moegs.c\n",
    "bench/named.py": 'API = "moegs.sub.e:f"\nTEXT = "moegs.c is not a name here"\n',
}


@pytest.fixture
def tree(tmp_path, monkeypatch):
    for name, text in FILES.items():
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text(text)
    experts = (("one", "moegs.experts.one"), ("two", "moegs.experts.two"))
    monkeypatch.setattr(codedeps, "builtin_experts", lambda: experts)
    yield tmp_path
    codedeps.import_graph.cache_clear()
    codedeps.source_version.cache_clear()


def test_closure_follows_every_import_and_the_parent_packages(tree):
    assert codedeps.closure(["bench.run"], tree) == {
        "bench",
        "bench.run",
        "bench.cells",
        "bench.cells.kind",
        "moegs",
        "moegs.a",
        "moegs.b",
        "moegs.c",
    }
    assert codedeps.closure(["moegs.sub.e"], tree) == {"moegs", "moegs.sub", "moegs.sub.e", "moegs.c"}
    # the harness names library pieces by string; such a name is an import
    assert codedeps.closure(["bench.named"], tree) == {
        "bench",
        "bench.named",
        "moegs",
        "moegs.sub",
        "moegs.sub.e",
        "moegs.c",
    }
    # an expert asked of the registry by a literal name is imported; a string elsewhere is not
    assert "moegs.experts.one" in codedeps.closure(["moegs.uses"], tree)
    assert codedeps.closure(["moegs.mentions"], tree) == {"moegs", "moegs.mentions"}
    with pytest.raises(KeyError, match="no module 'moegs.nope'"):
        codedeps.closure(["moegs.nope"], tree)


def test_version_moves_with_the_modules_it_hashes_and_no_other(tree):
    modules = codedeps.closure(["bench.run"], tree)
    before = codedeps.source_version(modules, tree)
    (tree / "moegs/unused.py").write_text("import moegs.a\nchanged = True\n")
    (tree / "bench/run.py").write_text("import moegs.a\nimport numpy\nimport bench.cells.kind\nX = 1\n")
    codedeps.source_version.cache_clear()
    assert codedeps.source_version(modules, tree) == before  # planning/reporting harness: not hashed
    (tree / "moegs/c.py").write_text("x = 2\n")
    codedeps.source_version.cache_clear()
    changed = codedeps.source_version(modules, tree)
    assert changed != before
    (tree / "bench/cells/kind.py").write_text("import moegs.c\nSCALE = 2\n")  # a cell kind computes numbers
    codedeps.source_version.cache_clear()
    assert codedeps.source_version(modules, tree) != changed


def test_comments_docstrings_and_layout_do_not_move_a_version_and_code_does(tree):
    modules = codedeps.closure(["moegs.c"], tree)
    path = tree / "moegs/c.py"
    path.write_text('"""Module doc."""\n\n\ndef f(a):\n    """Doc."""\n    return a + 1\n')
    codedeps.source_version.cache_clear()
    before = codedeps.source_version(modules, tree)
    path.write_text('"""Other doc."""\n# a comment\ndef f( a ):  # why\n    return (a\n            + 1)\n')
    codedeps.source_version.cache_clear()
    assert codedeps.source_version(modules, tree) == before
    # an attribute docstring documents too; a string the code uses is code
    path.write_text('"""Module doc."""\nX = 1\n"""X doc."""\n\n\ndef f(a):\n    return a + 1\n')
    codedeps.source_version.cache_clear()
    with_x = codedeps.source_version(modules, tree)
    assert with_x != before
    path.write_text('"""Module doc."""\nX = 1\n"""Other."""\n\n\ndef f(a):\n    "Doc."\n    return a + 1\n')
    codedeps.source_version.cache_clear()
    assert codedeps.source_version(modules, tree) == with_x
    path.write_text('"""Module doc."""\n\n\ndef f(a):\n    return a + 1 if a != "kept" else a\n')
    codedeps.source_version.cache_clear()
    assert codedeps.source_version(modules, tree) != before
    path.write_text('"""Module doc."""\n\n\ndef f(a):\n    return a + 2\n')
    codedeps.source_version.cache_clear()
    assert codedeps.source_version(modules, tree) != before
    path.write_text("def f(a):\n    return a +\n")
    codedeps.source_version.cache_clear()
    with pytest.raises(SyntaxError) as err:
        codedeps.source_version(modules, tree)
    assert err.value.filename == str(path)


def test_the_c_kernel_counts_where_the_kernels_package_is_imported(tree):
    with_kernel = frozenset({"moegs", "moegs.kernels"})
    before, without = (
        codedeps.source_version(with_kernel, tree),
        codedeps.source_version(frozenset({"moegs"}), tree),
    )
    (tree / "moegs/kernels/k.c").write_text("int k = 1;\n")
    codedeps.source_version.cache_clear()
    assert codedeps.source_version(with_kernel, tree) != before
    assert codedeps.source_version(frozenset({"moegs"}), tree) == without


def test_tasks_hash_their_own_expert_and_loader_only():
    deformable = Task("build", "expert", {"expert": "deformable"}, "dnerf:mutant")
    modules = codedeps.task_modules(*deformable.code_dependencies())
    assert {"moegs.experts.deformable", "moegs.data.dnerf", "moegs.train.loop", "moegs.kernels"} <= modules
    assert not {"moegs.experts.grid4d", "moegs.data.panoptic", "moegs.moe"} & modules
    moe = Task("build", "moe", {"experts": ["fourdgs", "grid4d"], "router": "vapr"}, "panoptic:basketball")
    assert moe.code_dependencies() == ("moe", frozenset({"fourdgs", "grid4d"}), "panoptic")
    modules = codedeps.task_modules(*moe.code_dependencies())
    assert {
        "moegs.experts.fourdgs",
        "moegs.experts.grid4d",
        "moegs.moe.routers",
        "moegs.data.panoptic",
    } <= modules
    assert "moegs.experts.deformable" not in modules
    # the version is part of the key; the evaluation of a build shares its code
    evaluation = deformable.derive("eval", "expert", {"expert": "deformable"})
    assert deformable.identity()["code_version"] == evaluation.identity()["code_version"]
    assert deformable.code_version != moe.code_version
    with pytest.raises(ValueError, match="unknown dataset 'nope'; valid datasets"):
        dataset_module("nope")


@pytest.mark.parametrize(
    ("module", "hashed"),
    [
        ("moegs.experts.stg", True),
        ("bench.worker", True),
        ("bench.cells.moe", True),
        ("bench.schedules", True),  # stretches the quick schedules a standard cell trains with
        ("bench.report", False),
        ("bench.plan", False),
        ("bench.schedulesx", False),
    ],
)
def test_the_harness_modules_that_compute_numbers_are_hashed(module, hashed):
    assert codedeps.is_hashed(module) is hashed
